"""``swarmslam tune SPEC.toml``: Ray Tune with an Optuna search over named configuration
fields; a trial's objective is its worst ratio to a reference error over the chosen logs
(Cartographer's published figure for Intel, ACES3 and fr-clinic), so the search tunes for
every log at once rather than one; the best configuration is written as a TOML file that
``--config`` loads, and every trial's changes and ratios beside it as JSON (docs/sweeps.md
§3).

A spec — the log fields of a sweep spec (``logs``, ``seeds``, ``odometry``, ``limit``,
``preset``, ``config``, ``data``), and::

    optimizer = "abc"
    trials = 24
    seed = 0                      # the search's
    out = "tuned.toml"            # the best configuration (beside the spec unless absolute)

    [search]                      # configuration fields and their ranges
    "front_end.node_distance" = { low = 0.2, high = 0.6 }
    "matcher.refine_evaluations" = { low = 200, high = 900 }    # integers: an integer range
    "loop_closure.wide_search.resolution" = { low = 0.1, high = 0.8, log = true }
    "matcher.swarm.optimizer" = { choices = ["abc", "pso"] }

    [reference]                   # eT (m) per log without a published figure
    "my-building.clf" = 0.05
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from swarmslam.runtime.config import ConfigError, override, to_toml
from swarmslam.runtime.realtime.writers import write_bytes_atomic, write_json_atomic
from swarmslam.bench.slam import PUBLISHED
from swarmslam.sweep import (
    Run,
    SpecError,
    SweepSpec,
    _get,
    load_toml,
    ray_session,
    read_spec_fields,
    run_replay,
)

# Cartographer's published eT per log and scored part (Hess et al. 2016)
CARTOGRAPHER = {"intel": {"": PUBLISHED["intel"]["Cartographer"][0]},
                "aces": {"": PUBLISHED["aces"]["Cartographer"][0]},
                "clinic": {"_local": PUBLISHED["clinic"]["Cartographer, local"][0],
                           "_global": PUBLISHED["clinic"]["Cartographer, global"][0]}}


@dataclass
class TuneSpec:
    runs: SweepSpec  # the logs, seeds and base configuration every trial replays
    optimizer: str = "abc"
    trials: int = 12
    seed: int = 0
    out: Path = Path("tuned.toml")
    search: dict = field(default_factory=dict)  # field → {"low", "high", "log"} | {"choices"}
    reference: dict = field(default_factory=dict)  # log → {part: eT}


def read_tune_spec(path, data=None) -> TuneSpec:
    path = Path(path)
    table = load_toml(path)
    where, base = str(path), path.parent
    own = {"optimizer", "trials", "seed", "out", "search", "reference"}
    runs = read_spec_fields({k: v for k, v in table.items() if k not in own}, where, base, data,
                            allowed={"logs", "seeds", "odometry", "limit", "preset", "config",
                                     "data"}, extra=own)
    spec = TuneSpec(runs)
    spec.optimizer = _get(table, "optimizer", str, where, "abc")
    spec.trials = _get(table, "trials", int, where, 12)
    if spec.trials < 1:
        raise SpecError(f"{where}: field 'trials' must be >= 1, got {spec.trials}")
    spec.seed = _get(table, "seed", int, where, 0)
    spec.out = (base / _get(table, "out", str, where, "tuned.toml")).resolve()
    search = _get(table, "search", dict, where, {})
    if not search:
        raise SpecError(f"{where}: [search] names no configuration field to tune")
    for key, dist in search.items():
        spec.search[key] = _distribution(key, dist, where)
    given = _get(table, "reference", dict, where, {})
    for log, (path, relations) in spec.runs.logs.items():
        if relations is None:
            raise SpecError(f"{where}: log {log!r} has no relations beside it ({path}): a "
                            "tuned log must be scored")
        if log in CARTOGRAPHER:
            spec.reference[log] = CARTOGRAPHER[log]
        elif isinstance(given.get(log), (int, float)) and given[log] > 0:
            spec.reference[log] = {"": float(given[log])}
        else:
            raise SpecError(f"{where}: log {log!r} has no published figure: give its reference "
                            f"eT in [reference] (\"{log}\" = metres)")
    base_config = spec.runs.base_config()
    try:  # the range's ends are values the configuration accepts
        for key, dist in spec.search.items():
            for value in dist.get("choices") or (dist["low"], dist["high"]):
                override(base_config, {key: value})
    except (ConfigError, KeyError, TypeError, ValueError) as e:
        raise SpecError(f"{where}: [search] {e}") from None
    return spec


def _distribution(key, dist, where) -> dict:
    if not isinstance(dist, dict):
        raise SpecError(f"{where}: [search] field {key!r} must be a table: "
                        "{ low = .., high = .. } or { choices = [..] }")
    if "choices" in dist:
        if not isinstance(dist["choices"], list) or not dist["choices"]:
            raise SpecError(f"{where}: [search] field {key!r}: choices must be a non-empty list")
        return {"choices": dist["choices"]}
    low, high = dist.get("low"), dist.get("high")
    if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in (low, high)) \
            or not low < high:
        raise SpecError(f"{where}: [search] field {key!r}: needs numbers low < high")
    log = bool(dist.get("log", False))
    if log and low <= 0:
        raise SpecError(f"{where}: [search] field {key!r}: a log range needs low > 0")
    return {"low": low, "high": high, "log": log,
            "integer": isinstance(low, int) and isinstance(high, int)}


# ---------------------------------------------------------------------- a trial
def objective(spec: TuneSpec, changes: dict) -> dict:
    """One trial: every log and seed replayed with ``changes``; per log the mean over seeds of
    each scored part's eT over its reference, the log's ratio the worst part's; the objective
    the worst log's ratio (below 1: better than the reference on every log)."""
    base = override(spec.runs.base_config(), changes)
    ratios = {}
    for log, (path, relations) in spec.runs.logs.items():
        records = [run_replay(Run(log, spec.optimizer, seed), path, relations,
                              spec.runs.odometry, spec.runs.limit, base)
                   for seed in spec.runs.seeds]
        parts = spec.reference[log]
        ratios[log] = max(float(np.mean([r[f"eT{part}" if part else "eT"] for r in records]))
                          / reference for part, reference in parts.items())
    worst = max(ratios.values())
    return {"objective": worst if math.isfinite(worst) else 1e9,
            **{f"ratio {log}": r for log, r in ratios.items()}}


