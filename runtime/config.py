"""One configuration tree for the SLAM runtime, validated when built, to and from TOML.

    config = preset("rplidar-a1")                         # or SlamConfig() for the defaults
    config = override(config, {"front_end.node_distance": 0.4})
    text = to_toml(config)                                # what ``swarmslam config show`` prints
    assert from_toml(text) == config

The tree is nested by component: ``sensor``, ``input``, ``capacity``, ``front_end`` (with its
``odometry_gate``, ``heading_prior``, ``previous_scan_check``, ``recovery``, ``odometry_scale``
and ``between_scans``), ``matcher`` (with its ``swarm``), ``loop_closure`` (with its
``agreement`` and ``wide_search``), ``optimizer`` (Gauss–Newton), ``relocalization``,
``localization``, ``map`` and ``runtime``. Every setting a user may set is a field here,
documented where it is declared (``doc``, with its level); a stage's internals are constants
named beside their use. Every field is checked
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


# A field's level, which ``config show`` lists: basic the few a user is expected to set
# (the scanner, how often a node is made, the swarm's budget, the map, the rate, the
# capacities), standard what a user tuning a robot may change, expert a stage's internals.
BASIC, STANDARD, EXPERT = "basic", "standard", "expert"
DOC_LENGTH = 120  # characters a field's doc may have: unit, what, what its default means


def doc(text: str, *, gt=None, ge=None, le=None, lt=None, choices=None, level=STANDARD):
    """Field metadata: what the field means, the bounds that ``validate`` enforces and the
    level at which ``config show`` lists it."""
    return {"doc": text, "gt": gt, "ge": ge, "le": le, "lt": lt, "choices": choices,
            "level": level}


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
    optimizer: str = _setting("abc", "the swarm method", choices=OPTIMIZERS, level=BASIC)
    members: int | None = _setting(
        None, "PSO particles / ABC colony (2 × food sources) / fireflies; none: Table 1", ge=2,
        le=10_000)
    params: tuple[float, ...] | None = _setting(
        None, "the method's parameters (PSO w c1 c2; ABC limit; FA β0 γ α); none: Table 1",
        level=EXPERT)
    max_iterations: int = _setting(1000, "halting rule 1: iterations", ge=1, le=1_000_000,
                                   level=EXPERT)
    stagnation_iterations: int = _setting(50, "halting rule 2: iterations without gain", ge=1,
                                         le=1_000_000, level=EXPERT)
    stagnation_tol: float = _setting(1e-6, "what counts as a gain for rule 2", ge=0,
                                     level=EXPERT)
    target_value: float = _setting(1e-6, "halting rule 3: stop below this objective value",
                                   level=EXPERT)
    max_evaluations: int = _setting(0, "evaluation budget (0: the halting rules only)", ge=0,
                                   le=100_000_000, level=BASIC)
    stall_iterations: int = _setting(
        0, "iterations in a row the best may gain no more than stall_tol before the swarm stops "
        "(0: off; not for FA)", ge=0, le=1_000_000, level=EXPERT)
    stall_tol: float = _setting(0.0, "what counts as a gain in the best for the stall rule "
                                "(objective's units)", ge=0, level=EXPERT)

    @property
    def kind(self) -> int:
        """The method's code in the compiled kernels (its index in ``OPTIMIZERS``)."""
        return OPTIMIZERS.index(self.optimizer)

    @property
    def stall_window(self) -> int:
        """The stall rule's iterations as the method runs them: ``stall_iterations``, but 0
        (off) for the firefly swarm. Its brightest member only walks at random (Eq. 12), so
        its best gains when another overtakes it, after runs without a gain that the rule
        takes for a settled swarm (docs/method.md §2)."""
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
    resolution: float = _setting(0.05, "m per distance-field / local-grid cell", gt=0,
                                 level=BASIC)
    kernel: str = _setting("cauchy", "per-point cost: 'paper' is Eq. 14, 'cauchy' "
                           "log(1 + d²/c²)", choices=KERNEL_NAMES)
    cauchy_scale: float = _setting(0.07, "m, c of the Cauchy kernel", gt=0, level=EXPERT)
    field_radius: float = _setting(0.5, "m: distances exact below, truncated above", gt=0,
                                   level=EXPERT)
    max_gap: float = _setting(1.0, "m: reference points closer than this form a surface", ge=0)
    surface_bend: float = _setting(
        0.05236, "rad: farther neighbours still form a surface where the pairs either side "
        "continue their line within this (0: off)", ge=0, lt=math.pi / 2, level=EXPERT)
    coarse_resolution: float = _setting(0.1, "m, the global stage's coarse field (0: none)", ge=0,
                                        level=EXPERT)
    stride: int = _setting(2, "the global stage uses every stride-th point", ge=1, level=EXPERT)
    global_points: int = _setting(
        96, "points the global stage scores at most; a denser scan's stride grows (0: stride "
        "alone)", ge=0, level=EXPERT)
    refine_points: int = _setting(
        192, "points the local stage scores at most, by a stride (0: all)", ge=0, level=EXPERT)
    refine_evaluations: int = _setting(600, "budget of the local stage (0: none)", ge=0,
                                      le=10_000_000)
    refine_window: tuple[float, float, float] = _setting(
        (0.15, 0.15, 0.08), "half-widths (m, m, rad) of the local stage", gt=0, level=EXPERT)
    polish_evaluations: int = _setting(
        300, "budget of the compass search that settles the match on the fine field (0: none)",
        ge=0, le=10_000_000, level=EXPERT)
    predict_first: float = _setting(
        0.0, "with a guess, the local stage runs first; it stands at λ ≤ this × the running "
        "mean λ (0: off)", ge=0, level=EXPERT)
    search_window: tuple[float, float, float] = _setting(
        (2.0, 2.0, 1.6), "half-widths of the box without a guess (m, m, rad)", gt=0)
    guess_window: tuple[float, float, float] = _setting(
        (0.3, 0.3, 0.3), "half-widths of the box around a guess (m, m, rad)", gt=0)
    grid_cells: int = _setting(2048, "cells per side of the reference grids; a wider submap "
                              "keeps what lies within half of it", ge=8, le=8192)
    scan_to_map: bool = _setting(False, "Alg. 5's scan-to-map fallback (Eq. 16)", level=EXPERT)
    robot_diameter: float = _setting(0.35, "m, for Eq. 17", gt=0, level=EXPERT)

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
    name: str = _setting("sick-lms200", "the preset this came from (a label)", level=BASIC)
    min_range: float = _setting(0.05, "m: nearer readings are dropped", ge=0, level=BASIC)
    max_range: float = _setting(80.0, "m: readings at or beyond are 'no return'", gt=0,
                                level=BASIC)
    max_points: int = _setting(1440, "points kept per scan (≥ samples per rotation)", ge=1,
                              le=100_000, level=BASIC)
    sweep_seconds: float = _setting(
        0.0, "s from a scan's first beam to its last (a rotating scanner's sweep; 0: all at "
        "once; docs/method.md §6.1)", ge=0, le=1.0)
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


