"""Scoring and checking a run: Kümmerle et al.'s metric, ICP, the relations' audit and clock, what
a run showed of odometry (docs/method.md §7)."""
