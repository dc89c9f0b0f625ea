"""Localization in a saved map: the global place search, the candidates' tracking and confirmation
(docs/method.md §8–9)."""