@dataclass(frozen=True)
class CapacityConfig(Section):
    """What grows with time, fixed at start-up (docs/runtime.md §4)."""

    KEY = "capacity"
    max_nodes: int = _setting(5000, "pose-graph nodes", ge=2, le=1_000_000, level=BASIC)
    max_edges: int = _setting(20000, "pose-graph edges (≈ 1 + loops per node)", ge=1,
                             le=10_000_000)
    max_scans: int = _setting(100000, "trajectory poses kept (one per scan)", ge=1,
                             le=100_000_000, level=BASIC)


@dataclass(frozen=True)
class OdometryGateConfig(Section):
    """The odometry gate and its exceptions (docs/method.md §6.1, "The odometry gate")."""

    KEY = "front_end.odometry_gate"
    enabled: bool = _setting(True, "a match correcting odometry by more than the tolerance is "
                             "lost")
    tolerance: tuple[float, float] = _setting(
        (0.15, math.radians(5.0)), "m, rad the gate allows, plus the shares below", ge=0,
        level=BASIC)
    share: tuple[float, float] = _setting(
        (0.2, 0.35), "shares of odometry's step (translation, rotation) added to the tolerance",
        ge=0, level=EXPERT)
    fit: float = _setting(
        0.1, "against a stale reading, a refused match stands if it fits this share more points "
        "than odometry (1: never)", ge=0, le=1, level=EXPERT)
    explained: float = _setting(
        0.45, "a match refused for its heading stands if it fits over this share of the points "
        "odometry misses (1: never)", ge=0, le=1, level=EXPERT)


@dataclass(frozen=True)
class HeadingPriorConfig(Section):
    """Odometry's heading as a prior on a turning match (docs/method.md §6.1)."""

    KEY = "front_end.heading_prior"
    enabled: bool = _setting(True, "of two headings the scans fit alike, the one nearer "
                             "odometry's stands", level=EXPERT)
    weight: float = _setting(
        5.0, "λ per (turn from odometry's prediction / σ)² added to a turning match's λ", gt=0,
        level=EXPERT)


@dataclass(frozen=True)
class PreviousScanCheckConfig(Section):
    """The previous-scan check (docs/method.md §6.1)."""

    KEY = "front_end.previous_scan_check"
    enabled: bool = _setting(True, "a match the previous scan fits worse than odometry's "
                             "prediction is lost", level=EXPERT)
    gain: float = _setting(
        0.1, "share of the points by which odometry must fit the previous scan better",
        ge=0, le=1, level=EXPERT)


