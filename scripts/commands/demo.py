"""``swarmslam demo``: a simulated robot explores a world with SLAM (swarmslam.demo)."""

from __future__ import annotations

from pathlib import Path

from swarmslam.commands.common import at_least_one, config_options, run_config, view_options
from swarmslam.runtime.config import OPTIMIZERS
from swarmslam.view.run_view import RunWatch

# (what the command does, reads and writes; an example), shown by its --help
HELP = {
    "demo": ("A simulated robot with a 360° LiDAR explores a world on its own while the SLAM "
             "tracks it, until 90% is mapped. Prints coverage, collisions and the pose error "
             "against the truth; writes the map, both trajectories (TUM), trajectory.png and "
             "summary.json to --out (default swarmslam-demo/).",
             "swarmslam demo --world maze --seed 3"),
}


def add(sub) -> None:
    """The command's parser, under ``sub`` (the CLI's subparsers)."""
    demo = sub.add_parser("demo", help="a simulated robot explores the office world with SLAM")
    demo.add_argument("--out", default="swarmslam-demo", help="output folder")
    demo.add_argument("--world", default="office",
                      help="built-in world, generator (rooms, maze, clutter) or .world file")
    demo.add_argument("--optimizer", choices=OPTIMIZERS,
                      help="swarm method (default: the configuration's, abc)")
    demo.add_argument("--seed", type=int, default=0)
    demo.add_argument("--steps", type=at_least_one, help="step limit (default 1500; 120 with --matcher-only)")
    demo.add_argument("--matcher-only", action="store_true",
                      help="runtime only, no simulator: chain swarm matches around a synthetic loop")
    config_options(demo, "the simulator's preset")
    view_options(demo)
    demo.set_defaults(func=_demo)


def _demo(args) -> int:
    if args.matcher_only:
        from swarmslam.matcher_demo import run_demo

        run_demo(out_dir=Path(args.out), optimizer=args.optimizer or "abc", seed=args.seed,
                 steps=args.steps or 120)
        return 0
    from swarmslam.demo import run_exploration_demo

    run_exploration_demo(Path(args.out), world=args.world, optimizer=args.optimizer,
                         seed=args.seed, max_steps=args.steps or 1500,
                         config=run_config(args, "sim-rplidar-a1"), watch=RunWatch.from_args(args))
    return 0


