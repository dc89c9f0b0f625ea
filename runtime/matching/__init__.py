"""Scan matching: point scans, the distance fields and the objective they give, the swarm
optimizers, the matcher (Alg. 5) and the place search (docs/method.md §2–4, §8)."""