@dataclass(frozen=True)
class RecoveryConfig(Section):
    """The searches that seek a lost match again (docs/method.md §6.1, "Recovery")."""

    KEY = "front_end.recovery"
    stale_turn_window: float = _setting(
        0.6, "rad either side in heading sought after a stale odometry reading", gt=0,
        le=math.pi, level=EXPERT)
    pivot_search_rate: float = _setting(
        3.0, "rad/s: headings a robot turning this fast reached since its last reading are "
        "sought (0: not)", ge=0, le=20.0, level=EXPERT)
    heading_step: float = _setting(
        0.05236, "rad between the compass search's starts across a prior's box (0: not; else "
        "≥ 0.005)", ge=0, le=math.pi, level=EXPERT)

    def __post_init__(self):
        super().__post_init__()
        if 0.0 < self.heading_step < MIN_HEADING_STEP:
            raise ConfigError("front_end.recovery.heading_step: must be 0 or >= "
                              f"{MIN_HEADING_STEP}, got {self.heading_step}")


@dataclass(frozen=True)
class OdometryScaleConfig(Section):
    """Odometry's translation scale fitted to the matches (docs/method.md §6.1, "Odometry's
    scale")."""

    KEY = "front_end.odometry_scale"
    enabled: bool = _setting(True, "fit odometry's scale; the degenerate edges take it at the "
                             "next loop closure")
    limits: tuple[float, float] = _setting(
        (0.8, 1.25), "least and greatest scale the fit gives (a step beyond counts at the "
        "limit)", gt=0, level=EXPERT)

    def __post_init__(self):
        super().__post_init__()
        low, high = self.limits
        if not low < 1.0 < high:
            raise ConfigError("front_end.odometry_scale.limits: must hold 1 (odometry as it "
                              f"reads) strictly between them, got {self.limits}")


@dataclass(frozen=True)
class BetweenScansConfig(Section):
    """Poses of the scans between nodes (docs/method.md §6.2, "Between-scan poses")."""

    KEY = "front_end.between_scans"
    headings: bool = _setting(True, "odometry's turns weighed into the headings by the run's "
                              "own noise")
    positions: bool = _setting(True, "odometry's motion weighed into the positions likewise")
    min_pairs: int = _setting(
        30, "pairs of scans each kind needs before its noise is estimated", ge=3, level=EXPERT)


@dataclass(frozen=True)
class FrontEndConfig(Section):
    """Tracking against the keyframe (Alg. 5) and node insertion (Alg. 6); docs/method.md
    §6.1."""

    KEY = "front_end"
    odometry_gate: OdometryGateConfig = _section(OdometryGateConfig, "the odometry gate")
    heading_prior: HeadingPriorConfig = _section(HeadingPriorConfig, "odometry's heading prior")
    previous_scan_check: PreviousScanCheckConfig = _section(PreviousScanCheckConfig,
                                                            "the previous-scan check")
    recovery: RecoveryConfig = _section(RecoveryConfig, "recovery of a lost match")
    odometry_scale: OdometryScaleConfig = _section(OdometryScaleConfig, "odometry's scale")
    between_scans: BetweenScansConfig = _section(BetweenScansConfig, "between-scan poses")
    node_distance: float = _setting(0.5, "m moved since the last node that makes a node (Alg. 6)",
                                    gt=0, level=BASIC)
    node_angle: float = _setting(0.5, "rad turned since the last node that makes a node", gt=0,
                                 level=BASIC)
    information: str = _setting(
        "fixed", "edge information: 'fixed' diag(1/σt², 1/σt², 1/σθ²), 'paper' Eq. 20's I/σλ²",
        choices=INFORMATION_MODES, level=EXPERT)
    sigma_translation: float = _setting(0.025, "m, σt of a node edge's fixed information",
                                        gt=0)
    sigma_rotation: float = _setting(0.005, "rad, σθ of a node edge's fixed information", gt=0)
    min_track_inliers: float = _setting(
        0.5, "share of points on the keyframe's surfaces below which tracking is lost",
        ge=0, le=1)
    track_inlier_distance: float = _setting(0.2, "m: a point this near a surface is an inlier",
                                            gt=0)
    stale_motion: bool = _setting(
        True, "a stale odometry reading predicts the last reading's translation per scan, not "
        "its turn", level=EXPERT)
    periodic_odometry_ratio: float = _setting(
        1.5, "odometry read more than this many scans apart is followed at its own period "
        "(0: off)", ge=0, level=EXPERT)
    submap_nodes: int = _setting(
        3, "node scans in the keyframe reference: the newest and those before it", ge=1, le=100)
    drop_moved_points: bool = _setting(
        True, "points another node scan saw through, and none saw, are left out of the "
        "reference", level=EXPERT)
    degeneracy_ratio: float = _setting(
        0.12, "a direction pinned below this share of the other is degenerate; the prediction "
        "stands along it (0: off)", ge=0, lt=1, level=EXPERT)
    degenerate_information: float = _setting(
        0.1, "least share of its information an edge keeps along a degenerate direction", gt=0,
        le=1, level=EXPERT)
    spread_corrections: bool = _setting(
        True, "a scan between two nodes takes both nodes' corrections, shared by time",
        level=EXPERT)


