"""One configuration tree for the SLAM runtime, validated when built, to and from TOML.

    config = preset("rplidar-a1")                         # or SlamConfig() for the defaults
    config = override(config, {"front_end.node_distance": 0.4})
    text = to_toml(config)                                # what ``swarmslam config show`` prints
    assert from_toml(text) == config

The tree: ``sensor``, ``capacity``, ``front_end``, ``matcher`` (with its ``swarm``),
``loop_closure``, ``optimizer`` (Gauss–Newton), ``map`` and ``runtime``. Every tuning constant
of the core is a field here, documented where it is declared (``doc``); every field is checked
by one mechanism, its declared type and bounds, so a bad value fails when the tree is built,
naming its key (``front_end.node_distance: must be > 0, got -1``). Presets name the sensors the
project knows; a preset is a whole tree, and a TOML file changes only the fields it names.
``docs/configuration.md`` lists every field.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import types
import typing
from dataclasses import dataclass, field, fields, is_dataclass, replace
from pathlib import Path

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

# The swarm methods, in the order of their numeric codes in the compiled kernels. The one list:
# the optimizers, the CLI and the environment take their names from here.
OPTIMIZERS = ("pso", "abc", "fa")
KERNEL_NAMES = ("paper", "cauchy")  # Eq. 14 as printed; the per-point robust kernel
INFORMATION_MODES = ("fixed", "paper")
SCHEDULES = ("budgeted", "lockstep")
SOLVERS = ("ldl", "superlu")


# The finest step between a heading search's starts (rad): a whole turn is then 1,257 starts,
# a bound on the search's work (ScanMatcher.seek_headings, front_end.recovery_heading_step).
MIN_HEADING_STEP = 0.005


class ConfigError(ValueError):
    """A configuration value or file that cannot be used; the message names the key."""


def doc(text: str, *, gt=None, ge=None, le=None, lt=None, choices=None):
    """Field metadata: what the field means and the bounds that ``validate`` enforces."""
    return {"doc": text, "gt": gt, "ge": ge, "le": le, "lt": lt, "choices": choices}


def _setting(default, text, **bounds):
    if isinstance(default, (list, dict)) or is_dataclass(default):
        raise TypeError("use _section for nested or mutable defaults")
    return field(default=default, metadata=doc(text, **bounds))


def _section(factory, text):
    return field(default_factory=factory, metadata=doc(text))


class Section:
    """Base of every node of the tree: validates its fields when built."""

    def __post_init__(self):
        validate(self)


def _check_number(key, value, kind, meta):
    if kind is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{key}: must be true or false, got {value!r}")
        return
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"{key}: must be a number, got {value!r}")
    if kind is int and not isinstance(value, int):
        raise ConfigError(f"{key}: must be a whole number, got {value!r}")
    if not math.isfinite(value):
        raise ConfigError(f"{key}: must be finite, got {value!r}")
    for name, test, word in (("gt", lambda v, b: v > b, ">"), ("ge", lambda v, b: v >= b, ">="),
                             ("lt", lambda v, b: v < b, "<"), ("le", lambda v, b: v <= b, "<=")):
        bound = meta.get(name)
        if bound is not None and not test(value, bound):
            raise ConfigError(f"{key}: must be {word} {bound}, got {value!r}")


def _check_value(key, value, hint, meta):
    """Check ``value`` against the annotation ``hint`` and the field's bounds."""
    args = typing.get_args(hint)
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        if value is None:
            if type(None) not in args:
                raise ConfigError(f"{key}: may not be none")
            return
        hint = next(a for a in args if a is not type(None))
        args = typing.get_args(hint)
    if hint is str:
        if not isinstance(value, str):
            raise ConfigError(f"{key}: must be a string, got {value!r}")
        if meta.get("choices") and value not in meta["choices"]:
            raise ConfigError(f"{key}: must be one of {', '.join(meta['choices'])}, got {value!r}")
        return
    if typing.get_origin(hint) is tuple:
        if not isinstance(value, tuple):
            raise ConfigError(f"{key}: must be a list, got {value!r}")
        length = None if Ellipsis in args else len(args)
        if length is not None and len(value) != length:
            raise ConfigError(f"{key}: needs {length} values, got {len(value)}")
        for v in value:
            _check_number(key, v, args[0], meta)
        return
    _check_number(key, value, hint, meta)


def validate(section, where: str | None = None) -> None:
    """Check every field of ``section`` (not its sub-sections: each checks itself)."""
    where = where or getattr(section, "KEY", type(section).__name__)
    hints = typing.get_type_hints(type(section))
    for f in fields(section):
        value = getattr(section, f.name)
        if is_dataclass(hints[f.name]):
            if not isinstance(value, hints[f.name]):
                raise ConfigError(f"{where}.{f.name}: must be a {hints[f.name].__name__}")
            continue
        _check_value(f"{where}.{f.name}", value, hints[f.name], f.metadata)


# ---------------------------------------------------------------------- the tree
@dataclass(frozen=True)
class SwarmConfig(Section):
    """Which swarm method, its parameters (defaults: the paper's Table 1) and halting rules
    (docs/method.md §2)."""

    KEY = "matcher.swarm"
    optimizer: str = _setting("abc", "the swarm method", choices=OPTIMIZERS)
    members: int | None = _setting(
        None, "PSO particles / ABC colony (2 × food sources) / fireflies; none: Table 1", ge=2,
        le=10_000)
    params: tuple[float, ...] | None = _setting(
        None, "the method's parameters (PSO w c1 c2; ABC limit; FA β0 γ α); none: Table 1")
    max_iterations: int = _setting(1000, "halting rule 1: iterations", ge=1, le=1_000_000)
    stagnation_iterations: int = _setting(50, "halting rule 2: iterations without gain", ge=1,
                                         le=1_000_000)
    stagnation_tol: float = _setting(1e-6, "what counts as a gain for rule 2", ge=0)
    target_value: float = _setting(1e-6, "halting rule 3: stop below this objective value")
    max_evaluations: int = _setting(0, "evaluation budget (0: the halting rules only)", ge=0,
                                   le=100_000_000)
    stall_iterations: int = _setting(
        0, "beyond the paper: stop after this many iterations in a row in which the best "
        "found gained no more than stall_tol (0: off; ABC and PSO only: a firefly swarm's best "
        "gains in bursts; docs/method.md §2)", ge=0, le=1_000_000)
    stall_tol: float = _setting(0.0, "what counts as a gain in the best for the stall rule "
                                "(in the objective's units)", ge=0)

    @property
    def kind(self) -> int:
        """The method's code in the compiled kernels (its index in ``OPTIMIZERS``)."""
        return OPTIMIZERS.index(self.optimizer)

    @property
    def stall_window(self) -> int:
        """The stall rule's iterations as the method runs them: ``stall_iterations``, but 0
        (off) for the firefly swarm. Its brightest member only walks at random (Eq. 12), so
        its best gains when another overtakes it, after runs without a gain that the rule
        takes for a settled swarm: with the rule, the matcher benchmark's matches with no
        guess failed several times as often as without."""
        return 0 if self.optimizer == "fa" else self.stall_iterations


def _budgeted_swarm() -> SwarmConfig:
    # A fixed-rate tick needs a bound on the global stage: 3,000 evaluations reached every
    # target of the matcher benchmark (docs/benchmarks.md). A swarm whose best has stopped
    # gaining ends sooner: the local stages settle the match (docs/method.md §2).
    return SwarmConfig(max_evaluations=3000, stall_iterations=30, stall_tol=1e-3)


