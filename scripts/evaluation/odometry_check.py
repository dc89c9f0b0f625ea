"""What a run shows of its robot's odometry (``odometry_seen`` in a replay's ``metrics.json``;
docs/formats.md, "metrics.json").

A robot's odometry is set up by hand: a wheel radius, a wheel base. The SLAM fits the
distance scale where it must (:mod:`swarmslam.runtime.front_end.odometry_scale`), and a run tells the
user how far off both are, from the trajectory's motion between scans with consecutive new
readings against odometry's over the same readings:

- ``translation_scale``: the least-squares fit of the trajectory's translations to odometry's,
  ``Σ m·o / Σ o·o`` in each pair's first frame; 1.03 means the robot went 3% farther than its
  odometry said (a wheel radius 3% too small). Along a plain corridor the trajectory takes
  odometry's distance (the scans do not pin it), which pulls the figure towards 1.
- ``fitted_scale``: the SLAM's own fit at the end (docs/method.md §6.1, "Odometry's scale"),
  and ``edges_scale`` the scale the pose graph's edges hold odometry's part at (the fit's
  value at the last loop closure).
- ``heading_sigma_deg``, ``position_sigma_m``: the noise of odometry's motion over one
  reading, and ``match_heading_sigma_deg``, ``match_position_sigma_m`` a between-scan
  match's, as the trajectory's smoothing estimated them (docs/method.md §6.2, "Between-scan
  poses"); absent where the run could not tell (too few readings, or the matches look exact).

    >>> import numpy as np
    >>> from swarmslam.runtime.front_end.between_scans import NEW_READING
    >>> path = np.c_[np.arange(50) * 0.1, np.zeros(50), np.zeros(50)]  # 0.1 m a scan
    >>> odometry = path * [0.97, 1.0, 1.0]                             # reads 3% short
    >>> round(translation_scale(path, odometry, np.full(50, NEW_READING))[0], 4)
    1.0309
"""

from __future__ import annotations

import math

import numpy as np

from swarmslam.runtime.front_end.between_scans import linked
from swarmslam.runtime.pose import between


def translation_scale(trajectory, odometry, kind) -> tuple[float | None, int]:
    """``(scale, pairs)``: the trajectory's translations over odometry's (see the module's
    docstring) for the scans whose ``kind`` (``NEW_READING`` ...) links them, and how many
    pairs it rests on; the scale is None where odometry did not move."""
    new, joined = linked(np.asarray(kind))
    p, q = new[:-1][joined[1:]], new[1:][joined[1:]]
    if not len(p):
        return None, 0
    trajectory, odometry = np.asarray(trajectory), np.asarray(odometry)
    matched = between(trajectory[q], trajectory[p])[:, :2]
    read = between(odometry[q], odometry[p])[:, :2]
    squared = float(np.sum(read * read))
    if not squared > 0.0:
        return None, int(len(p))
    return float(np.sum(matched * read)) / squared, int(len(p))


def odometry_seen(front_end, trajectory) -> dict:
    """The run's figures (see the module's docstring) from ``front_end``'s record and its
    ``trajectory`` (one pose per scan, as ``FrontEnd.trajectory`` gave it, which also leaves
    the smoothing's noise estimates on the front end); empty without odometry."""
    n = front_end.scans.n
    scale, pairs = translation_scale(trajectory[:n], front_end.scans.odometry[:n],
                                     front_end.scans.reading[:n])
    if scale is None:
        return {}
    out = {"translation_scale": scale, "pairs": pairs,
           "edges_scale": front_end.graph.scale, "fitted_scale": front_end.calibration.fit.scale}
    for noise, key, unit in ((front_end.scans.heading_noise, "heading_sigma_deg", math.degrees),
                             (front_end.scans.position_noise, "position_sigma_m", float)):
        if noise is None:
            continue
        if noise.odometry > 0:
            out[key] = unit(math.sqrt(noise.odometry))
        if noise.between > 0:
            out[f"match_{key}"] = unit(math.sqrt(noise.between))
    return out
