"""``swarmslam sweep SPEC.toml``: many SLAM replays — logs × optimizers × seeds ×
configuration variants — run as Ray tasks, each result appended to a JSON-lines file the
moment it finishes; run again, only the runs not in that file are done (docs/sweeps.md).

A spec (every field but ``logs`` optional)::

    logs = ["intel", "aces"]      # bench slam's names, or paths of CARMEN logs (LOG.relations
                                  # beside a log scores it)
    optimizers = ["abc", "pso", "fa"]
    seeds = [0, 1, 2]
    odometry = true
    limit = 0                     # scans per log (0: all)
    preset = "sick-lms200"        # the configuration's base, as --preset
    config = "base.toml"          # fields changed over the preset, as --config
    results = "sweep.jsonl"       # beside the spec unless absolute

    [grid]                        # configuration fields → values: every combination is a variant
    "front_end.node_distance" = [0.3, 0.5]

Workers read the logs from the paths the driver resolves (a folder every worker can read:
the local machine, or a file system the cluster shares); nothing is shipped through the
object store. Each run is :func:`swarmslam.replay.replay_run` with the seed, so its figures are
those of ``swarmslam replay`` with that seed.
"""

from __future__ import annotations

import contextlib
import io
import itertools
import json
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import tomllib

from swarmslam.runtime.config import (
    DEFAULT_PRESET,
    OPTIMIZERS,
    ConfigError,
    load_config,
    override,
    preset,
)
from swarmslam.runtime.realtime.writers import write_json_atomic
from swarmslam.bench.slam import LOGS
from swarmslam.datasets import find_datasets, require
from swarmslam.progress import Progress
from swarmslam.replay import replay_run
from swarmslam.runs import RunOptions

# what a results line keeps of a replay's metrics (the runtime's full report stays out)
KEPT = ("eT", "eT_std", "eR_deg", "eR_std", "eT_local", "eR_local_deg", "eT_global",
        "eR_global_deg", "relations_used", "loops_accepted", "nodes", "scans", "wall_seconds",
        "real_time_factor", "latency_ms_p99", "status")


class SpecError(ValueError):
    """A sweep or tune spec that cannot be run: the message names the file and the field."""


@dataclass(frozen=True)
class Run:
    """One replay of a sweep: a log, an optimizer, a seed and a variant's changes."""

    log: str  # the spec's name for it
    optimizer: str
    seed: int
    changes: tuple = ()  # ((field, value), ...), sorted

    @property
    def variant(self) -> str:
        return ", ".join(f"{k}={v}" for k, v in self.changes) or "defaults"

    @property
    def key(self) -> str:
        """Names the run in the results file (a finished run is one with this key there)."""
        return f"{self.log} | {self.optimizer} | seed {self.seed} | {self.variant}"


@dataclass
class SweepSpec:
    logs: dict  # name → (log path, relations path or None)
    optimizers: tuple = ("abc",)
    seeds: tuple = (0,)
    odometry: bool = True
    limit: int = 0
    preset: str = DEFAULT_PRESET
    config: Path | None = None
    results: Path = Path("sweep.jsonl")
    grid: dict = field(default_factory=dict)

    def runs(self) -> list[Run]:
        """Every run, log by log (a log's runs together, so a killed sweep has whole logs)."""
        fields = sorted(self.grid)
        variants = [tuple(zip(fields, values))
                    for values in itertools.product(*(self.grid[f] for f in fields))]
        return [Run(log, optimizer, seed, variant) for log in self.logs
                for variant in variants for optimizer in self.optimizers for seed in self.seeds]

    def base_config(self):
        base = preset(self.preset)
        return load_config(self.config, base) if self.config else base


def _get(table: dict, key: str, kind, where: str, default=None):
    if key not in table:
        return default
    value = table[key]
    if not isinstance(value, kind) or isinstance(value, bool) and kind is not bool:
        names = kind.__name__ if isinstance(kind, type) else " or ".join(k.__name__ for k in kind)
        raise SpecError(f"{where}: field {key!r} must be {names}, got {value!r}")
    return value