@dataclass(frozen=True)
class MatcherConfig(Section):
    """Scan matcher, Alg. 5 (docs/method.md §3). The defaults are the ones
    ``swarmslam bench matcher`` measures; :meth:`paper` gives the paper's own form."""

    KEY = "matcher"
    swarm: SwarmConfig = _section(_budgeted_swarm, "the swarm of the global stage")
    resolution: float = _setting(0.05, "m per distance-field / local-grid cell", gt=0)
    kernel: str = _setting("cauchy", "per-point cost: 'paper' is Eq. 14, 'cauchy' "
                           "log(1 + d²/c²)", choices=KERNEL_NAMES)
    cauchy_scale: float = _setting(0.07, "m, c of the Cauchy kernel", gt=0)
    field_radius: float = _setting(0.5, "m: distances exact below, truncated above", gt=0)
    max_gap: float = _setting(1.0, "m: reference points closer than this form a surface", ge=0)
    surface_bend: float = _setting(
        0.05236, "rad (3°): neighbours farther apart than max_gap form a surface too when the "
        "pairs either side continue their line within this bend (a wall far down a corridor, "
        "seen grazing; docs/method.md §3); 0: max_gap alone", ge=0, lt=math.pi / 2)
    surface_gap_ratio: float = _setting(
        2.0, "... and their gap is at most this many times the shorter of those two pairs' "
        "(one surface sampled evenly, not a doorway's two sides)", ge=1)
    coarse_resolution: float = _setting(0.1, "m, the global stage's coarse field (0: none)", ge=0)
    coarse_radius: float = _setting(0.6, "m, truncation of the coarse field", gt=0)
    stride: int = _setting(2, "the global stage uses every stride-th point", ge=1)
    global_points: int = _setting(
        96, "the global stage scores at most about this many points: a denser scan's stride "
        "grows to keep to it (a 0.5° scanner costs what a 1° one does; 0: stride alone)", ge=0)
    refine_points: int = _setting(
        192, "the local stage scores at most about this many points, by a stride (its best "
        "judged on all; 0: all)", ge=0)
    refine_evaluations: int = _setting(600, "budget of the local stage (0: none)", ge=0,
                                      le=10_000_000)
    refine_window: tuple[float, float, float] = _setting(
        (0.15, 0.15, 0.08), "half-widths (m, m, rad) of the local stage", gt=0)
    polish_step: tuple[float, float] = _setting(
        (0.01, 0.005), "first steps (m, rad) of the compass search that settles the swarm's "
        "match on the fine field", gt=0)
    polish_halvings: int = _setting(
        6, "times the compass search halves its steps before it ends", ge=0)
    polish_evaluations: int = _setting(
        300, "budget of the compass search (0: no polish)", ge=0, le=10_000_000)
    predict_first: float = _setting(
        0.0, "with a guess, the local stage runs first at it; its match stands if λ is at "
        "most this many times the running mean λ, skipping the global stage (0: off)", ge=0)
    search_window: tuple[float, float, float] = _setting(
        (2.0, 2.0, 1.6), "half-widths of the box without a guess (m, m, rad)", gt=0)
    guess_window: tuple[float, float, float] = _setting(
        (0.3, 0.3, 0.3), "half-widths of the box around a guess (m, m, rad)", gt=0)
    grid_cells: int = _setting(2048, "capacity per side of the reference grids (a submap "
                              "wider than this at `resolution` keeps its points within half "
                              "of it from the sensor)", ge=8, le=8192)
    scan_to_map: bool = _setting(False, "Alg. 5's scan-to-map fallback (Eq. 16)")
    robot_diameter: float = _setting(0.35, "m, for Eq. 17", gt=0)
    occupied_radius: float = _setting(0.1, "m, ramp around obstacles in the local grid", gt=0)

    @classmethod
    def for_optimizer(cls, optimizer: str, **overrides) -> MatcherConfig:
        """The default matcher with another swarm method (its budget kept)."""
        return cls(swarm=replace(_budgeted_swarm(), optimizer=optimizer), **overrides)

    @classmethod
    def paper(cls, optimizer: str = "abc", **overrides) -> MatcherConfig:
        """The paper's matcher: Eq. 14 on a single field, the swarm halted by its own rules."""
        base = dict(swarm=SwarmConfig(optimizer=optimizer), kernel="paper", field_radius=1.0,
                    surface_bend=0.0, coarse_resolution=0.0, stride=1, global_points=0,
                    refine_points=0, refine_evaluations=0, polish_evaluations=0,
                    scan_to_map=True)
        base.update(overrides)
        return cls(**base)


@dataclass(frozen=True)
class SensorConfig(Section):
    """What the runtime needs to know of the scanner."""

    KEY = "sensor"
    name: str = _setting("sick-lms200", "the preset this came from (a label)")
    min_range: float = _setting(0.05, "m: nearer readings are dropped", ge=0)
    max_range: float = _setting(80.0, "m: readings at or beyond are 'no return'", gt=0)
    max_points: int = _setting(1440, "points kept per scan (≥ samples per rotation)", ge=1,
                              le=100_000)
    sweep_seconds: float = _setting(
        0.0, "s from a scan's first beam to its last, the beams in that order (a rotating "
        "scanner's sweep; 0: all at once); each point is turned to the robot's heading at the "
        "stamp (docs/method.md §6.1, 'The sweep')", ge=0, le=1.0)
    sweep_stamp: float = _setting(1.0, "where in the sweep a scan's stamp falls: 0 at its first "
                                  "beam, 1 at its last", ge=0, le=1)


@dataclass(frozen=True)
class InputConfig(Section):
    """What a record must be to be used (docs/runtime.md §7): odometry further than a robot
    moves between two readings is dropped from its scan, counted."""

    KEY = "input"
    max_speed: float = _setting(5.0, "m/s: odometry moving faster between two readings jumped",
                                gt=0)
    max_turn_rate: float = _setting(6.0, "rad/s: odometry turning faster jumped", gt=0)
    # The slacks cover logs whose stamps were reordered (two readings metres or a radian
    # apart within milliseconds); a garbage line is metres or kilometres off.
    jump_slack: float = _setting(1.0, "m allowed on top of max_speed × the time between "
                                 "readings (reordered stamps, readings at one instant)", ge=0)
    turn_slack: float = _setting(1.0, "rad allowed on top of max_turn_rate × the time", ge=0)


@dataclass(frozen=True)
class CapacityConfig(Section):
    """What grows with time, fixed at start-up (docs/runtime.md §4)."""

    KEY = "capacity"
    max_nodes: int = _setting(5000, "pose-graph nodes", ge=2, le=1_000_000)
    max_edges: int = _setting(20000, "pose-graph edges (≈ 1 + loops per node)", ge=1,
                             le=10_000_000)
    max_scans: int = _setting(100000, "trajectory poses kept (one per scan)", ge=1,
                             le=100_000_000)