@dataclass(frozen=True)
class AgreementConfig(Section):
    """Loops kept because two agree (docs/method.md §5, step 4)."""

    KEY = "loop_closure.agreement"
    enabled: bool = _setting(True, "a loop refused for the total's rise alone stands when an "
                             "earlier one agrees", level=EXPERT)
    nodes: int = _setting(3, "nodes back the agreeing loop may come from", ge=1, level=EXPERT)
    max_given_up: int = _setting(
        3, "kept loops a group of agreeing ones the graph cannot absorb may give up (0: none)",
        ge=0, level=EXPERT)


@dataclass(frozen=True)
class WideSearchConfig(Section):
    """The wide loop search after a long drift (docs/method.md §5, step 5)."""

    KEY = "loop_closure.wide_search"
    enabled: bool = _setting(True, "search widely when the ordinary search finds nothing after "
                             "a drift")
    after: int = _setting(10, "nodes since the last kept closure before a wide search", ge=1)
    spacing: int = _setting(
        5, "nodes after a wide search that fitted nowhere before the next", ge=1, level=EXPERT)
    min_gap: int = _setting(100, "nodes just behind the new one left out of the searched map",
                            ge=1, level=EXPERT)
    radius: float = _setting(60.0, "m: least half-width of the positions searched", gt=0)
    drift: float = _setting(0.2, "m of half-width per m of path since the last closure", ge=0,
                            level=EXPERT)
    max_radius: float = _setting(150.0, "m: greatest half-width (the grids are sized for it)",
                                 gt=0, level=EXPERT)
    angle: float = _setting(0.5, "rad: least headings searched either side of the estimate",
                            gt=0, level=EXPERT)
    turn_drift: float = _setting(0.001, "rad of that per m of path since the last closure", ge=0,
                                 level=EXPERT)
    max_angle: float = _setting(1.0, "rad: greatest headings either side (buffers are sized "
                                "for it)", gt=0, level=EXPERT)
    resolution: float = _setting(0.4, "m per cell of the hit grid", gt=0, level=EXPERT)
    query_nodes: int = _setting(5, "node scans forming the query: the node's and those before "
                                "it", ge=1, level=EXPERT)
    min_score: float = _setting(0.7, "mean hit value (0-1) a proposal needs", gt=0, le=1,
                                level=EXPERT)
    slice_cells: int = _setting(100_000, "grid cells a slice renders or pools in the fixed-rate "
                                "runtime", ge=1, level=EXPERT)
    slice_nodes: int = _setting(100, "old node scans a slice splats into the grid", ge=1,
                                level=EXPERT)
    slice_blocks: int = _setting(5000, "branch-and-bound blocks a slice scores", ge=1,
                                 level=EXPERT)


@dataclass(frozen=True)
class LoopClosureConfig(Section):
    """Seek_Loop_Closure, Alg. 7 (docs/method.md §5)."""

    KEY = "loop_closure"
    agreement: AgreementConfig = _section(AgreementConfig, "loops kept because two agree")
    wide_search: WideSearchConfig = _section(WideSearchConfig, "the wide search")
    search_radius: float = _setting(10.0, "m: candidates beyond this are never considered", gt=0,
                                    level=BASIC)
    closure_spacing: int = _setting(
        0, "nodes after a kept closure whose loop search is skipped (0: none skipped)", ge=0)
    exclude_recent: int = _setting(10, "nodes just behind the new one are neighbours, not loops",
                                   ge=1)
    max_candidates: int = _setting(8, "gated candidates kept, closest first", ge=1, le=10_000,
                                   level=EXPERT)
    max_attempts: int = _setting(3, "alignments tried per new node", ge=1, le=10_000)
    sigma_translation: float = _setting(0.05, "m, σt of a loop edge's fixed information", gt=0,
                                        level=EXPERT)
    sigma_rotation: float = _setting(0.02, "rad, σθ of a loop edge's fixed information", gt=0,
                                     level=EXPERT)
    chi2_gate: float = _setting(7.81, "χ²₃ at 95% on the new edge's own error after optimising",
                                gt=0)
    total_gate: float = _setting(16.27, "χ²₃ at 99.9% on the rise of the total error", gt=0)
    min_inliers: float = _setting(0.8, "share of points on the submap's surfaces that accepts a "
                                  "loop match", ge=0, le=1, level=BASIC)
    min_overlap: float = _setting(
        0.3, "or: share of points on surfaces the submap's scans saw (1: this test off)", ge=0,
        le=1)
    inlier_distance: float = _setting(0.2, "m: a point this near a seen surface is on it", gt=0,
                                      level=EXPERT)
    submap_nodes: int = _setting(2, "node scans either side of the candidate in its submap", ge=0,
                                 le=50, level=EXPERT)
    steady_turn_rate: float = _setting(
        0.5, "rad/s: a candidate turning faster gives its edge to a steadier submap node (0: "
        "never)", ge=0, level=EXPERT)
    search_window: tuple[float, float, float] = _setting(
        (2.0, 2.0, 0.5), "least half-widths of the loop match's box around the graph's estimate",
        gt=0, level=EXPERT)
    max_search_window: tuple[float, float, float] = _setting(
        (2.0, 2.0, 0.5), "greatest half-widths; between, the box spans 3σ of the relative pose",
        gt=0, level=EXPERT)
    degenerate_information: float = _setting(
        0.01, "share of its information a loop edge keeps along a degenerate direction", gt=0,
        le=1, level=EXPERT)


