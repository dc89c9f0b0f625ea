"""Surveys: a robot driven along a fixed route through a generated floor, with the scans, the
wheel odometry and the true poses recorded — the raw material of ``swarmslam simlog`` and the
generalization suite (docs/formats.md §7).

    survey = run_survey(site("building", seed=0), lidar="sick-0.5", rate_hz=10.0)
    survey.true_poses      # (N, 3): where each scan was really taken
    survey.odometry        # (N, 3): what the wheels said, from the same start

The drive is kinematic (the routes keep clear of walls; no physics is needed): a pure-pursuit
controller follows the route's centre line at walking pace, slowing into turns. The odometry is
a differential drive's: each wheel's travel with noise growing with the square root of distance
(a random walk) and, for a biased robot, one wheel larger than the odometry assumes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from swarmslam_sim.generators import building, corridor, hall
from swarmslam_sim.lidar import Lidar, LidarConfig
from swarmslam_sim.world import World

# Scanners of the suite: the logs it stands in for carry 180° SICK lasers at 1° and 0.5°
# reaching 80 m; small robots carry 360° RPLidars reaching 12 m. "sick-1-8m" is a SICK in its
# millimetre mode, reaching 8.183 m and reading that for a beam without a return: a FLASER
# log of it says so only by that recurring value (swarmslam.carmen.flaser_no_return).
SCANNERS = {
    "sick-1": LidarConfig(181, math.pi, 0.05, 80.0, 10.0, 0.01, 0.0),
    "sick-0.5": LidarConfig(361, math.pi, 0.05, 80.0, 10.0, 0.01, 0.0),
    "sick-1-8m": LidarConfig(181, math.pi, 0.05, 8.183, 10.0, 0.01, 0.0),
    "rplidar-a1": LidarConfig(360, 2 * math.pi, 0.15, 12.0, 5.5, 0.02, 0.01),
    "rplidar-a2": LidarConfig(720, 2 * math.pi, 0.15, 12.0, 10.0, 0.015, 0.005),
}


@dataclass(frozen=True)
class OdometryModel:
    """A differential drive's wheel odometry."""

    wheel_noise: float  # m per √m of wheel travel (a random walk per wheel)
    right_wheel_scale: float = 1.0  # the right wheel's true size over the size assumed
    wheel_base: float = 0.4  # m


ODOMETRY = {
    "good": OdometryModel(0.003),
    "noisy": OdometryModel(0.015),
    "biased": OdometryModel(0.003, right_wheel_scale=1.02),  # one wheel 2% larger
}


@dataclass(frozen=True)
class Site:
    """A world and the route a survey drives through it (waypoints, driven in order)."""

    world: World
    route: np.ndarray  # (K, 2)


def _ring(x0, y0, x1, y1):
    return [(x0, y0), (x1, y0), (x1, y1), (x0, y1), (x0, y0)]


def site(kind: str, seed: int = 0) -> Site:
    """``building``: twice round the 76 m ring, then the two halves through the cross
    corridor; ``corridor``: once and a half round the 132 m ring of plain corridors; ``hall``:
    twice round a 60 m loop in the open middle of a hall."""
    if kind == "building":
        world = building(seed)
        w, h = world.bounds[2] - 0.5, world.bounds[3] - 0.5
        lo, xm = 5.0, w / 2  # the ring's centre line: room depth + half the corridor
        ring = _ring(lo, lo, w - lo, h - lo)
        route = ring + ring[1:] + [(xm, lo), (xm, h - lo), (w - lo, h - lo), (w - lo, lo),
                                   (xm, lo), (xm, h - lo), (lo, h - lo), (lo, lo)]
    elif kind == "corridor":
        world = corridor(seed)
        w, h = world.bounds[2] - 1.0, world.bounds[3] - 1.0
        ring = _ring(1.0, 1.0, w - 1.0, h - 1.0)
        route = ring + ring[1:3]
    elif kind == "hall":
        world = hall(seed)
        w, h = world.bounds[2] - 0.5, world.bounds[3] - 0.5
        ring = _ring(w / 4, h / 2 - 3.5, 3 * w / 4, h / 2 + 6.5)
        route = ring + ring[1:]
    else:
        raise ValueError(f"unknown site {kind!r}; choose one of {', '.join(SITES)}")
    return Site(world, np.array(route, float))


SITES = ("building", "corridor", "hall")


@dataclass
class Survey:
    site: Site
    lidar: LidarConfig
    stamps: np.ndarray  # (N,) s
    true_poses: np.ndarray  # (N, 3)
    odometry: np.ndarray  # (N, 3), starting at the true start pose
    ranges: np.ndarray  # (N, beams); max_range where nothing returned
    angles: np.ndarray  # (beams,) in the scanner's frame

    @property
    def length(self) -> float:
        """Metres driven."""
        return float(np.sum(np.hypot(*np.diff(self.true_poses[:, :2], axis=0).T)))