@dataclass(frozen=True)
class FrontEndConfig(Section):
    """Tracking against the keyframe (Alg. 5) and node insertion (Alg. 6); docs/method.md
    §6.1."""

    KEY = "front_end"
    node_distance: float = _setting(0.5, "m moved since the last node that makes a node (Alg. 6)",
                                    gt=0)
    node_angle: float = _setting(0.5, "rad turned since the last node that makes a node", gt=0)
    information: str = _setting(
        "fixed", "edge information: 'fixed' diag(1/σt², 1/σt², 1/σθ²), 'paper' Eq. 20's I/σλ²",
        choices=INFORMATION_MODES)
    sigma_translation: float = _setting(0.025, "m, σt of a node edge's fixed information",
                                        gt=0)
    sigma_rotation: float = _setting(
        0.005, "rad, σθ of a node edge's fixed information (five to ten times what the match's "
        "curvature says: docs/method.md §4.2)", gt=0)
    min_track_inliers: float = _setting(
        0.5, "share of points on the keyframe's surfaces below which tracking is lost",
        ge=0, le=1)
    track_inlier_distance: float = _setting(0.2, "m: a point this near a surface is an inlier",
                                            gt=0)
    track_inlier_slope: float = _setting(0.01, "m per m of range added to track_inlier_distance "
                                         "(beams spread and graze)", ge=0)
    weak_information_factor: float = _setting(
        9.0, "the next edge's information is divided by this after a lost match", ge=1)
    odometry_gate: tuple[float, float] | None = _setting(
        (0.15, math.radians(5.0)),
        "a match correcting odometry by more than (m, rad) plus the shares below is lost; "
        "none: no gate", ge=0)
    odometry_gate_share: tuple[float, float] = _setting(
        (0.2, 0.35), "shares of odometry's step (translation, rotation) added to the gate", ge=0)
    odometry_gate_fit: float = _setting(
        0.1, "a match the gate refuses against a stale reading (odometry's last one again) "
        "stands when its share of points on the keyframe's surfaces exceeds odometry's "
        "prediction's by this much, or when it would stand against a new reading: the scans "
        "overrule odometry (docs/method.md §6.1); 1: by the gain never",
        ge=0, le=1)
    odometry_gate_explained: float = _setting(
        0.45, "a match the gate refuses for its heading against a reading (new, or stale "
        "where odometry_gate_fit's gain is not met) stands when it fits more than this share "
        "of the points odometry's prediction misses (docs/method.md §6.1); 1: never", ge=0, le=1)
    odometry_gate_distance: float = _setting(
        0.15, "m: against a new reading (or a stale one odometry_gate_fit's gain does not "
        "settle), the fits of a match and of odometry's prediction count the points this near "
        "a surface (plus track_inlier_slope per m of range): narrower than "
        "track_inlier_distance, which tells a lost match, it tells two poses a few degrees "
        "apart", gt=0)
    odometry_heading_weight: float = _setting(
        5.0, "λ per (turn / σ)²: a match turning odometry's prediction (a new reading) by more "
        "than σ is weighed against the optimum the compass search settles in from the "
        "prediction, each by its λ plus this times (its turn from the prediction / σ)²; of "
        "two valleys the scans fit alike, the nearer one stands (docs/method.md §6.1); 0: off",
        ge=0)
    odometry_heading_sigma: float = _setting(
        math.radians(1.0), "rad, σ of odometry's heading over a step, plus "
        "odometry_gate_share's heading share of its turn", gt=0)
    previous_scan_gain: float = _setting(
        0.1, "a match is lost when odometry's prediction (a new reading) fits the previous scan "
        "by more than this share of the points better than the match does: the keyframe's "
        "submap may hold a wall twice where the previous scan holds it once (docs/method.md "
        "§6.1); 1: never", ge=0, le=1)
    previous_scan_fit: float = _setting(
        0.75, "previous_scan_gain applies only where odometry's prediction fits at least this "
        "share of the points on the previous scan's surfaces (within track_inlier_distance "
        "plus the slope): the previous scan vouches for the prediction where the two overlap",
        ge=0, le=1)
    stale_turn_window: float = _setting(
        0.6, "rad: after odometry's reading came again unchanged (stale), a lost match is "
        "sought again this far either side in heading (a robot may have turned in place "
        "meanwhile)", gt=0, le=math.pi)
    pivot_search_rate: float = _setting(
        3.0, "rad/s: a lost match that no prior recovers, its odometry reading taken some time "
        "before the scan, is sought again over every heading the robot may have turned to "
        "since the last scan turning at most this fast (0: not)", ge=0, le=20.0)
    recovery_heading_step: float = _setting(
        0.05236, "rad (3°): a lost match sought again around a prior is also settled by the "
        "compass search alone, on the fine field, from headings this far apart across the "
        "box (0: not; else at least 0.005 rad); see recovery_seek_ratio", ge=0, le=math.pi)
    recovery_seek_ratio: float = _setting(
        0.9, "the compass search's match replaces the swarm's where its λ is below this "
        "share of the swarm's: a basin the swarm missed, not the same one polished",
        gt=0, le=1)
    stale_motion: bool = _setting(
        True, "a reading that came again unchanged (stale), within as many scans as the last "
        "new one took to come, predicts the translation per scan that reading showed, not "
        "its turn (false: no motion): odometry read less often than the scans (docs/method.md "
        "§6.1)")
    periodic_odometry_ratio: float = _setting(
        1.5, "odometry whose new readings come on average more than this many scan intervals "
        "apart is read at its own period: each reading's lag behind the scan that brought it "
        "is followed, and a stale reading continues the rate the last one showed for a period "
        "(docs/method.md §6.1, \"Odometry at its own period\"); 0: off", ge=0)
    period_restart_gaps: int = _setting(
        3, "this many gaps in a row between new odometry readings, each longer than twice the "
        "fewest scans one took, start the period's count again: the fewest was a stray (a "
        "reading one scan after another where scans were refused now and then)", ge=1,
        le=1000)
    window_margin: float = _setting(
        0.05, "a match within this share of its search box's edge found no optimum inside the "
        "box: tracking is lost", ge=0, lt=1)
    submap_nodes: int = _setting(
        3, "node scans in the keyframe reference: the newest and those just before it, placed "
        "by the graph (1: the newest alone)", ge=1, le=100)
    drop_moved_points: bool = _setting(
        True, "leave out of the keyframe reference the points another of its node scans saw "
        "through (its every ray passing within track_inlier_distance + track_inlier_slope "
        "per m of the point went on beyond it by more) and none saw a surface at: what stood "
        "there moved, a person walking (docs/method.md §6.1)")
    degeneracy_ratio: float = _setting(
        0.12, "a translation direction the match pins less than this share of the other is "
        "degenerate (a plain corridor's axis): the prediction stands in along it; 0: off",
        ge=0, lt=1)
    degenerate_information: float = _setting(
        0.1, "the least share of its information an edge keeps along a degenerate direction "
        "(there its value is odometry's prediction: 0.1 of 1/sigma_translation^2 is σ 0.079 m "
        "per edge, 0.16 m with the former sigma_translation of 5 cm)", gt=0, le=1)
    curvature_step: tuple[float, float] = _setting(
        (0.05, 0.01), "finite-difference steps (m, rad) of the match's curvature", gt=0)
    calibrate_odometry_scale: bool = _setting(
        True, "odometry's translation scale is fitted to the matches that pin the motion (a "
        "wheel a per cent off), and the node edges that took odometry's distance along a "
        "degenerate axis are brought to it in the next loop closure's optimisation "
        "(docs/method.md §6.1, \"Odometry's scale\")")
    odometry_scale_prior_travel: float = _setting(
        5.0, "m: the fit is blended with a scale of 1 worth this much travel (a short run "
        "keeps odometry as it reads)", ge=0)
    odometry_scale_limits: tuple[float, float] = _setting(
        (0.8, 1.25), "the least and greatest ratio of a step's scanned to read translation "
        "the fit tells apart (one beyond counts at the limit), and so the least and greatest "
        "scale it gives", gt=0)
    odometry_scale_dead_zone: float = _setting(
        0.005, "the fitted scale is shrunk towards 1 by this much (1 within it): the matches' "
        "own scale errs by a per-mille or two", ge=0, lt=0.2)
    spread_corrections: bool = _setting(
        True, "a scan between two nodes takes the graph's correction of both, shared by time "
        "(false: its tracking node's alone)")
    smooth_between_headings: bool = _setting(
        True, "the trajectory's scans between nodes take odometry's turns into their headings, "
        "weighed by the noise the run's own record shows of each (docs/method.md §6.2, "
        "\"Between-scan poses\"); the map and the nodes are as matched")
    smooth_between_positions: bool = _setting(
        True, "the trajectory's scans between nodes take odometry's motion into their "
        "positions, weighed as the headings are (docs/method.md §6.2, \"Between-scan poses\"); "
        "the map and the nodes are as matched")
    between_significance: float = _setting(
        2.0, "standard errors by which the between-scan matches' estimated noise (heading, "
        "position) must exceed 0 before odometry's motion is taken in (and its lower bound is "
        "what is used)", ge=0)
    between_gate: float = _setting(
        4.0, "σ: odometry's motion between two scans that disagrees with their matches by "
        "more is not taken in (a slipping wheel, a stamp out of step in a turn)", gt=0)
    between_min_pairs: int = _setting(
        30, "pairs of scans each kind of pair needs before the noise is estimated from it",
        ge=3)

    def __post_init__(self):
        super().__post_init__()
        if 0.0 < self.recovery_heading_step < MIN_HEADING_STEP:
            raise ConfigError("front_end.recovery_heading_step: must be 0 or >= "
                              f"{MIN_HEADING_STEP}, got {self.recovery_heading_step}")
        low, high = self.odometry_scale_limits
        if not low < 1.0 < high:
            raise ConfigError("front_end.odometry_scale_limits: must hold 1 (odometry as it "
                              f"reads) strictly between them, got {self.odometry_scale_limits}")


