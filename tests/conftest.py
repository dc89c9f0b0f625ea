"""Shared test set-up."""

from hypothesis import settings

# The first call of a numba kernel compiles it (seconds with an empty cache): no deadlines.
settings.register_profile("swarmslam", deadline=None)
settings.load_profile("swarmslam")