def drive(route, rate_hz: float, speed: float = 0.5, max_turn: float = 0.8,
          lookahead: float = 0.6, control_dt: float = 0.01, seconds: float | None = None):
    """True poses at ``rate_hz`` and, per scan interval, the control steps' motions
    ``(ds, dθ)`` (for the odometry), following ``route`` by pure pursuit (for at most
    ``seconds``, if given)."""
    route = np.asarray(route, float)
    seg = np.diff(route, axis=0)
    seg_len = np.hypot(seg[:, 0], seg[:, 1])
    arc = np.r_[0.0, np.cumsum(seg_len)]
    total = arc[-1]
    sub = max(1, math.ceil(1.0 / (rate_hz * control_dt)))
    dt = 1.0 / (rate_hz * sub)
    pose = np.array([*route[0], math.atan2(seg[0, 1], seg[0, 0])])
    progress, k = 0.0, 0
    poses, motions = [pose.copy()], []

    def point_at(s):
        i = min(int(np.searchsorted(arc, s, side="right")) - 1, len(seg) - 1)
        return route[i] + seg[i] * ((s - arc[i]) / seg_len[i])

    while progress < total - 0.05 and (seconds is None or len(motions) < seconds * rate_hz):
        steps = np.zeros((sub, 2))
        for m in range(sub):
            # progress: the projection on the current segment or the next
            for _ in range(2):
                a, d = route[k], seg[k]
                t = np.clip(((pose[0] - a[0]) * d[0] + (pose[1] - a[1]) * d[1]) / seg_len[k] ** 2,
                            0.0, 1.0)
                progress = max(progress, arc[k] + t * seg_len[k])
                if t >= 1.0 and k < len(seg) - 1:
                    k += 1
                else:
                    break
            target = point_at(min(progress + lookahead, total))
            alpha = math.atan2(target[1] - pose[1], target[0] - pose[0]) - pose[2]
            alpha = math.atan2(math.sin(alpha), math.cos(alpha))
            v = speed * max(0.0, math.cos(alpha)) ** 2 if abs(alpha) < 1.2 else 0.0
            w = float(np.clip(2.0 * max(v, 0.2) * math.sin(alpha) / lookahead, -max_turn, max_turn))
            ds, dth = v * dt, w * dt
            pose[0] += ds * math.cos(pose[2] + dth / 2)
            pose[1] += ds * math.sin(pose[2] + dth / 2)
            pose[2] = math.atan2(math.sin(pose[2] + dth), math.cos(pose[2] + dth))
            steps[m] = ds, dth
        poses.append(pose.copy())
        motions.append(steps)
    return np.array(poses), motions


def integrate_odometry(start, motions, model: OdometryModel, rng: np.random.Generator):
    """The wheel odometry's pose at each scan: every control step's true wheel travel, the
    right wheel's scaled by the bias, each with its random-walk noise."""
    pose = np.array(start, float)
    out = [pose.copy()]
    b = model.wheel_base
    for steps in motions:
        for ds, dth in steps:
            left, right = ds - dth * b / 2, ds + dth * b / 2
            right = right / model.right_wheel_scale  # a larger wheel travels further per count
            noise = rng.standard_normal(2) * model.wheel_noise
            left += noise[0] * math.sqrt(abs(left))
            right += noise[1] * math.sqrt(abs(right))
            ds_o, dth_o = (left + right) / 2, (right - left) / b
            pose[0] += ds_o * math.cos(pose[2] + dth_o / 2)
            pose[1] += ds_o * math.sin(pose[2] + dth_o / 2)
            pose[2] = math.atan2(math.sin(pose[2] + dth_o), math.cos(pose[2] + dth_o))
        out.append(pose.copy())
    return np.array(out)


def run_survey(where: Site, lidar: str | LidarConfig = "sick-0.5", rate_hz: float = 10.0,
               odometry: str | OdometryModel = "good", seed: int = 0,
               speed: float = 0.5, seconds: float | None = None) -> Survey:
    """Drive ``where``'s route (for at most ``seconds``) and record scans at ``rate_hz`` with
    their odometry and truth. Everything random (range noise, dropouts, wheel noise) comes
    from ``seed``."""
    config = SCANNERS[lidar] if isinstance(lidar, str) else lidar
    model = ODOMETRY[odometry] if isinstance(odometry, str) else odometry
    if not rate_hz > 0:
        raise ValueError(f"rate_hz must be > 0, got {rate_hz}")
    rng = np.random.default_rng(seed)
    poses, motions = drive(where.route, rate_hz, speed, seconds=seconds)
    odo = integrate_odometry(poses[0], motions, model, rng)
    scanner = Lidar(where.world, config)
    ranges = np.empty((len(poses), config.beams))
    for k, pose in enumerate(poses):
        ranges[k] = scanner.scan(pose, rng)
    stamps = np.arange(len(poses)) / rate_hz
    return Survey(where, config, stamps, poses, odo, ranges, scanner.angles.copy())