def _space(spec: TuneSpec) -> dict:
    from ray import tune

    space = {}
    for key, d in spec.search.items():
        if "choices" in d:
            space[key] = tune.choice(d["choices"])
        elif d["integer"]:
            space[key] = (tune.lograndint if d["log"] else tune.randint)(d["low"], d["high"] + 1)
        else:
            space[key] = (tune.loguniform if d["log"] else tune.uniform)(d["low"], d["high"])
    return space


# ---------------------------------------------------------------------- the search
def tune_config(spec: TuneSpec, address: str | None = None, workers: int | None = None,
                echo=print) -> dict:
    """``trials`` trials of an Optuna search (TPE, seeded) on Ray Tune, ``workers`` at a time;
    the best configuration is written to ``spec.out``. Returns the best trial's changes and
    figures, and every trial's."""
    with ray_session(address, workers):
        from ray import tune
        from ray.tune.search.optuna import OptunaSearch

        def trial(changes):
            tune.report(objective(spec, dict(changes)))

        searcher = OptunaSearch(metric="objective", mode="min", seed=spec.seed)
        # Ray Tune's own record of the trials, beside the configuration (its progress table
        # is the progress shown)
        tuner = tune.Tuner(
            tune.with_resources(trial, {"cpu": 1}), param_space=_space(spec),
            tune_config=tune.TuneConfig(search_alg=searcher, num_samples=spec.trials,
                                        max_concurrent_trials=workers),
            run_config=tune.RunConfig(storage_path=str(spec.out.parent),
                                      name=spec.out.stem + ".trials", verbose=1))
        results = tuner.fit()
        trials = [{"changes": {k: _plain(r.config[k]) for k in spec.search},
                   **{k: v for k, v in r.metrics.items()
                      if k == "objective" or k.startswith("ratio ")}}
                  for r in results if r.metrics and "objective" in r.metrics]
    if not trials:
        raise RuntimeError("no trial finished (see Ray's logs)")
    best = min(trials, key=lambda t: t["objective"])
    config = override(spec.runs.base_config(), best["changes"])
    write_bytes_atomic(spec.out, to_toml(config).encode())
    write_json_atomic(spec.out.with_suffix(".json"), {"best": best, "trials": trials})
    echo(f"best of {len(trials)} trials: worst ratio to the reference {best['objective']:.3f} "
         f"with {best['changes']}; configuration in {spec.out}")
    return {"best": best, "trials": trials, "out": str(spec.out)}


def _plain(value):
    """numpy scalars (Optuna's) as Python numbers, for TOML."""
    return value.item() if hasattr(value, "item") else value
