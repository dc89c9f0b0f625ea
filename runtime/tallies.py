"""The components' tallies (``TrackingCounts``, ``LoopCounts``, ``SearchCounts``):
dataclasses of counts, saved with a session as their ``asdict`` and reported whole by
:meth:`swarmslam.runtime.slam.GraphSlam.report`."""

from __future__ import annotations

import dataclasses


def restore_counts(counts, saved: dict) -> None:
    """A tallies dataclass (``TrackingCounts``, ``LoopCounts``, ...) set from the dict its
    ``asdict`` saved: every field given, each a non-negative whole number."""
    names = {f.name for f in dataclasses.fields(counts)}
    if set(saved) != names:
        raise ValueError(f"{type(counts).__name__} saved as {sorted(saved)}, expected "
                         f"{sorted(names)}")
    for name, value in saved.items():
        if int(value) != value or value < 0:
            raise ValueError(f"{type(counts).__name__}.{name} is {value!r}, not a count")
        setattr(counts, name, int(value))
