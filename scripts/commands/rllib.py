"""``swarmslam rllib``: RLlib's PPO on SwarmSlam-v0 (swarmslam.train_rllib)."""

from __future__ import annotations

from pathlib import Path

from swarmslam.commands.common import at_least_one

# (what the command does, reads and writes; an example), shown by its --help
HELP = {
    "rllib": ("Train RLlib's PPO on SwarmSlam-v0 with env runners on Ray (extra 'rllib'). "
              "docs/sweeps.md §4.", "swarmslam rllib --env-runners 4 --iterations 20 --slam"),
}


def add(sub) -> None:
    """The command's parser, under ``sub`` (the CLI's subparsers)."""
    rl = sub.add_parser("rllib", help="PPO on SwarmSlam-v0 with RLlib, env runners on Ray "
                                      "(extra 'rllib')")
    rl.add_argument("--iterations", type=at_least_one, default=10)
    rl.add_argument("--env-runners", type=at_least_one, default=2)
    rl.add_argument("--world", default="office")
    rl.add_argument("--slam", action="store_true", help="the SLAM's pose in the observation "
                                                        "(default: the true pose, faster)")
    rl.add_argument("--episode-steps", type=at_least_one, default=500)
    rl.add_argument("--seed", type=int, default=0)
    rl.add_argument("--checkpoint", metavar="DIR", help="save the trained algorithm here")
    rl.add_argument("--address", help="an existing Ray cluster (default: a local Ray)")
    rl.set_defaults(func=_rllib)


def _rllib(args) -> int:
    from swarmslam.train_rllib import train_ppo

    env_config = {"slam": args.slam, "world": args.world,
                  "max_episode_steps": args.episode_steps}
    result = train_ppo(args.iterations, args.env_runners, env_config, args.seed,
                       Path(args.checkpoint) if args.checkpoint else None, args.address)
    if result["checkpoint"]:
        print(f"checkpoint in {result['checkpoint']}")
    return 0