def resolve_logs(names, where: str, base: Path, data=None) -> dict:
    """Each ``logs`` entry — a name ``bench slam`` knows, or a CARMEN log's path — as
    ``name → (log, relations or None)``, every file checked now (not in a worker later)."""
    if not isinstance(names, list) or not names:
        raise SpecError(f"{where}: field 'logs' must be a non-empty list of log names or paths")
    out = {}
    for entry in names:
        if not isinstance(entry, str):
            raise SpecError(f"{where}: field 'logs': {entry!r} is not a name or a path")
        if entry in LOGS:
            folder = find_datasets(data) / "radish"
            log, rel = (require(folder / f) for f in LOGS[entry])
        else:
            log = Path(entry) if Path(entry).is_absolute() else base / entry
            if not log.is_file():
                raise SpecError(f"{where}: field 'logs': {entry!r} is neither one of "
                                f"{', '.join(LOGS)} nor a file ({log} does not exist)")
            stem = log.name.removesuffix(".gz").removesuffix(".clf").removesuffix(".log")
            rel = log.with_name(stem + ".relations")
            rel = rel if rel.is_file() else None
        out[entry] = (log.resolve(), rel.resolve() if rel else None)
    return out


SWEEP_FIELDS = frozenset({"logs", "optimizers", "seeds", "odometry", "limit", "preset",
                          "config", "results", "grid", "data"})


def read_spec(path, data=None) -> SweepSpec:
    """A sweep spec (see module doc); every field checked, errors naming the file."""
    path = Path(path)
    return read_spec_fields(load_toml(path), str(path), path.parent, data)


def read_spec_fields(table: dict, where: str, base: Path, data=None, allowed=SWEEP_FIELDS,
                     extra=frozenset()) -> SweepSpec:
    """The sweep fields of a spec's ``table`` (``where``: its file, for errors; ``base``: the
    folder its relative paths start from); ``allowed`` of them may be given, and the
    ``extra`` fields of a spec that holds them (a tune spec's)."""
    known = set(allowed) | set(extra)
    unknown = sorted(set(table) - known)
    if unknown:
        raise SpecError(f"{where}: unknown field {unknown[0]!r}; known: {', '.join(sorted(known))}")
    spec = SweepSpec(logs=resolve_logs(table.get("logs"), where, base,
                                       data or _get(table, "data", str, where)))
    optimizers = _get(table, "optimizers", list, where, ["abc"])
    for o in optimizers:
        if o not in OPTIMIZERS:
            raise SpecError(f"{where}: field 'optimizers': unknown optimizer {o!r}; choose from "
                            f"{', '.join(OPTIMIZERS)}")
    seeds = _get(table, "seeds", list, where, [0])
    if not seeds or not all(isinstance(s, int) and not isinstance(s, bool) and s >= 0
                            for s in seeds):
        raise SpecError(f"{where}: field 'seeds' must be a non-empty list of integers >= 0")
    spec.optimizers, spec.seeds = tuple(optimizers), tuple(seeds)
    spec.odometry = _get(table, "odometry", bool, where, True)
    spec.limit = _get(table, "limit", int, where, 0)
    if spec.limit < 0:
        raise SpecError(f"{where}: field 'limit' must be >= 0, got {spec.limit}")
    spec.preset = _get(table, "preset", str, where, DEFAULT_PRESET)
    config = _get(table, "config", str, where)
    spec.config = None if config is None else (base / config).resolve()
    spec.results = (base / _get(table, "results", str, where, "sweep.jsonl")).resolve()
    spec.grid = _get(table, "grid", dict, where, {})
    for key, values in spec.grid.items():
        if not isinstance(values, list) or not values:
            raise SpecError(f"{where}: [grid] field {key!r} must be a non-empty list of values")
    try:  # every variant is a valid configuration, checked before anything runs
        base_config = spec.base_config()
        for run in spec.runs()[:: len(spec.optimizers) * len(spec.seeds)]:
            override(base_config, dict(run.changes))
    except (ConfigError, KeyError, TypeError, ValueError) as e:
        raise SpecError(f"{where}: {e}") from None
    return spec