@dataclass(frozen=True)
class LoopClosureConfig(Section):
    """Seek_Loop_Closure, Alg. 7 (docs/method.md §5)."""

    KEY = "loop_closure"
    search_radius: float = _setting(10.0, "m: candidates beyond this are never considered", gt=0)
    closure_spacing: int = _setting(
        0, "nodes after one where a loop closure was kept whose loop search is skipped "
        "(0: every node is searched; docs/method.md §5, step 0)", ge=0)
    exclude_recent: int = _setting(10, "nodes just behind the new one are neighbours, not loops",
                                   ge=1)
    max_candidates: int = _setting(8, "gated candidates kept, closest first", ge=1, le=10_000)
    max_attempts: int = _setting(3, "alignments tried per new node", ge=1, le=10_000)
    sigma_translation: float = _setting(
        0.05, "m, σt of a loop edge's fixed information: a match against a submap the graph "
        "placed, looser than a node edge's (docs/method.md §4.2)", gt=0)
    sigma_rotation: float = _setting(0.02, "rad, σθ of a loop edge's fixed information", gt=0)
    chi2_gate: float = _setting(7.81, "χ²₃ at 95% on the new edge's own error after optimising",
                                gt=0)
    total_gate: float = _setting(16.27, "χ²₃ at 99.9% on the rise of the total error", gt=0)
    agreement_nodes: int = _setting(
        3, "a loop refused for the rise of the total alone is kept, judged by its own error, "
        "when a loop made from one of this many nodes before it was refused so too and puts "
        "the robot in the same place (docs/method.md §5, step 4); 0: never", ge=0)
    agreement_distance: float = _setting(
        0.1, "m: how near the two loops of agreement_nodes must place the node", gt=0)
    agreement_angle: float = _setting(
        0.02, "rad: how near in heading the two loops of agreement_nodes must place it", gt=0)
    max_given_up: int = _setting(
        3, "two loops in a row that the graph cannot absorb, and that agree as agreement_nodes "
        "says, are kept by giving up at most this many kept loops, those whose error the two "
        "raise the most (docs/method.md §5, step 4); 0: never", ge=0)
    min_strain: float = _setting(
        1.0, "a kept loop is given up for two that agree only when they raise its eᵀΩe by more "
        "than this", gt=0)
    min_inliers: float = _setting(0.8, "share of points on the submap's surfaces that accepts a "
                                  "loop match (strict: a wrong loop bends the map)", ge=0, le=1)
    min_overlap: float = _setting(
        0.3, "or: share of the new scan's points that land on surfaces the submap's scans saw "
        "(1: this test off)", ge=0, le=1)
    max_violations: float = _setting(
        0.03, "largest share of the points the submap's scans saw that may lie in space they "
        "saw through", ge=0, le=1)
    inlier_distance: float = _setting(0.2, "m: a point this near a seen surface is on it", gt=0)
    inlier_slope: float = _setting(0.01, "m per m of range added to inlier_distance (beams "
                                   "spread and graze)", ge=0)
    bearing_bins: int = _setting(720, "bearing bins of a submap scan's range image", ge=8,
                                le=100_000)
    position_floor: float = _setting(0.1, "m: minimum std of the relative position in the gate",
                                     ge=0)
    submap_nodes: int = _setting(2, "node scans either side of the candidate in its submap", ge=0,
                                 le=50)
    steady_turn_rate: float = _setting(
        0.5, "rad/s: a candidate whose node turned faster than this to the node before or after "
        "it (over the time between) gives its loop edge to the nearest node of its submap that "
        "turned no faster, the match re-expressed in that node's frame: a scan swept in a fast "
        "turn leaves its node's pose degrees off the map its scan draws, and every closure "
        "made to that node would repeat the offset (docs/method.md §5, step 3); 0: never",
        ge=0)
    search_window: tuple[float, float, float] = _setting(
        (2.0, 2.0, 0.5), "least half-widths of the loop match's box around the graph's estimate",
        gt=0)
    window_margin: float = _setting(
        0.05, "a loop match within this share of its box's edge is refused: the optimum lies at "
        "or beyond the box, not inside it", ge=0, lt=1)
    max_search_window: tuple[float, float, float] = _setting(
        (2.0, 2.0, 0.5), "largest half-widths: between the two, the box spans 3σ of the "
        "propagated relative pose", gt=0)
    degenerate_information: float = _setting(
        0.01, "the share of its information an ordinary loop edge keeps along a degenerate "
        "direction, where its value is the graph's own estimate, not a measurement (a wide "
        "search's proposal keeps the share its curvature supports; docs/method.md §5, step 3)",
        gt=0, le=1)
    # The wide search after a long drift (runtime/back_end/wide_loop_search.py; docs/method.md §5).
    wide_after: int = _setting(
        10, "nodes since the last kept closure after which a node whose ordinary search found "
        "nothing is searched for widely (0: never)", ge=0)
    wide_spacing: int = _setting(
        5, "nodes after a wide search that fitted the scan nowhere (new ground) before the "
        "next: the nodes between see much the same (1: every such node; docs/method.md §5, "
        "step 5)", ge=1)
    wide_min_gap: int = _setting(100, "nodes just behind the new one left out of the wide "
                                 "search's map (they drifted with it)", ge=1)
    wide_radius: float = _setting(60.0, "m: half-width of the square of positions searched "
                                  "around the graph's estimate, at the least", gt=0)
    wide_drift: float = _setting(
        0.2, "m of half-width per m of path since the last closure with the old map: the "
        "window grows with the drift it may have to bridge", ge=0)
    wide_max_radius: float = _setting(
        150.0, "m: the half-width the window grows to at most (its grids are sized for it)",
        gt=0)
    wide_angle: float = _setting(0.5, "rad: headings searched either side of the estimate's, at "
                                 "the least", gt=0)
    wide_turn_drift: float = _setting(
        0.001, "rad of that per m of path since the last closure with the old map: the "
        "heading's drift grows with it too", ge=0)
    wide_max_angle: float = _setting(
        1.0, "rad: the headings either side grow to at most this (its buffers are sized for it)",
        gt=0)
    wide_resolution: float = _setting(0.4, "m per cell of the wide search's hit grid", gt=0)
    wide_hit_sigma: float = _setting(0.2, "m: a point this far from a surface scores e^(-1/2)",
                                     gt=0)
    wide_surface_tolerance: float = _setting(
        0.04, "m: a run of a node scan's joined points is drawn into the wide search's hit grid "
        "as one segment while it passes this near every point it skips (0: one segment per "
        "pair of points)", ge=0)
    wide_levels: int = _setting(6, "pyramid levels above the hit grid (blocks of 2^levels cells)",
                                ge=1, le=10)
    wide_query_range: float = _setting(12.0, "m: the query's points farther from the node are "
                                       "not used (it also sets the heading step)", gt=0)
    wide_query_nodes: int = _setting(5, "node scans forming the query: the node's and those of "
                                     "the nodes just before it, placed by the graph", ge=1)
    wide_query_points: int = _setting(128, "query points at most (thinned evenly)", ge=8)
    wide_min_score: float = _setting(0.7, "mean hit value (0-1) a proposal needs", gt=0, le=1)
    wide_ratio: float = _setting(0.9, "a distinct pose scoring this share of the best makes the "
                                 "search refuse (a corridor, a repeated room)", gt=0, le=1)
    wide_distinct_distance: float = _setting(1.0, "m: poses farther apart are distinct", gt=0)
    wide_agreement: tuple[float, float] = _setting(
        (0.5, 0.05), "m, rad: a proposal needs a search sharing no scan with its own (of a node "
        "wide_query_nodes to twice that many back) to have found the same correction of the "
        "graph within these", gt=0)
    wide_refine_window: tuple[float, float, float] = _setting(
        (0.3, 0.3, 0.05), "half-widths of the swarm's alignment around a proposal", gt=0)
    wide_slice_cells: int = _setting(
        100_000, "grid cells a slice of the wide search renders or pools when the fixed-rate "
        "runtime spreads it over ticks (docs/runtime.md §3)", ge=1)
    wide_slice_nodes: int = _setting(
        100, "old node scans a slice of the wide search splats into its grid", ge=1)
    wide_slice_blocks: int = _setting(
        5000, "branch-and-bound blocks a slice of the wide search scores", ge=1)


