"""``swarmslam lidar``: live SLAM from an RPLidar (swarmslam.live)."""

from __future__ import annotations

from swarmslam.commands.common import (MODELS, at_least_one, config_options, positive,
                                       run_options, sigterm_as_ctrl_c, view_options)
from swarmslam.view.run_view import RunWatch

# (what the command does, reads and writes; an example), shown by its --help
HELP = {
    "lidar": ("Live SLAM from a Slamtec RPLidar on a serial port at a fixed rate. Prints the "
              "scanner's info and a status line each second; on Ctrl-C or SIGTERM writes the "
              "map (PGM + YAML, PNG), trajectory (TUM), graph (g2o), session.npz and "
              "summary.json to --out. Wiring and udev: hardware/README.md.",
              "swarmslam lidar --port /dev/rplidar --model a2 --out my-run"),
}


def add(sub) -> None:
    """The command's parser, under ``sub`` (the CLI's subparsers)."""
    li = sub.add_parser("lidar", help="live SLAM from an RPLidar (or the emulator) at a fixed rate")
    li.add_argument("--port", required=True, help="serial port, e.g. /dev/rplidar or /dev/ttyUSB0")
    li.add_argument("--model", default="a1", choices=MODELS)
    li.add_argument("--bag", metavar="FILE",
                    help="record every scan to a ROS bag (X.bag: ROS 1, X.mcap: MCAP, any other "
                         "name: a ROS 2 sqlite3 bag folder; extra 'bags')")
    li.add_argument("--baud", type=at_least_one,
                    help="switch the link to this rate after connecting, where the model "
                         "allows (the A2: 256000)")
    li.add_argument("--mode", default="typical",
                    help="scan mode: 'typical' (the scanner's recommended mode, as Slamtec's "
                         "SDK starts; express on old firmware), 'standard', 'express', or a "
                         "mode name the scanner lists (Boost, Sensitivity, DenseBoost, ...)")
    li.add_argument("--out", default="swarmslam-live", help="output folder (written on Ctrl-C)")
    li.add_argument("--rate", type=positive, help="SLAM ticks per second (default: the configuration's, 10)")
    li.add_argument("--seconds", type=positive, help="stop after this long (default: Ctrl-C)")
    saved = li.add_mutually_exclusive_group()
    saved.add_argument("--resume", metavar="SESSION",
                       help="extend a saved session's map from wherever the scanner is in it")
    saved.add_argument("--localize", metavar="SESSION",
                       help="localize in a saved session's map (never changed), no prior")
    config_options(li, "the model's preset", sessions=True)
    view_options(li)
    li.set_defaults(func=_lidar)


def _lidar(args) -> int:
    from swarmslam.live import run_live

    with sigterm_as_ctrl_c():
        summary = run_live(args.port, args.model, args.mode, args.out, args.rate, args.seconds,
                           run_options(args, f"rplidar-{args.model}"),
                           watch=RunWatch.from_args(args), baud=args.baud, bag=args.bag)
    return 1 if summary["status"].startswith("no scans") else 0