def load_toml(path: Path) -> dict:
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except OSError as e:
        raise SpecError(f"{path}: cannot read the spec: {e.strerror}") from None
    except tomllib.TOMLDecodeError as e:
        raise SpecError(f"{path}: not valid TOML: {e}") from None


# ---------------------------------------------------------------------- one run
def run_replay(run: Run, log: Path, relations: Path | None, odometry: bool, limit: int,
               base_config) -> dict:
    """One replay, as a results line: the run's fields and the figures of ``KEPT``. The
    replay's progress lines are not shown (the sweep shows its own)."""
    config = override(base_config, dict(run.changes))
    with contextlib.redirect_stderr(io.StringIO()):
        metrics, _ = replay_run(log, relations, RunOptions(config, run.optimizer, run.seed),
                                odometry=odometry, limit=limit or None, label=run.key)
    return {"key": run.key, "log": run.log, "optimizer": run.optimizer, "seed": run.seed,
            "variant": run.variant, "changes": dict(run.changes), "odometry": odometry,
            "limit": limit, "pid": os.getpid(),
            **{k: metrics[k] for k in KEPT if k in metrics}}


# ---------------------------------------------------------------------- the results file
def read_results(path: Path) -> dict:
    """``key → record`` of the finished runs in a results file (none if it does not exist).
    A last line cut short (the sweep was killed while writing it) is dropped from the file,
    so the next append starts on a line of its own; any other bad line is an error."""
    path = Path(path)
    if not path.exists():
        return {}
    data = path.read_bytes()
    lines = data.split(b"\n")
    done, good_end = {}, 0
    for number, line in enumerate(lines, 1):
        if not line.strip():
            good_end += len(line) + 1
            continue
        try:
            record = json.loads(line)
            done[record["key"]] = record
        except (json.JSONDecodeError, KeyError, TypeError):
            if number == len(lines):  # the unfinished last write
                with open(path, "r+b") as f:
                    f.truncate(good_end)
                break
            raise SpecError(f"{path}: line {number} is not a results record") from None
        good_end += len(line) + 1
    return done


def append_result(path: Path, record: dict) -> None:
    """One line, written and flushed to disk at once: a finished run survives a kill."""
    line = (json.dumps(record, sort_keys=True) + "\n").encode()
    with open(path, "ab") as f:
        f.write(line)
        f.flush()
        os.fsync(f.fileno())


# ---------------------------------------------------------------------- the sweep
def sweep(spec: SweepSpec, address: str | None = None, workers: int | None = None,
          serial: bool = False, echo=print) -> list[dict]:
    """Every run of ``spec`` not yet in its results file — on Ray (``address``: a cluster's;
    None: a local Ray with ``workers`` CPUs, all by default) or, ``serial``, one after another
    in this process. Returns every record of the spec's runs, finished before or now."""
    runs = spec.runs()
    done = read_results(spec.results)
    todo = [r for r in runs if r.key not in done]
    echo(f"sweep: {len(runs)} runs, {len(runs) - len(todo)} already in {spec.results}, "
         f"{len(todo)} to run{' serially' if serial else ' on Ray'}")
    spec.results.parent.mkdir(parents=True, exist_ok=True)
    progress = Progress(len(todo), "sweep", every=0.0)
    base = spec.base_config()
    start = time.perf_counter()
    for record in (_serial(spec, todo, base) if serial else
                   _on_ray(spec, todo, base, address, workers)):
        append_result(spec.results, record)
        done[record["key"]] = record
        progress.update(note=f"{record['key']}: eT {record.get('eT', float('nan')):.4f} m")
    progress.close()
    if todo:
        echo(f"sweep: {len(todo)} runs in {time.perf_counter() - start:.1f} s")
    return [done[r.key] for r in runs if r.key in done]