@dataclass(frozen=True)
class RelocalizationConfig(Section):
    """The global search for a scan's pose in a saved map (docs/method.md §8)."""

    KEY = "relocalization"
    resolution: float = _setting(0.1, "m per cell of the hit grid the search scores on", gt=0)
    hit_sigma: float = _setting(0.1, "m: a point this far from a surface scores e^(-1/2) of "
                                "one on it", gt=0)
    exact_max_cells: int = _setting(
        400_000, "fine cells up to which one exact search runs on the fine grid; a larger map is "
        "searched coarse to fine (the exact search's cost grows with the map: 0.2-0.35 ms per "
        "1,000 cells measured)", ge=0)
    coarse_resolution: float = _setting(
        0.5, "m per cell of the first pass's hit grid on a map over exact_max_cells (the "
        "exhaustive search runs there, its candidates are refined at resolution)", gt=0)
    coarse_hit_sigma: float = _setting(0.4, "m: hit_sigma of the first pass's grid", gt=0)
    coarse_points: int = _setting(24, "query points of the first pass at most (thinned evenly)",
                                  ge=3)
    coarse_min_score: float = _setting(0.6, "mean hit value (0-1) a first-pass candidate needs",
                                       gt=0, le=1)
    coarse_ratio: float = _setting(0.9, "first-pass candidates score at least this share of "
                                   "its best", gt=0, le=1)
    coarse_candidates: int = _setting(64, "first-pass candidates refined at most (the best "
                                      "distinct ones)", ge=1)
    coarse_distinct_distance: float = _setting(
        0.5, "m: first-pass candidates nearer than this (and coarse_distinct_angle) are one",
        gt=0)
    coarse_distinct_angle: float = _setting(0.15, "rad: see coarse_distinct_distance", gt=0)
    refine_moves: int = _setting(3, "times a candidate's fine window may move to a best found on "
                                 "its edge", ge=0)
    levels: int = _setting(6, "pyramid levels above the exhaustive pass's hit grid (blocks of "
                           "2^levels cells)", ge=1, le=12)
    heading_levels: int = _setting(
        0, "top levels whose blocks also span 2, 4, … headings (looser bounds, fewer roots)",
        ge=0)
    map_range: float = _setting(30.0, "m: node scan points beyond are not rendered", gt=0)
    query_range: float = _setting(20.0, "m: query points beyond are not used (it also sets "
                                  "the heading step)", gt=0)
    query_spacing: float = _setting(0.2, "m: query points at least this far apart along the scan",
                                    ge=0)
    query_points: int = _setting(96, "query points at most (thinned evenly)", ge=8)
    min_score: float = _setting(0.7, "mean hit value (0-1) a pose needs to be an answer",
                                gt=0, le=1)
    ambiguity_ratio: float = _setting(
        0.9, "a distinct pose scoring at least this share of the best makes the answer "
        "'ambiguous'", gt=0, le=1)
    distinct_distance: float = _setting(
        0.7, "m: poses farther apart than this are distinct (a map's walls drawn twice this far "
        "apart are two places, not one: docs/method.md §8)", gt=0)
    distinct_angle: float = _setting(0.35, "rad: or turned more than this", gt=0)
    max_hypotheses: int = _setting(4, "distinct poses an ambiguous answer lists", ge=2)
    refine_window: tuple[float, float, float] = _setting(
        (0.15, 0.15, 0.03), "half-widths of the swarm's polish around the search's cell", gt=0)
    refine_nodes: int = _setting(5, "nearest node scans the polish matches against", ge=1)
    confirm_seconds: float = _setting(
        2.0, "s of scans over which candidate poses are tracked (or merged) before one is "
        "committed", ge=0)
    confirm_replay_scans: int = _setting(
        32, "scans since the search began that a new candidate is tracked back over by "
        "odometry (their share of confirm_seconds counts; docs/method.md §9)", ge=0)
    confirm_look: bool = _setting(
        True, "at the window's end the newest scan is searched again: candidates not among "
        "its poses are dropped; placed elsewhere alone, that place is confirmed instead")
    max_cells: int = _setting(50_000_000, "cells of the fine hit grid at most (memory: about "
                              "3 bytes per cell, docs/method.md §8)", ge=16)
    slice_blocks: int = _setting(
        5000, "branch-and-bound blocks a search scores between two looks at the clock when "
        "the runtime spreads it over ticks (about 0.2-0.7 ms; docs/method.md §9)", ge=1)


@dataclass(frozen=True)
class LocalizationConfig(Section):
    """Tracking in a saved map that never changes (docs/method.md §9)."""

    KEY = "localization"
    submap_nodes: int = _setting(5, "saved node scans nearest the pose that form the tracking "
                                 "reference", ge=1)
    heading_weight: float = _setting(
        2.0, "m per rad: a saved node's heading difference counts as this much distance when "
        "the nearest are chosen (a scan sees what its node faced)", ge=0)
    reanchor_distance: float = _setting(
        0.3, "m: the reference is rebuilt once a saved node is this much nearer than its anchor",
        ge=0)
    lost_scans: int = _setting(5, "poor matches in a row that mean the pose is lost (the global "
                               "search follows)", ge=1)
    max_held_scans: int = _setting(
        2, "matches in a row a committed pose (or a candidate being confirmed) may refuse for "
        "placing it farther from odometry's prediction than the front end's odometry_gate "
        "allows over the motion since the last match kept; the next is kept (0: no gate)", ge=0)
    merge_distance: float = _setting(
        0.2, "m: candidates that tracked this near each other are one (the worse is dropped)",
        ge=0)
    merge_angle: float = _setting(0.05, "rad: and turned at most this from each other", ge=0)
    confirm_misses: float = _setting(
        1.5, "after confirm_seconds, a candidate whose share of scan points off the saved "
        "surfaces exceeds this many times the best one's (plus confirm_miss_floor) is dropped",
        ge=1)
    confirm_miss_floor: float = _setting(
        0.003, "share of points off the surfaces any candidate may have beyond the best one's "
        "multiple (a nearly perfect best one then does not drop the other for a point or two)",
        ge=0)
    confirm_max_miss: float = _setting(
        0.3, "after confirm_seconds, a candidate with more than this share of its scan points "
        "off the saved surfaces is dropped whatever the others' (a wrong place seen from afar "
        "tracks, but misses many)", ge=0, le=1)
    corridor_max_miss: float = _setting(
        0.015, "a lone candidate no match has pinned along every direction (a place seen only "
        "as a corridor) is committed when at most this share of its points fell off the saved "
        "surfaces over the window; otherwise it is followed until a match pins it (a wrong "
        "map's corridor fits worse: docs/method.md §9)", ge=0, le=1)


