"""The embeddable SLAM core (README, "Layout"; docs/runtime.md). Importing it first makes sure no compiled
kernel cached from older sources runs (:mod:`swarmslam.runtime.kernel_cache`)."""

from pathlib import Path

from swarmslam.runtime.kernel_cache import refresh

refresh(Path(__file__).parent)