@dataclass(frozen=True)
class RelocalizationConfig(Section):
    """The global search for a scan's pose in a saved map (docs/method.md §8)."""

    KEY = "relocalization"
    resolution: float = _setting(0.1, "m per cell of the hit grid the search scores on", gt=0)
    hit_sigma: float = _setting(0.1, "m: a point this far from a surface scores e^(-1/2)", gt=0,
                                level=EXPERT)
    exact_max_cells: int = _setting(
        400_000, "fine cells up to which one exact search runs; a larger map is searched coarse "
        "to fine", ge=0, level=EXPERT)
    coarse_resolution: float = _setting(0.5, "m per cell of the coarse first pass's hit grid",
                                        gt=0, level=EXPERT)
    levels: int = _setting(6, "pyramid levels above the exhaustive pass's hit grid", ge=1, le=12,
                           level=EXPERT)
    map_range: float = _setting(30.0, "m: node scan points beyond are not rendered", gt=0,
                                level=EXPERT)
    query_range: float = _setting(20.0, "m: query points beyond are not used (it sets the "
                                  "heading step)", gt=0, level=EXPERT)
    query_points: int = _setting(96, "query points at most (thinned evenly)", ge=8, level=EXPERT)
    min_score: float = _setting(0.7, "mean hit value (0-1) a pose needs to be an answer",
                                gt=0, le=1)
    ambiguity_ratio: float = _setting(
        0.9, "a distinct pose scoring this share of the best makes the answer 'ambiguous'", gt=0,
        le=1)
    distinct_distance: float = _setting(0.7, "m: poses farther apart are distinct", gt=0,
                                        level=EXPERT)
    distinct_angle: float = _setting(0.35, "rad: or turned more than this", gt=0, level=EXPERT)
    max_hypotheses: int = _setting(4, "distinct poses an ambiguous answer lists", ge=2,
                                   level=EXPERT)
    refine_window: tuple[float, float, float] = _setting(
        (0.15, 0.15, 0.03), "half-widths of the swarm's polish around the search's cell", gt=0,
        level=EXPERT)
    confirm_seconds: float = _setting(
        2.0, "s of scans over which candidates are tracked before one is committed", ge=0)
    confirm_replay_scans: int = _setting(
        32, "scans since the search began that a new candidate is tracked back over", ge=0,
        level=EXPERT)
    confirm_look: bool = _setting(
        True, "the newest scan is searched again at the window's end; candidates not among its "
        "poses are dropped", level=EXPERT)
    max_cells: int = _setting(50_000_000, "cells of the fine hit grid at most (about 3 bytes "
                              "each)", ge=16, level=EXPERT)
    slice_blocks: int = _setting(
        5000, "branch-and-bound blocks a search scores between two looks at the clock", ge=1,
        level=EXPERT)


@dataclass(frozen=True)
class LocalizationConfig(Section):
    """Tracking in a saved map that never changes (docs/method.md §9)."""

    KEY = "localization"
    submap_nodes: int = _setting(5, "saved node scans nearest the pose that form the tracking "
                                 "reference", ge=1)
    lost_scans: int = _setting(5, "poor matches in a row that mean the pose is lost", ge=1)
    max_held_scans: int = _setting(
        2, "matches in a row the odometry gate may refuse before the next is kept (0: no gate)",
        ge=0, level=EXPERT)
    confirm_misses: float = _setting(
        1.5, "a candidate missing this many times the best one's share of points is dropped",
        ge=1, level=EXPERT)
    confirm_max_miss: float = _setting(
        0.3, "a candidate missing more than this share of its points is dropped", ge=0, le=1,
        level=EXPERT)
    corridor_max_miss: float = _setting(
        0.015, "a lone candidate pinned only as a corridor is committed at this share of misses "
        "at most", ge=0, le=1, level=EXPERT)