@dataclass(frozen=True)
class OptimizerConfig(Section):
    """Gauss–Newton on the pose graph, Eq. 21 (docs/method.md §4.3)."""

    KEY = "optimizer"
    max_iterations: int = _setting(30, "Gauss–Newton steps before the Levenberg–Marquardt restart",
                                   ge=0)
    tolerance: float = _setting(1e-9, "converged when χ² falls by less than this share", gt=0)
    solver: str = _setting("ldl", "our compiled sparse LDLᵀ, or scipy's SuperLU", choices=SOLVERS)
    fill_ratio: float = _setting(4.0, "factor capacity in multiples of the largest upper "
                                 "triangle of H", ge=1)
    lm_initial_damping: float = _setting(1e-5, "Levenberg–Marquardt μ₀ as a share of max diag(H)",
                                         gt=0)
    lm_iteration_factor: int = _setting(10, "LM may take this many times max_iterations", ge=1)
    robust_loops: float | None = _setting(
        None, "Φ of dynamic covariance scaling on loop edges (an edge whose eᵀΩe exceeds Φ is "
        "down-weighted); none: plain least squares, as g2o", gt=0)


def _slam_optimizer() -> OptimizerConfig:
    # The SLAM's graph keeps a loop closure that later evidence contradicts from bending the
    # map: Φ = χ²₃ at 95%, so an edge the consistency test would pass keeps its full weight.
    return OptimizerConfig(robust_loops=7.81)


@dataclass(frozen=True)
class MapConfig(Section):
    """The occupancy grid, rendered from the nodes on demand."""

    KEY = "map"
    resolution: float = _setting(0.05, "m per cell", gt=0)
    max_range: float = _setting(30.0, "m: readings beyond are not drawn", gt=0)
    max_cells: int = _setting(4096, "cells per side at most (the map coarsens beyond)", ge=16,
                             le=65_536)
    margin: float = _setting(1.0, "m of unknown around what was seen", ge=0)


@dataclass(frozen=True)
class RuntimeConfig(Section):
    """The fixed-rate loop (docs/runtime.md §1)."""

    KEY = "runtime"
    rate_hz: float = _setting(10.0, "ticks per second", gt=0)
    tick_budget: float = _setting(0.015, "s of work per tick; the rest of the period is the "
                                  "robot's (must fit the period)", gt=0)
    schedule: str = _setting("budgeted", "'budgeted' consults the clock; 'lockstep' runs the "
                             "whole back end every tick (repeatable)", choices=SCHEDULES)
    front_end_share: float = _setting(0.6, "share of the tick budget the swarm plans for",
                                      gt=0, le=1)
    min_evaluation_share: float = _setting(0.25, "the swarm's budget never drops below this "
                                           "share", gt=0, le=1)
    front_end_cost_smoothing: float = _setting(
        0.1, "weight of the newest tick in the running front-end cost", gt=0, le=1)
    loop_queue: int = _setting(64, "nodes awaiting their loop search", ge=1, le=1_000_000)
    max_deferred_ticks: int = _setting(10, "a back-end slice waits at most this many ticks",
                                       ge=0)
    slice_cost_decay: float = _setting(
        0.97, "a slice's expected cost fades by this factor per tick", gt=0, le=1)
    slice_cost_memory: float = _setting(
        0.95, "a measured slice cost replaces the estimate unless this × the estimate is "
        "larger", gt=0, le=1)
    latency_window: int = _setting(4096, "recent tick latencies kept for the median / p99",
                                   ge=1, le=10_000_000)
    commit_memory: bool | None = _setting(
        None, "back every buffer with memory at start-up, and keep what is alive when the "
        "fixed-rate loop starts out of the garbage collector's passes (none: when budgeted)")
    malloc_mmap_threshold: int = _setting(
        131_072, "bytes: with commit_memory, glibc's mmap threshold is pinned here and its "
        "trim threshold at twice it, so freed memory goes back (0: the allocator's own)",
        ge=0, le=32 * 2**20)
    warm_up_scans: int = _setting(120, "synthetic scans the warm-up runs", ge=10, le=100_000)
    autosave_seconds: float = _setting(60.0, "s between session autosaves of a live run "
                                       "(written beside the loop, atomically; 0: none)", ge=0)

    def __post_init__(self):
        super().__post_init__()
        if self.tick_budget > 1.0 / self.rate_hz:
            raise ConfigError(f"runtime.tick_budget: must fit the period "
                              f"{1 / self.rate_hz:g} s, got {self.tick_budget}")

    @property
    def period(self) -> float:
        return 1.0 / self.rate_hz


@dataclass(frozen=True)
class SlamConfig(Section):
    """The whole tree (docs/configuration.md)."""

    KEY = ""
    sensor: SensorConfig = _section(SensorConfig, "the scanner")
    input: InputConfig = _section(InputConfig, "what a record must be to be used")
    capacity: CapacityConfig = _section(CapacityConfig, "capacities fixed at start-up")
    front_end: FrontEndConfig = _section(FrontEndConfig, "tracking and node insertion")
    matcher: MatcherConfig = _section(MatcherConfig, "the scan matcher (Alg. 5)")
    loop_closure: LoopClosureConfig = _section(LoopClosureConfig, "loop closure (Alg. 7)")
    optimizer: OptimizerConfig = _section(_slam_optimizer, "Gauss–Newton (Eq. 21)")
    relocalization: RelocalizationConfig = _section(RelocalizationConfig,
                                                    "the global search in a saved map")
    localization: LocalizationConfig = _section(LocalizationConfig,
                                                "tracking in a saved map (localization mode)")
    map: MapConfig = _section(MapConfig, "the occupancy grid")
    runtime: RuntimeConfig = _section(RuntimeConfig, "the fixed-rate loop")

    def with_optimizer(self, optimizer: str) -> SlamConfig:
        return override(self, {"matcher.swarm.optimizer": optimizer})


# ---------------------------------------------------------------------- presets
# Stored scans are sized for a scanner's samples per rotation with this margin and slack
# (rotations vary), and never below MIN_POINTS.
POINTS_MARGIN = 1.25
POINTS_SLACK = 64
MIN_POINTS = 400
# RPLidar models: (samples per second of the fastest scan mode, rotations per second, range m)
# as swarmslam.hardware.models has them (a test keeps the two equal; the core does not import hardware).
RPLIDAR_MODELS = {"a1": (4000, 5.5, 12.0), "a2": (7874, 10.0, 12.0), "a3": (15873, 10.0, 25.0),
                  "s1": (9259, 10.0, 40.0), "s2": (32000, 10.0, 30.0), "c1": (5000, 10.0, 12.0)}
# The simulator's LiDARs (swarmslam_sim.lidar.PRESETS): beams, min and max range.
SIMULATED_LIDARS = {"rplidar-a1": (360, 0.15, 12.0), "rplidar-a2": (720, 0.15, 12.0),
                    "lms200": (181, 0.05, 50.0)}


# A reference grid of 1,024 cells (51 m at 5 cm) holds every submap of a scanner reaching
# REACH_1024 m: its reach both ways and the few metres its submaps' nodes lie apart. A
# farther reach gets the default 2,048 (102 m: a SICK's returns to 51 m each way, which is
# what pins the heading in an open hall).
REACH_1024 = 20.0


def reach_grid_cells(reach: float) -> int:
    """``matcher.grid_cells`` for a scanner reaching ``reach`` metres."""
    return 1024 if reach <= REACH_1024 else MatcherConfig().grid_cells


