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
from swarmslam_sim.lidar import Lidar, LidarConfig, no_return
from swarmslam_sim.world import World

# Scanners of the suite: the logs it stands in for carry 180° SICK lasers at 1° and 0.5°
# reaching 80 m; small robots carry 360° RPLidars reaching 12 m. "sick-1-8m" is a SICK in its
# millimetre mode, reaching 8.183 m and reading that for a beam without a return: a FLASER
# log of it says so only by that recurring value (swarmslam.formats.carmen.flaser_no_return).
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
class Effects:
    """What a real robot and scanner add to a survey, each off at 0 (docs/formats.md §7):
    what makes a real log's heading hard, and that a simulated one lacked."""

    # s between odometry readings. The log then has no ODOM stream of its own (as MIT-CSAIL
    # and fr-clinic): each scan carries the latest reading, stale for several scans, then
    # caught up in one burst.
    odometry_period: float = 0.0
    odometry_latency: float = 0.0  # s: the reading a scan carries was taken this long before
    stamp_jitter: float = 0.0  # s: std of the error of a scan's stamp
    # s from a scan's first beam to its last (the stamp marks the last): each beam is taken
    # from where the robot was then. A spinning RPLidar's is its whole turn; a SICK LMS200's
    # 13 ms (1°) or 27 ms (0.5°, two interlaced sweeps).
    sweep_seconds: float = 0.0
    # A scanner whose beams go all the way round (an RPLidar) sweeps for its whole turn, one
    # turn per scan (1 / the scan rate), whatever ``sweep_seconds`` says (:func:`sweep_of`).
    sweep_turn: bool = False
    range_bias: float = 0.0  # m: std of each beam's own fixed range offset
    # Probability that a beam whose footprint (BEAM_WIDTH) spans a depth edge reads somewhere
    # between the two surfaces (a mixed pixel) instead of the nearer one.
    mixed_pixels: float = 0.0
    people: int = 0  # people walking up and down the route, PERSON_RADIUS wide

    def __post_init__(self):
        for name in ("odometry_period", "odometry_latency", "stamp_jitter", "sweep_seconds",
                     "range_bias", "mixed_pixels"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be finite and ≥ 0, got {value}")
        if self.mixed_pixels > 1 or self.people < 0:
            raise ValueError("mixed_pixels must be ≤ 1 and people ≥ 0")


BEAM_WIDTH = math.radians(0.5)  # a beam's footprint across (a SICK's is 0.25–0.5°)
MIXED_EDGE = 0.3  # m: a depth step across the footprint this large is an edge
SWEEP_GROUPS = 16  # beams cast together from one pose of a moving sweep, at least ...
SWEEP_GROUP_SECONDS = 0.002  # ... and as many more as keep a group within this long
PERSON_RADIUS = 0.25  # m
PERSON_SPEED = 1.0  # m/s
PERSON_OFFSET = 0.5  # m at most beside the route's centre line
# Scans per second a survey takes: real 2-D scanners turn at 5–75 Hz; below, a route is a few
# scans; above, the log's size (every scan kept in memory) grows without use.
RATE_HZ = (0.1, 1000.0)
# A robot as real logs show it (MIT-CSAIL): odometry read about once a second into a log of
# its own, stale between readings; turns up to ~2 rad/s; a SICK's 0.5° interlaced sweep; a
# few millimetres of per-beam bias, mixed pixels at edges, people passing.
EFFECTS = {
    "none": Effects(),
    "robot": Effects(odometry_period=0.8, odometry_latency=0.02, stamp_jitter=0.002,
                     sweep_seconds=0.027, sweep_turn=True, range_bias=0.005, mixed_pixels=0.5,
                     people=3),
}


def rotates(lidar: LidarConfig) -> bool:
    """A scanner whose beams go all the way round (an RPLidar): it sweeps a whole turn."""
    return lidar.fov >= 2 * math.pi - 1e-9


def sweep_of(effects: Effects, lidar: LidarConfig, rate_hz: float) -> float:
    """s from a scan's first beam to its last, as ``effects`` and the scanner make it: a full
    turn of beams swept for the whole turn when ``sweep_turn`` (an RPLidar at 5.5 Hz: 0.18 s),
    else ``sweep_seconds``: what a replay of the log may be told (``sensor.sweep_seconds``)."""
    if effects.sweep_turn and rotates(lidar):
        return 1.0 / rate_hz
    return effects.sweep_seconds


@dataclass(frozen=True)
class Turning:
    """How the robot turns: at most ``max_rate`` rad/s; beyond a heading error of ``pivot``
    rad it stops and turns in place at that rate (None: never); it pursues the route
    ``lookahead`` m ahead (shorter: sharper corners)."""

    max_rate: float = 0.8
    pivot: float | None = None
    lookahead: float = 0.6


# With each set of effects. Pure pursuit alone turns at ~0.6 rad/s; MIT-CSAIL's robot stops
# and turns at 1.4–2.4 rad/s.
TURNING = {"none": Turning(), "robot": Turning(2.0, 0.6, 0.2)}
# Each effect in a word, for the command line (swarmslam simlog --odometry-period ...).
EFFECT_HELP = {
    "odometry_period": "s between odometry readings; the log then has no ODOM stream: each "
                       "scan carries the latest reading, stale until the next",
    "odometry_latency": "s: the reading a scan carries was taken this long before it",
    "stamp_jitter": "s: std of the error of each scan's stamp",
    "sweep_seconds": "s from a scan's first beam to its last, each beam taken where the robot "
                     "was then (the stamp marks the last)",
    "range_bias": "m: std of each beam's own fixed range offset",
    "mixed_pixels": "probability that a beam across a depth edge reads between the surfaces",
    "people": "people walking up and down the route",
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
    odometry_stream: bool = True  # the log has an ODOM stream (else the scans' own readings)
    sweep_seconds: float = 0.0  # from each scan's first beam to its last (:func:`sweep_of`)

    @property
    def length(self) -> float:
        """Metres driven."""
        return float(np.sum(np.hypot(*np.diff(self.true_poses[:, :2], axis=0).T)))


def drive(route, rate_hz: float, speed: float = 0.5, max_turn: float = 0.8,
          lookahead: float = 0.6, control_dt: float = 0.01, seconds: float | None = None,
          pivot: float | None = None):
    """True poses at ``rate_hz``, per scan interval the control steps' motions ``(ds, dθ)``
    (for the odometry), and the true pose after every control step (``control_dt`` apart,
    the first the start), following ``route`` by pure pursuit (for at most ``seconds``, if
    given), turning at most ``max_turn`` rad/s; ``pivot``: a heading error (rad) beyond which
    the robot stops and turns in place at ``max_turn`` (None: it never does)."""
    route = np.asarray(route, float)
    seg = np.diff(route, axis=0)
    seg_len = np.hypot(seg[:, 0], seg[:, 1])
    arc = np.r_[0.0, np.cumsum(seg_len)]
    total = arc[-1]
    sub = max(1, math.ceil(1.0 / (rate_hz * control_dt)))
    dt = 1.0 / (rate_hz * sub)
    pose = np.array([*route[0], math.atan2(seg[0, 1], seg[0, 0])])
    progress, k = 0.0, 0
    poses, motions, fine = [pose.copy()], [], [pose.copy()]

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
            if pivot is not None and abs(alpha) > pivot:  # stop and turn in place, briskly
                v, w = 0.0, math.copysign(max_turn, alpha)
            ds, dth = v * dt, w * dt
            pose[0] += ds * math.cos(pose[2] + dth / 2)
            pose[1] += ds * math.sin(pose[2] + dth / 2)
            pose[2] = math.atan2(math.sin(pose[2] + dth), math.cos(pose[2] + dth))
            steps[m] = ds, dth
            fine.append(pose.copy())
        poses.append(pose.copy())
        motions.append(steps)
    return np.array(poses), motions, np.array(fine)


def integrate_odometry(start, motions, model: OdometryModel, rng: np.random.Generator):
    """The wheel odometry's pose after every control step (the first the start): each step's
    true wheel travel, the right wheel's scaled by the bias, each with its random-walk
    noise. Every ``len(motions[0])``-th is the odometry at a scan."""
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
               speed: float = 0.5, seconds: float | None = None,
               effects: str | Effects = "none", turning: str | Turning | None = None,
               max_turn: float | None = None) -> Survey:
    """Drive ``where``'s route (for at most ``seconds``) and record scans at ``rate_hz`` with
    their odometry and truth, with real-robot ``effects``. The robot turns as ``turning`` says
    (default: as the effects named, TURNING), at most ``max_turn`` rad/s if given. Everything
    random (range noise, dropouts, wheel noise, the effects) comes from ``seed``; without
    effects a survey is what it was before they existed."""
    config = SCANNERS[lidar] if isinstance(lidar, str) else lidar
    model = ODOMETRY[odometry] if isinstance(odometry, str) else odometry
    if turning is None:
        turning = effects if isinstance(effects, str) else "none"
    turning = TURNING[turning] if isinstance(turning, str) else turning
    max_turn = turning.max_rate if max_turn is None else max_turn
    effects = EFFECTS[effects] if isinstance(effects, str) else effects
    if not RATE_HZ[0] <= rate_hz <= RATE_HZ[1]:
        raise ValueError(f"rate_hz must be within {RATE_HZ[0]:g}–{RATE_HZ[1]:g} scans per "
                         f"second, got {rate_hz}")
    if not max_turn > 0:
        raise ValueError(f"max_turn must be > 0, got {max_turn}")
    rng = np.random.default_rng(seed)
    poses, motions, fine = drive(where.route, rate_hz, speed, max_turn, turning.lookahead,
                                 seconds=seconds, pivot=turning.pivot)
    sub = len(motions[0]) if motions else 1
    odo_fine = integrate_odometry(poses[0], motions, model, rng)
    stamps = np.arange(len(poses)) / rate_hz
    scanner = Lidar(where.world, config)
    ranges = np.empty((len(poses), config.beams))
    if effects == EFFECTS["none"]:
        for k, pose in enumerate(poses):
            ranges[k] = scanner.scan(pose, rng)
        return Survey(where, config, stamps, poses, odo_fine[::sub], ranges,
                      scanner.angles.copy())
    # The effects draw from a stream of their own: the rest of the survey stays as it was.
    fx = np.random.default_rng([seed, 2])
    step = 1.0 / (rate_hz * sub)  # s between control steps
    odo = odometry_readings(odo_fine, stamps, step, effects)
    people = People(where.route, effects.people, fx)
    bias = fx.normal(0.0, effects.range_bias, config.beams) if effects.range_bias else None
    sweep = sweep_of(effects, config, rate_hz)
    for k in range(len(poses)):
        r = sweep_scan(scanner, fine, stamps[k], step, sweep, effects, people, fx)
        if config.noise_std > 0:
            r += config.noise_std * rng.standard_normal(config.beams)
        if bias is not None:
            r += bias
        if config.dropout > 0:
            r[rng.random(config.beams) < config.dropout] = np.inf
        no_return(r, config.min_range, config.max_range)
        ranges[k] = r
    logged = stamps
    if effects.stamp_jitter:
        logged = np.maximum.accumulate(stamps + fx.normal(0.0, effects.stamp_jitter, len(stamps)))
    return Survey(where, config, logged, poses, odo, ranges, scanner.angles.copy(),
                  odometry_stream=effects.odometry_period == 0, sweep_seconds=sweep)


def pose_at(fine, t: float, step: float) -> np.ndarray:
    """The true pose at time ``t`` (the nearest control step's)."""
    return fine[min(max(int(round(t / step)), 0), len(fine) - 1)]


def odometry_readings(odo_fine, stamps, step: float, effects: Effects) -> np.ndarray:
    """The odometry each scan carries: the reading taken ``odometry_latency`` before it, or
    with readings ``odometry_period`` apart, the latest of those."""
    out = np.empty((len(stamps), 3))
    for k, t in enumerate(stamps):
        t = max(t - effects.odometry_latency, 0.0)
        if effects.odometry_period:
            t = math.floor(t / effects.odometry_period) * effects.odometry_period
        out[k] = pose_at(odo_fine, t, step)
    return out


def sweep_scan(scanner: Lidar, fine, stamp: float, step: float, sweep: float, effects: Effects,
               people: "People", fx: np.random.Generator) -> np.ndarray:
    """One scan's exact ranges with the geometric effects: the beams of a ``sweep`` s long
    from the poses the robot had when each was taken, mixed pixels at depth edges, people in
    the way."""
    angles, n = scanner.angles, scanner.config.beams
    r = np.empty(n)
    groups = max(SWEEP_GROUPS, math.ceil(sweep / SWEEP_GROUP_SECONDS))
    edges = np.linspace(0, n, min(groups, n) + 1).astype(int) if sweep else np.array([0, n])
    for a, b in zip(edges[:-1], edges[1:]):
        middle = 0.5 * (a + b - 1) / max(n - 1, 1)  # the group's share through the sweep
        pose = pose_at(fine, stamp - sweep * (1.0 - middle), step)
        scanner.cast_angles(pose, angles[a:b], r[a:b])
        if effects.mixed_pixels:
            mixed_pixels(scanner, pose, angles[a:b], r[a:b], effects.mixed_pixels, fx)
        people.block(pose, angles[a:b], r[a:b], stamp)
    return r


def mixed_pixels(scanner: Lidar, pose, angles, r, share: float, fx: np.random.Generator):
    """Where the two edges of a beam's footprint see surfaces ``MIXED_EDGE`` or more apart,
    the beam reads (with probability ``share``) a range between them."""
    left = scanner.cast_angles(pose, angles + BEAM_WIDTH / 2, np.empty(len(angles)))
    right = scanner.cast_angles(pose, angles - BEAM_WIDTH / 2, np.empty(len(angles)))
    near, far = np.minimum(left, right), np.maximum(left, right)
    with np.errstate(invalid="ignore"):  # (both sides without a return: inf - inf)
        step = far - near
    edge = np.isfinite(far) & (step >= MIXED_EDGE) & (fx.random(len(angles)) < share)
    r[edge] = near[edge] + fx.random(int(edge.sum())) * (far[edge] - near[edge])


class People:
    """People walking up and down segments of the route, beside its centre line: discs of
    ``PERSON_RADIUS`` the scanner sees, never where the robot is."""

    def __init__(self, route, count: int, fx: np.random.Generator):
        route = np.asarray(route, float)
        seg = np.flatnonzero(np.hypot(*np.diff(route, axis=0).T) > 1.0)
        self.count = count
        if count == 0:
            return
        k = fx.choice(seg, count)
        self.start, self.end = route[k], route[k + 1]
        d = self.end - self.start
        normal = np.c_[-d[:, 1], d[:, 0]] / np.hypot(d[:, 0], d[:, 1])[:, None]
        side = fx.uniform(-PERSON_OFFSET, PERSON_OFFSET, count)[:, None] * normal
        self.start, self.end = self.start + side, self.end + side
        self.length = np.hypot(*(self.end - self.start).T)
        self.phase = fx.uniform(0.0, 2.0, count) * self.length

    def at(self, t: float) -> np.ndarray:
        """Their positions at time ``t`` ((count, 2)): there and back along their segments."""
        walked = (self.phase + PERSON_SPEED * t) % (2 * self.length)
        along = np.where(walked > self.length, 2 * self.length - walked, walked) / self.length
        return self.start + along[:, None] * (self.end - self.start)

    def block(self, pose, angles, r, t: float) -> None:
        """Shorten the ranges ``r`` of beams at ``angles`` from ``pose`` that hit a person."""
        if self.count == 0:
            return
        centres = self.at(t) - pose[:2]
        centres = centres[np.hypot(centres[:, 0], centres[:, 1]) > PERSON_RADIUS + 0.3]
        if not len(centres):
            return
        d = np.c_[np.cos(pose[2] + angles), np.sin(pose[2] + angles)]  # (beams, 2)
        along = d @ centres.T  # (beams, people): the ray's closest approach
        miss2 = np.sum(centres**2, axis=1)[None, :] - along**2
        inside = PERSON_RADIUS**2 - miss2
        hit = np.where((inside > 0) & (along > 0), along - np.sqrt(np.maximum(inside, 0)), np.inf)
        np.minimum(r, hit.min(axis=1), out=r)