@dataclass(frozen=True)
class OptimizerConfig(Section):
    """Gauss–Newton on the pose graph, Eq. 21 (docs/method.md §4.3)."""

    KEY = "optimizer"
    max_iterations: int = _setting(30, "Gauss–Newton steps before the Levenberg–Marquardt restart",
                                   ge=0, level=EXPERT)
    tolerance: float = _setting(1e-9, "converged when χ² falls by less than this share", gt=0,
                                level=EXPERT)
    solver: str = _setting("ldl", "our compiled sparse LDLᵀ, or scipy's SuperLU", choices=SOLVERS)
    fill_ratio: float = _setting(4.0, "factor capacity in multiples of the largest upper "
                                 "triangle of H", ge=1, level=EXPERT)
    robust_loops: float | None = _setting(
        None, "Φ of dynamic covariance scaling on loop edges; none: plain least squares, as g2o",
        gt=0)


def _slam_optimizer() -> OptimizerConfig:
    # The SLAM's graph keeps a loop closure that later evidence contradicts from bending the
    # map: Φ = χ²₃ at 95%, so an edge the consistency test would pass keeps its full weight.
    return OptimizerConfig(robust_loops=7.81)


@dataclass(frozen=True)
class MapConfig(Section):
    """The occupancy grid, rendered from the nodes on demand."""

    KEY = "map"
    resolution: float = _setting(0.05, "m per cell", gt=0, level=BASIC)
    max_range: float = _setting(30.0, "m: readings beyond are not drawn", gt=0, level=BASIC)
    max_cells: int = _setting(4096, "cells per side at most (the map coarsens beyond)", ge=16,
                             le=65_536)
    margin: float = _setting(1.0, "m of unknown around what was seen", ge=0)


@dataclass(frozen=True)
class RuntimeConfig(Section):
    """The fixed-rate loop (docs/runtime.md §1)."""

    KEY = "runtime"
    rate_hz: float = _setting(10.0, "ticks per second", gt=0, level=BASIC)
    tick_budget: float = _setting(0.015, "s of work per tick; the rest of the period is the "
                                  "robot's", gt=0, level=BASIC)
    schedule: str = _setting("budgeted", "'budgeted' consults the clock; 'lockstep' runs the "
                             "whole back end every tick", choices=SCHEDULES, level=BASIC)
    front_end_share: float = _setting(0.6, "share of the tick budget the swarm plans for",
                                      gt=0, le=1, level=EXPERT)
    loop_queue: int = _setting(64, "nodes awaiting their loop search", ge=1, le=1_000_000,
                               level=EXPERT)
    max_deferred_ticks: int = _setting(10, "a back-end slice waits at most this many ticks",
                                       ge=0, level=EXPERT)
    latency_window: int = _setting(4096, "recent tick latencies kept for the median / p99",
                                   ge=1, le=10_000_000, level=EXPERT)
    commit_memory: bool | None = _setting(
        None, "back every buffer with memory at start-up, out of the collector's passes (none: "
        "when budgeted)", level=EXPERT)
    autosave_seconds: float = _setting(60.0, "s between session autosaves of a live run (0: "
                                       "none)", ge=0, level=BASIC)

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


# ---------------------------------------------------------------------- older names
# Every name a configuration once had and this one does not, in one place: files, dotted
# overrides and sessions written by an older version read through :func:`upgrade_names`
# (docs/configuration.md, "Older names").
#
# Fields this version no longer has (commit 449cba7 is the last with them) → the value that
# left their path off. A session or file that names one with that value reads as before;
# with another, it needs the older version. (None: any value, its path being off by another's.)
REMOVED_FIELDS = {
    "front_end.odometry_noise_window": 0, "front_end.odometry_noise_min_steps": None,
    "front_end.odometry_turn_split": None, "front_end.odometry_sigma_floor": None,
    "front_end.match_heading_sigma": None, "front_end.odometry_scale_window": 0,
    "front_end.odometry_scale_min_steps": None, "front_end.odometry_scale_min_step": None,
    "front_end.odometry_scale_max_turn": None, "front_end.odometry_scale_confidence": None,
    "loop_closure.wide_total_gate": NONE,
    "loop_closure.degenerate_share": "floor", "loop_closure.stale_turn_window": None}