def rplidar_points(samples_per_second: float, scan_hz: float) -> int:
    """Points per stored scan for a scanner of this rate (its fastest mode, with margin)."""
    return max(int(samples_per_second / scan_hz * POINTS_MARGIN) + POINTS_SLACK, MIN_POINTS)


def _rplidar(model: str) -> SlamConfig:
    sps, hz, reach = RPLIDAR_MODELS[model]
    # A rotation is one sweep, stamped at its end (swarmslam.hardware.driver).
    return override(SlamConfig(), {"sensor.name": f"rplidar-{model}", "sensor.max_range": reach,
                                   "sensor.max_points": rplidar_points(sps, hz),
                                   "sensor.sweep_seconds": 1.0 / hz, "map.max_range": reach,
                                   "matcher.grid_cells": reach_grid_cells(reach)})


def simulated(lidar: str = "rplidar-a1", beams: int | None = None, min_range: float | None = None,
              max_range: float | None = None) -> SlamConfig:
    """The simulator's SLAM: half the swarm budget of the dataset benchmarks (the simulated
    odometry always centres the search), the local stage tried first at odometry's prediction
    (``predict_first``), and no loop search for the 2 nodes after a closure
    (``closure_spacing``): random driving revisits a place at almost every node. Each was
    measured in the office explorations of ``swarmslam demo --seed N`` (pose error and steps
    per second); the current figures are the demo's own output and ``bench env``'s
    (docs/results.md)."""
    b, lo, hi = SIMULATED_LIDARS.get(lidar, SIMULATED_LIDARS["rplidar-a1"])
    reach = hi if max_range is None else max_range
    return override(SlamConfig(), {
        "sensor.name": f"sim-{lidar}", "sensor.max_points": beams or b,
        "sensor.min_range": lo if min_range is None else min_range,
        "sensor.max_range": reach, "matcher.grid_cells": reach_grid_cells(reach),
        "matcher.swarm.max_evaluations": 1500, "matcher.refine_evaluations": 300,
        "matcher.predict_first": 1.5, "loop_closure.closure_spacing": 2,
        "capacity.max_nodes": 4000, "capacity.max_edges": 16000, "capacity.max_scans": 20000})


PRESETS = {
    "sick-lms200": SlamConfig,  # 180° SICK-class scanners, as on the public logs (the default)
    **{f"rplidar-{m}": (lambda m=m: _rplidar(m)) for m in RPLIDAR_MODELS},
    **{f"sim-{name}": (lambda name=name: simulated(name)) for name in SIMULATED_LIDARS},
}
DEFAULT_PRESET = "sick-lms200"


def preset(name: str = DEFAULT_PRESET) -> SlamConfig:
    """A named configuration tree for a sensor the project knows."""
    try:
        return PRESETS[name]()
    except KeyError:
        raise ConfigError(f"unknown preset {name!r}; choose one of {', '.join(PRESETS)}") from None


# ---------------------------------------------------------------------- dict / TOML
NONE = "none"  # TOML has no null: an unset optional field is written as this string


def to_dict(config) -> dict:
    return dataclasses.asdict(config)


# Fields this version no longer has (docs/configuration.md; commit 449cba7 is the last with
# them) → the value that left their path off. A session or file
# that names one with that value reads as before; with another, it needs the older version.
REMOVED_FIELDS = {
    "front_end.odometry_noise_window": 0, "front_end.odometry_noise_min_steps": None,
    "front_end.odometry_turn_split": None, "front_end.odometry_sigma_floor": None,
    "front_end.match_heading_sigma": None, "front_end.odometry_scale_window": 0,
    "front_end.odometry_scale_min_steps": None, "front_end.odometry_scale_min_step": None,
    "front_end.odometry_scale_max_turn": None, "front_end.odometry_scale_confidence": None,
    "loop_closure.wide_total_gate": NONE,
    "loop_closure.degenerate_share": "floor", "loop_closure.stale_turn_window": None}


def _without_removed(data: dict, where: str) -> dict:
    """``data`` less the removed fields it names; one set to what turned its path on is
    refused by name. (None above: any value, its path being off by the other's.)"""
    kept = {}
    for key, value in data.items():
        path = f"{where}.{key}" if where else key
        if path not in REMOVED_FIELDS:
            kept[key] = value
        elif REMOVED_FIELDS[path] is not None and (NONE if value is None else value) \
                != REMOVED_FIELDS[path]:
            raise ConfigError(f"{path} = {value!r}: this opt-in was removed in this version "
                              f"(docs/configuration.md); remove the key, "
                              f"or use commit 449cba7")
    return kept


def from_dict(data: dict, base=None, cls=SlamConfig, where: str = ""):
    """``base`` (default: ``cls()``) with the fields ``data`` names changed; nested tables
    change nested sections. Unknown keys and ill-typed values raise :class:`ConfigError`."""
    base = cls() if base is None else base
    if not isinstance(data, dict):
        raise ConfigError(f"{where or 'config'}: must be a table, got {data!r}")
    hints = typing.get_type_hints(cls)
    meta = {f.name: f.metadata for f in fields(cls)}
    changes = {}
    for key, value in _without_removed(data, where).items():
        path = f"{where}.{key}" if where else key
        if key not in meta:
            raise ConfigError(f"{path}: unknown key (valid: {', '.join(sorted(meta))})")
        kind = hints[key]
        if is_dataclass(kind):
            changes[key] = from_dict(value, getattr(base, key), kind, path)
            continue
        if value == NONE:
            value = None
        elif _wants_float(kind):  # TOML writes 1 for 1.0
            value = tuple(map(_as_float, value)) if isinstance(value, list) else _as_float(value)
        elif isinstance(value, list):
            value = tuple(value)
        _check_value(path, value, kind, meta[key])
        changes[key] = value
    return replace(base, **changes)  # a cross-field rule raises ConfigError here


def _as_float(value):
    return float(value) if isinstance(value, int) and not isinstance(value, bool) else value


def _wants_float(hint) -> bool:
    args = [a for a in typing.get_args(hint) if a is not type(None)]
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        return bool(args) and _wants_float(args[0])
    if typing.get_origin(hint) is tuple:
        return bool(args) and args[0] is float
    return hint is float


def override(config, changes: dict):
    """``config`` with dotted keys changed: ``{"front_end.node_distance": 0.4}``."""
    nested: dict = {}
    for dotted, value in changes.items():
        node = nested
        *parents, leaf = dotted.split(".")
        for p in parents:
            node = node.setdefault(p, {})
        node[leaf] = value
    return from_dict(nested, config, type(config))


def _toml_value(value) -> str:
    if value is None:
        return f'"{NONE}"'
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, float):
        return repr(value)  # shortest round-trip form
    if isinstance(value, tuple):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    return str(value)


# The fields a user is expected to set (``config show --basic``): the scanner, how often a
# node is made, the swarm and its budget, the loop search's reach, the map, the rate and the
# capacities.
BASIC_FIELDS = frozenset({
    "sensor.name", "sensor.min_range", "sensor.max_range", "sensor.max_points",
    "capacity.max_nodes", "capacity.max_scans",
    "front_end.node_distance", "front_end.node_angle", "front_end.odometry_gate",
    "matcher.resolution", "matcher.swarm.optimizer", "matcher.swarm.max_evaluations",
    "loop_closure.search_radius", "loop_closure.min_inliers",
    "map.resolution", "map.max_range",
    "runtime.rate_hz", "runtime.tick_budget", "runtime.schedule", "runtime.autosave_seconds"})
