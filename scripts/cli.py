"""``swarmslam``: the command-line entry point. Thin: it parses arguments and calls the
packages, which hold the logic."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def _bench_matcher(args) -> int:
    from runtime.benchmarks.matcher import DATASETS, bench_matcher
    from runtime.datasets import find_datasets

    data = find_datasets(args.data)
    optimizers = tuple(o.strip() for o in args.optimizers.split(",") if o.strip())
    datasets = tuple(d.strip() for d in args.datasets.split(",") if d.strip())
    for d in datasets:
        if d not in DATASETS:
            raise SystemExit(f"unknown dataset {d!r}; choose from {', '.join(DATASETS)}")
    bench_matcher(data, optimizers, datasets, paper=not args.no_paper, limit=args.limit,
                  seed=args.seed, json_path=args.json)
    if args.json:
        print(f"wrote {args.json}")
    return 0


def _demo(args) -> int:
    from runtime.demo import run_demo

    run_demo(out_dir=Path(args.out), optimizer=args.optimizer, seed=args.seed, steps=args.steps)
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="swarmslam", description=__doc__.split("\n")[0])
    sub = p.add_subparsers(dest="command", required=True)

    demo = sub.add_parser("demo", help="run the SLAM front end on the built-in synthetic world")
    demo.add_argument("--out", default="swarmslam-demo", help="output folder")
    demo.add_argument("--optimizer", default="abc", choices=["abc", "pso", "fa"])
    demo.add_argument("--seed", type=int, default=0)
    demo.add_argument("--steps", type=int, default=120, help="scans along the loop")
    demo.set_defaults(func=_demo)

    bench = sub.add_parser("bench", help="benchmarks (JSON + table)")
    bsub = bench.add_subparsers(dest="benchmark", required=True)
    m = bsub.add_parser("matcher", help="scan matching on keyframe logs, no initial guess")
    m.add_argument("--data", help="datasets folder (default: ../shared/datasets)")
    m.add_argument("--optimizers", default="abc,pso,fa")
    m.add_argument("--datasets", default="intel,aces")
    m.add_argument("--limit", type=int, help="match only the first N pairs per dataset")
    m.add_argument("--no-paper", action="store_true", help="skip the paper-form variants")
    m.add_argument("--seed", type=int, default=0)
    m.add_argument("--json", help="write results here (atomically)")
    m.set_defaults(func=_bench_matcher)
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except (FileNotFoundError, ValueError) as e:
        print(f"swarmslam: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("swarmslam: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