# Fields that became constants named beside their use (a stage's internals no user set):
# name → the constant's value. A file or session naming one at that value reads as before.
FIXED_FIELDS = {
    "input.jump_slack": 1.0, "input.turn_slack": 1.0,
    "front_end.track_inlier_slope": 0.01, "front_end.weak_information_factor": 9.0,
    "front_end.odometry_gate_distance": 0.15,
    "front_end.odometry_heading_sigma": math.radians(1.0), "front_end.previous_scan_fit": 0.75,
    "front_end.recovery_seek_ratio": 0.9, "front_end.window_margin": 0.05,
    "front_end.curvature_step": (0.05, 0.01), "front_end.period_restart_gaps": 3,
    "front_end.odometry_scale_prior_travel": 5.0, "front_end.odometry_scale_dead_zone": 0.005,
    "front_end.between_significance": 2.0, "front_end.between_gate": 4.0,
    "matcher.surface_gap_ratio": 2.0, "matcher.coarse_radius": 0.6,
    "matcher.polish_step": (0.01, 0.005), "matcher.polish_halvings": 6,
    "matcher.occupied_radius": 0.1,
    "loop_closure.agreement_distance": 0.1, "loop_closure.agreement_angle": 0.02,
    "loop_closure.min_strain": 1.0, "loop_closure.max_violations": 0.03,
    "loop_closure.inlier_slope": 0.01, "loop_closure.bearing_bins": 720,
    "loop_closure.position_floor": 0.1, "loop_closure.window_margin": 0.05,
    "loop_closure.wide_hit_sigma": 0.2, "loop_closure.wide_surface_tolerance": 0.04,
    "loop_closure.wide_levels": 6, "loop_closure.wide_query_range": 12.0,
    "loop_closure.wide_query_points": 128, "loop_closure.wide_ratio": 0.9,
    "loop_closure.wide_distinct_distance": 1.0, "loop_closure.wide_agreement": (0.5, 0.05),
    "loop_closure.wide_refine_window": (0.3, 0.3, 0.05),
    "optimizer.lm_initial_damping": 1e-5, "optimizer.lm_iteration_factor": 10,
    "relocalization.coarse_hit_sigma": 0.4, "relocalization.coarse_points": 24,
    "relocalization.coarse_min_score": 0.6, "relocalization.coarse_ratio": 0.9,
    "relocalization.coarse_candidates": 64, "relocalization.coarse_distinct_distance": 0.5,
    "relocalization.coarse_distinct_angle": 0.15, "relocalization.refine_moves": 3,
    "relocalization.heading_levels": 0, "relocalization.query_spacing": 0.2,
    "relocalization.refine_nodes": 5,
    "localization.heading_weight": 2.0, "localization.reanchor_distance": 0.3, "localization.merge_distance": 0.2,
    "localization.merge_angle": 0.05, "localization.confirm_miss_floor": 0.003,
    "runtime.min_evaluation_share": 0.25, "runtime.front_end_cost_smoothing": 0.1,
    "runtime.slice_cost_decay": 0.97, "runtime.slice_cost_memory": 0.95,
    "runtime.malloc_mmap_threshold": 131_072, "runtime.warm_up_scans": 120}
# Fields that moved into their component's section: old dotted name → new.
_WIDE = ("spacing", "min_gap", "radius", "drift", "max_radius", "angle", "turn_drift",
         "max_angle", "resolution", "query_nodes", "min_score", "slice_cells", "slice_nodes",
         "slice_blocks")
RENAMED_FIELDS = {
    "front_end.odometry_gate_share": "front_end.odometry_gate.share",
    "front_end.odometry_gate_fit": "front_end.odometry_gate.fit",
    "front_end.odometry_gate_explained": "front_end.odometry_gate.explained",
    "front_end.stale_turn_window": "front_end.recovery.stale_turn_window",
    "front_end.pivot_search_rate": "front_end.recovery.pivot_search_rate",
    "front_end.recovery_heading_step": "front_end.recovery.heading_step",
    "front_end.calibrate_odometry_scale": "front_end.odometry_scale.enabled",
    "front_end.odometry_scale_limits": "front_end.odometry_scale.limits",
    "front_end.smooth_between_headings": "front_end.between_scans.headings",
    "front_end.smooth_between_positions": "front_end.between_scans.positions",
    "front_end.between_min_pairs": "front_end.between_scans.min_pairs",
    "loop_closure.max_given_up": "loop_closure.agreement.max_given_up",
    **{f"loop_closure.wide_{name}": f"loop_closure.wide_search.{name}" for name in _WIDE}}