# The internals of a stage — numerical steps, search pyramids, slice sizes, the scheduler's
# smoothing — named so that each can be read and changed, but not what a user tunes: ``config
# show`` leaves them out, ``config show --all`` lists them.
EXPERT_FIELDS = frozenset({
    "input.jump_slack", "input.turn_slack",
    "front_end.track_inlier_slope", "front_end.curvature_step", "front_end.window_margin",
    "front_end.stale_turn_window", "front_end.pivot_search_rate", "front_end.stale_motion",
    "front_end.recovery_heading_step", "front_end.recovery_seek_ratio",
    "front_end.odometry_scale_prior_travel", "front_end.odometry_scale_limits",
    "front_end.odometry_scale_dead_zone",
    "front_end.periodic_odometry_ratio", "front_end.period_restart_gaps",
    "front_end.degenerate_information",
    "front_end.odometry_gate_share", "front_end.odometry_gate_fit",
    "front_end.odometry_gate_explained", "front_end.odometry_gate_distance",
    "front_end.odometry_heading_weight", "front_end.odometry_heading_sigma",
    "front_end.previous_scan_gain", "front_end.previous_scan_fit",
    "front_end.between_significance", "front_end.between_gate", "front_end.between_min_pairs",
    "loop_closure.steady_turn_rate",
    "loop_closure.agreement_nodes", "loop_closure.agreement_distance",
    "loop_closure.agreement_angle", "loop_closure.max_given_up", "loop_closure.min_strain",
    "matcher.surface_bend", "matcher.surface_gap_ratio", "matcher.coarse_radius",
    "matcher.polish_step", "matcher.polish_halvings", "matcher.polish_evaluations",
    "matcher.occupied_radius", "matcher.robot_diameter",
    "matcher.predict_first", "matcher.refine_points", "matcher.swarm.stagnation_tol",
    "matcher.swarm.stall_tol",
    "matcher.swarm.target_value", "matcher.swarm.params",
    "loop_closure.bearing_bins", "loop_closure.position_floor", "loop_closure.window_margin",
    "loop_closure.max_violations", "loop_closure.inlier_slope",
    "loop_closure.degenerate_information", "loop_closure.wide_min_gap",
    "loop_closure.wide_spacing", "loop_closure.wide_drift", "loop_closure.wide_max_radius",
    "loop_closure.wide_turn_drift",
    "loop_closure.wide_max_angle", "loop_closure.wide_resolution", "loop_closure.wide_hit_sigma",
    "loop_closure.wide_surface_tolerance", "loop_closure.wide_levels",
    "loop_closure.wide_query_range", "loop_closure.wide_query_nodes",
    "loop_closure.wide_query_points", "loop_closure.wide_ratio",
    "loop_closure.wide_distinct_distance", "loop_closure.wide_agreement",
    "loop_closure.wide_refine_window", "loop_closure.wide_slice_cells",
    "loop_closure.wide_slice_nodes", "loop_closure.wide_slice_blocks",
    "optimizer.tolerance", "optimizer.fill_ratio", "optimizer.lm_initial_damping",
    "optimizer.lm_iteration_factor",
    "relocalization.exact_max_cells", "relocalization.coarse_resolution",
    "relocalization.coarse_hit_sigma", "relocalization.coarse_points",
    "relocalization.coarse_min_score", "relocalization.coarse_ratio",
    "relocalization.coarse_candidates", "relocalization.coarse_distinct_distance",
    "relocalization.coarse_distinct_angle", "relocalization.refine_moves",
    "relocalization.levels", "relocalization.heading_levels", "relocalization.query_spacing",
    "relocalization.refine_nodes", "relocalization.confirm_replay_scans",
    "relocalization.confirm_look", "relocalization.max_cells", "relocalization.slice_blocks",
    "localization.heading_weight", "localization.merge_distance", "localization.merge_angle",
    "localization.confirm_miss_floor",
    "runtime.min_evaluation_share", "runtime.front_end_cost_smoothing", "runtime.loop_queue",
    "runtime.max_deferred_ticks", "runtime.slice_cost_decay", "runtime.slice_cost_memory",
    "runtime.latency_window", "runtime.commit_memory", "runtime.malloc_mmap_threshold",
    "runtime.warm_up_scans"})
LEVELS = ("basic", "standard", "all")


def field_names(config=None) -> list[str]:
    """Every field's dotted name, in the tree's order."""
    names: list[str] = []

    def walk(section, table: str):
        for f in fields(section):
            key = f"{table}.{f.name}" if table else f.name
            if is_dataclass(getattr(section, f.name)):
                walk(getattr(section, f.name), key)
            else:
                names.append(key)

    walk(config if config is not None else SlamConfig(), "")
    return names


def shown(key: str, level: str = "all") -> bool:
    """Whether ``config show`` at ``level`` lists the field ``key``: basic the few a user is
    expected to set, standard all but the stages' internals, all every one."""
    if level not in LEVELS:
        raise ConfigError(f"unknown level {level!r}; choose one of {', '.join(LEVELS)}")
    return level == "all" or (key in BASIC_FIELDS if level == "basic"
                              else key not in EXPERT_FIELDS)


def to_toml(config, comments: bool = True, level: str = "all") -> str:
    """The tree as TOML, each field with its meaning as a comment; ``level`` (see
    :func:`shown`) leaves fields out — what is left out keeps its value when read back."""
    lines: list[str] = []

    def emit(section, table: str):
        plain = [f for f in fields(section) if not is_dataclass(getattr(section, f.name))
                 and shown(f"{table}.{f.name}" if table else f.name, level)]
        if table and plain:
            lines.append(f"\n[{table}]" if lines else f"[{table}]")
        for f in plain:
            line = f"{f.name} = {_toml_value(getattr(section, f.name))}"
            if comments and f.metadata.get("doc"):
                line = f"{line:<44} # {f.metadata['doc']}"
            lines.append(line)
        for f in fields(section):
            if is_dataclass(getattr(section, f.name)):
                emit(getattr(section, f.name), f"{table}.{f.name}" if table else f.name)

    emit(config, "")
    return "\n".join(lines) + "\n"


def _parse_toml(text: str, source: str) -> dict:
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{source}: not valid TOML: {exc}") from None


def _read_toml(path: Path) -> dict:
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: cannot read the configuration: {exc}") from None
    return _parse_toml(text, str(path))


def _from_data(data: dict, base: SlamConfig | None, source: str) -> SlamConfig:
    try:
        return from_dict(data, base if base is not None else SlamConfig())
    except ConfigError as exc:
        raise ConfigError(f"{source}: {exc}") from None


def from_toml(text: str, base: SlamConfig | None = None, source: str = "<toml>") -> SlamConfig:
    return _from_data(_parse_toml(text, source), base, source)


def load_config(path, base: SlamConfig | None = None) -> SlamConfig:
    """``base`` (default: the defaults) with the fields a TOML file names changed."""
    path = Path(path)
    return _from_data(_read_toml(path), base, str(path))


# A saved session keeps the configuration its map was made with. These sections steer only
# the search and the tracking in that map, never the map, so a newer setting may be used on
# an older map (docs/method.md §9).
SESSION_SECTIONS = ("localization", "relocalization")


def session_changes(path) -> dict:
    """The changes (dotted keys, for :func:`override`) a TOML file makes to a saved session's
    configuration. Only :data:`SESSION_SECTIONS` may change; any other table is refused."""
    path = Path(path)
    data = _read_toml(path)
    for table in data:
        if table not in SESSION_SECTIONS:
            raise ConfigError(
                f"{path}: [{table}]: a saved session keeps the configuration its map was made "
                f"with; only [{'], ['.join(SESSION_SECTIONS)}] may change")
    _from_data(data, None, str(path))  # every key and value checked here, naming the file
    return _dotted(data)


def session_settings(config: SlamConfig) -> dict:
    """``config``'s :data:`SESSION_SECTIONS` as changes (dotted keys, for :func:`override`):
    a saved session loaded with them searches and tracks as ``config`` does."""
    return _dotted({table: to_dict(getattr(config, table)) for table in SESSION_SECTIONS})


def _dotted(tables: dict) -> dict:
    return {f"{table}.{key}": value for table, section in tables.items()
            for key, value in section.items()}
