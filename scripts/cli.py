"""``swarmslam``: the command-line entry point. It only dispatches: each command is a module of
:mod:`swarmslam.commands` with its parser, its ``--help`` texts and its function, and the
packages hold the logic."""

from __future__ import annotations

import argparse
import sys
import textwrap

from swarmslam.commands import (bench, config, convert, demo, emulate, lidar, relations, replay,
                                rllib, simlog, sweep, tune)

COMMANDS = (config, lidar, emulate, demo, replay, convert, simlog, relations, sweep, tune, rllib,
            bench)  # in the order --help lists them
# (what the command does, reads and writes; an example) per command, shown by its --help
HELP = {key: text for command in COMMANDS for key, text in command.HELP.items()}

DESCRIPTION = """SwarmSLAM: 2-D LiDAR graph SLAM whose scan matching is done by swarm optimizers
(particle swarm, artificial bee colony, firefly). Run it over a simulated robot (demo), a
recorded log or ROS bag (replay), or a live RPLidar (lidar); benchmark it on the public logs
(bench). Each command has its own --help."""


def _describe(parser, prefix=()) -> None:
    """Each command's --help: what it does, reads and writes, and an example."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                key = " ".join((*prefix, name))
                description, example = HELP[key]
                sub.description = textwrap.fill(description, 79)
                sub.epilog = f"example:\n  {example}"
                sub.formatter_class = argparse.RawDescriptionHelpFormatter
                _describe(sub, (*prefix, name))


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="swarmslam", description=DESCRIPTION,
                                epilog="example:\n  swarmslam demo",
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="command", required=True)
    for command in COMMANDS:
        command.add(sub)
    _describe(p)
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    if args.command == "bench":  # what shared the machine goes into its JSON
        from swarmslam.bench.record import start_watch

        start_watch()
    try:
        return args.func(args)
    except (OSError, ValueError) as e:  # files, ports (pyserial's errors are OSErrors), input
        print(f"swarmslam: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("swarmslam: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
