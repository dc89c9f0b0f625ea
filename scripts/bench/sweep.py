"""``swarmslam bench sweep SPEC.toml``: the same sweep run twice in one process's run — one
replay after another, then as tasks on a local Ray with ``--workers`` CPUs — with the wall
time of each and whether every run's figures came out the same (the speed-up is a ratio
measured on one machine in one run, so a busy machine slows both)."""

from __future__ import annotations

import tempfile
import time
from dataclasses import replace
from pathlib import Path

from swarmslam.sweep import KEPT, sweep
from swarmslam.bench.record import save_results

COMPARED = tuple(k for k in KEPT if k not in ("wall_seconds", "real_time_factor",
                                              "latency_ms_p99"))


def bench_sweep(spec, workers: int = 2, json_path=None, echo=print) -> dict:
    walls, records = {}, {}
    with tempfile.TemporaryDirectory() as tmp:
        for mode in ("serial", "ray"):
            run_spec = replace(spec, results=Path(tmp) / f"{mode}.jsonl")
            t0 = time.perf_counter()
            out = sweep(run_spec, workers=workers, serial=mode == "serial", echo=echo)
            walls[mode] = time.perf_counter() - t0
            records[mode] = {r["key"]: r for r in out}
    differ = [key for key, r in records["serial"].items()
              if any(r.get(k) != records["ray"][key].get(k) for k in COMPARED)]
    result = {"benchmark": "sweep", "runs": len(records["serial"]), "workers": workers,
              "serial_seconds": walls["serial"], "ray_seconds": walls["ray"],
              "ray_share_of_serial": walls["ray"] / walls["serial"],
              "processes_used_by_ray": len({r["pid"] for r in records["ray"].values()}),
              "runs_differing": differ, "same_figures": not differ}
    echo(f"{result['runs']} runs: serial {walls['serial']:.1f} s, Ray with {workers} workers "
         f"{walls['ray']:.1f} s ({result['ray_share_of_serial']:.0%} of serial); "
         f"same figures: {'yes' if not differ else 'no, ' + ', '.join(differ)}")
    if json_path:
        save_results(json_path, result)
    return result