# Fields whose sentinel value turned their rule off, now a section with an ``enabled`` flag:
# old dotted name → (the section, the field that takes any other value, the sentinel).
SWITCHED_FIELDS = {
    "front_end.odometry_gate": ("front_end.odometry_gate", "tolerance", None),
    "front_end.odometry_heading_weight": ("front_end.heading_prior", "weight", 0),
    "front_end.previous_scan_gain": ("front_end.previous_scan_check", "gain", 1),
    "loop_closure.agreement_nodes": ("loop_closure.agreement", "nodes", 0),
    "loop_closure.wide_after": ("loop_closure.wide_search", "after", 0)}


def flat_tables(data: dict, where: str = "") -> dict:
    """Nested tables (a file's, a session's) as their leaves' dotted names → values."""
    flat = {}
    for key, value in data.items():
        path = f"{where}.{key}" if where else key
        flat.update(flat_tables(value, path) if isinstance(value, dict) else {path: value})
    return flat


def _same(value, fixed) -> bool:
    if isinstance(value, list):
        value = tuple(value)
    return value == fixed if not isinstance(fixed, tuple) else (
        isinstance(value, tuple) and len(value) == len(fixed)
        and all(a == b for a, b in zip(value, fixed)))


def upgrade_names(data: dict) -> dict:
    """``data`` (a whole tree's nested tables) in this version's names: removed and fixed
    fields at their old values dropped, moved fields renamed, sentinels turned into
    ``enabled``. A value this version cannot honour is refused by name."""
    changes = {}
    for path, value in flat_tables(data).items():
        if path in REMOVED_FIELDS:
            off = REMOVED_FIELDS[path]
            if off is not None and (NONE if value is None else value) != off:
                raise ConfigError(f"{path} = {value!r}: this opt-in was removed in this version "
                                  f"(docs/configuration.md); remove the key, "
                                  f"or use commit 449cba7")
        elif path in FIXED_FIELDS:
            if not _same(value, FIXED_FIELDS[path]):
                raise ConfigError(f"{path} = {value!r}: this field is now a constant, "
                                  f"{FIXED_FIELDS[path]!r} (docs/configuration.md, \"Older "
                                  f"names\"); remove the key")
        elif path in SWITCHED_FIELDS:
            section, name, sentinel = SWITCHED_FIELDS[path]
            off = value is None or value == NONE if sentinel is None else value == sentinel
            changes[f"{section}.enabled"] = not off
            if not off:
                changes[f"{section}.{name}"] = value
        else:
            changes[RENAMED_FIELDS.get(path, path)] = value
    return nested_tables(changes)


def nested_tables(changes: dict) -> dict:
    """Dotted names → values as the nested tables a file or a session holds."""
    nested: dict = {}
    for dotted, value in changes.items():
        node = nested
        *parents, leaf = dotted.split(".")
        for p in parents:
            node = node.setdefault(p, {})
        node[leaf] = value
    return nested


def from_dict(data: dict, base=None, cls=SlamConfig, where: str = ""):
    """``base`` (default: ``cls()``) with the fields ``data`` names changed; nested tables
    change nested sections. Unknown keys and ill-typed values raise :class:`ConfigError`."""
    base = cls() if base is None else base
    if not isinstance(data, dict):
        raise ConfigError(f"{where or 'config'}: must be a table, got {data!r}")
    if cls is SlamConfig and not where:
        data = upgrade_names(data)
    hints = typing.get_type_hints(cls)
    meta = {f.name: f.metadata for f in fields(cls)}
    changes = {}
    for key, value in data.items():
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
    return from_dict(nested_tables(changes), config, type(config))


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


LEVELS = ("basic", "standard", "all")


def field_names(config=None) -> list[str]:
    """Every field's dotted name, in the order ``to_toml`` writes them: a section's own
    fields, then its sub-sections."""
    names: list[str] = []

    def walk(section, table: str):
        inner = [f for f in fields(section) if is_dataclass(getattr(section, f.name))]
        names.extend(f"{table}.{f.name}" if table else f.name for f in fields(section)
                     if f not in inner)
        for f in inner:
            walk(getattr(section, f.name), f"{table}.{f.name}" if table else f.name)

    walk(config if config is not None else SlamConfig(), "")
    return names


def field_level(key: str) -> str:
    """The level (basic, standard, expert) the field ``key`` declares in its metadata."""
    section, *path, name = key.split(".")
    node = getattr(SlamConfig(), section)
    for part in path:
        node = getattr(node, part)
    return {f.name: f.metadata for f in fields(node)}[name]["level"]


def shown(key: str, level: str = "all") -> bool:
    """Whether ``config show`` at ``level`` lists the field ``key``: basic the few a user is
    expected to set, standard all but the stages' internals (expert), all every one."""
    if level not in LEVELS:
        raise ConfigError(f"unknown level {level!r}; choose one of {', '.join(LEVELS)}")
    own = field_level(key)
    return level == "all" or (own == BASIC if level == "basic" else own != EXPERT)


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
