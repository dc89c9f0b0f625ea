"""What the commands share: the configuration and bag options, the number types of their
arguments, and SIGTERM taken as Ctrl-C."""

from __future__ import annotations

import argparse
import contextlib
import math
import signal

from swarmslam.runtime.config import PRESETS, SlamConfig, load_config, preset, session_changes
from swarmslam.runs import SESSION_TAKES_ITS_CONFIGURATION, RunOptions


UNUSABLE = ("no usable scan", "mostly unusable input")
D = "../shared/datasets/radish"  # the examples' logs
MODELS = ["a1", "a2", "a3", "s1", "s2", "c1"]  # the RPLidar models a preset is made for


def run_config(args, default_preset: str) -> SlamConfig | None:
    """``--config FILE`` over ``--preset`` (default: ``default_preset``); None when neither
    is given, so the command builds its own default."""
    if not (args.preset or args.config):
        return None
    base = preset(args.preset or default_preset)
    return load_config(args.config, base) if args.config else base


def run_options(args, default_preset: str, **given) -> RunOptions:
    """The :class:`RunOptions` of ``--config``, ``--preset``, ``--localize`` and ``--resume``
    (a new run: :func:`run_config`; a session's: what ``--config FILE`` changes of its own
    configuration, only its search and tracking), with ``given``."""
    localize, resume = getattr(args, "localize", None), getattr(args, "resume", None)
    if not (localize or resume):
        return RunOptions(config=run_config(args, default_preset), **given)
    if args.preset:
        raise ValueError(SESSION_TAKES_ITS_CONFIGURATION)
    return RunOptions(localize=localize, resume=resume,
                      session_changes=session_changes(args.config) if args.config else {},
                      **given)


@contextlib.contextmanager
def sigterm_as_ctrl_c():
    """SIGTERM (how systemd, docker and kill stop a service) stops a live run as Ctrl-C does:
    the run ends and its outputs are written. The previous handler is back afterwards."""
    previous = signal.signal(signal.SIGTERM, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def config_options(parser, default: str, sessions: bool = False) -> None:
    also = (" (with --localize/--resume: only the session's [localization] and "
            "[relocalization])" if sessions else "")
    parser.add_argument("--config", metavar="FILE",
                        help="TOML file changing fields of the configuration "
                             f"(see: swarmslam config show){also}")
    parser.add_argument("--preset", choices=list(PRESETS), help=f"configuration preset "
                        f"(default: {default})")


def bench_outputs(parser) -> None:
    parser.add_argument("--json", help="write results here (atomically)")
    parser.add_argument("--plots", metavar="DIR",
                        help="write the figures (PNG) here (extra 'plots')")


def bag_options(parser) -> None:
    """Which topics and frames of a ROS bag to read."""
    parser.add_argument("--scan-topic", help="a bag's LaserScan topic (default: the only one)")
    parser.add_argument("--odom-topic", help="a bag's Odometry topic (default: the only one; "
                                             "none: tf)")
    parser.add_argument("--odom-frame", default="odom", help="odometry's frame in tf")
    parser.add_argument("--base-frame", default="base_link", help="the robot's frame in tf")


def bag(args):
    from swarmslam.formats.logs import BagOptions

    return BagOptions(args.scan_topic, args.odom_topic, args.odom_frame, args.base_frame)


def view_options(parser) -> None:
    parser.add_argument("--view", action="store_true",
                        help="watch it live in rerun (extra 'view'; without a display it serves "
                             "the web viewer and prints the address)")
    parser.add_argument("--record", metavar="FILE.rrd", help="save the rerun stream to open later")
    parser.add_argument("--mcap", metavar="FILE", help="an MCAP recording Foxglove opens "
                                                       "(scans, poses, frames, the map)")


def whole_number(text: str, least: int) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
    if value < least:
        raise argparse.ArgumentTypeError(f"must be at least {least}, got {value}")
    return value


def at_least_one(text: str) -> int:
    """A count argument: a whole number ≥ 1 (0 or −5 would silently mean "all" or "drop")."""
    return whole_number(text, 1)


def whole(text: str) -> int:
    """An index argument: a whole number ≥ 0."""
    return whole_number(text, 0)


def finite(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be finite, got {text!r}")
    return value


def positive(text: str) -> float:
    """A duration or rate: a finite number > 0."""
    value = finite(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {value:g}")
    return value


def non_negative(text: str) -> float:
    value = finite(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be ≥ 0, got {value:g}")
    return value