def _serial(spec, todo, base):
    for run in todo:
        log, rel = spec.logs[run.log]
        yield run_replay(run, log, rel, spec.odometry, spec.limit, base)


def _on_ray(spec, todo, base, address, workers):
    """Each run a Ray task (one CPU each); records come back as they finish."""
    with ray_session(address, workers) as ray:
        task = ray.remote(num_cpus=1)(run_replay)
        base_ref = ray.put(base)
        pending = [task.remote(run, *spec.logs[run.log], spec.odometry, spec.limit, base_ref)
                   for run in todo]
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            yield ray.get(ready[0])


@contextlib.contextmanager
def ray_session(address: str | None = None, workers: int | None = None):
    """Ray for a sweep or a tuning: the one already running, a cluster's (``address``), or a
    local one of ``workers`` CPUs (default: all) started here and stopped at the end."""
    ray = require_ray()
    started_here = not ray.is_initialized()
    if started_here:
        options = {"include_dashboard": False, "log_to_driver": False}
        if address is None:
            options["num_cpus"] = workers
        ray.init(address=address, **options)
    try:
        yield ray
    finally:
        if started_here:
            ray.shutdown()


def require_ray():
    try:
        import ray
    except ImportError:
        raise SystemExit("swarmslam sweep and tune run on Ray: pip install 'swarmslam[scale]' "
                         "(or --serial for one process)") from None
    return ray


# ---------------------------------------------------------------------- the summary
def summarise(records: list[dict]) -> list[dict]:
    """Per log, optimizer and variant: the mean and the worst over seeds of every figure
    scored (eT, eR, and fr-clinic's local and global parts), and the slowest real time."""
    groups = {}
    for r in records:
        groups.setdefault((r["log"], r["optimizer"], r["variant"]), []).append(r)
    rows = []
    for (log, optimizer, variant), runs in groups.items():
        row = {"log": log, "optimizer": optimizer, "variant": variant,
               "seeds": sorted(r["seed"] for r in runs),
               "real_time_factor_min": min(r["real_time_factor"] for r in runs)}
        for key in ("eT", "eR_deg", "eT_local", "eR_local_deg", "eT_global", "eR_global_deg"):
            values = [r[key] for r in runs if key in r]
            if values:
                row[f"{key}_mean"], row[f"{key}_worst"] = float(np.mean(values)), max(values)
        rows.append(row)
    return rows


def format_summary(rows: list[dict]) -> str:
    head = (f"{'log':<12} {'optimizer':<9} {'variant':<32} {'seeds':>5} {'eT m':>8} "
            f"{'worst':>8} {'eR °':>7} {'worst':>7} {'x real time':>11}")
    lines = [head, "-" * len(head)]
    for r in rows:
        def f(key, width, digits):
            return f"{r[key]:{width}.{digits}f}" if key in r else f"{'—':>{width}}"
        lines.append(f"{Path(r['log']).name[:12]:<12} {r['optimizer']:<9} {r['variant'][:32]:<32} "
                     f"{len(r['seeds']):5d} {f('eT_mean', 8, 4)} {f('eT_worst', 8, 4)} "
                     f"{f('eR_deg_mean', 7, 3)} {f('eR_deg_worst', 7, 3)} "
                     f"{r['real_time_factor_min']:11.1f}")
    return "\n".join(lines)


def write_summary(spec: SweepSpec, records: list[dict]) -> Path:
    """The summary beside the results file (``RESULTS.summary.json``, atomically)."""
    path = spec.results.with_name(spec.results.stem + ".summary.json")
    write_json_atomic(path, {"results": str(spec.results), "runs": len(records),
                             "summary": summarise(records)})
    return path
