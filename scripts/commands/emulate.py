"""``swarmslam emulate``: a virtual RPLidar on a pseudo-terminal (swarmslam.hardware.emulator)."""

from __future__ import annotations

import time

from swarmslam.commands.common import MODELS, sigterm_as_ctrl_c
from swarmslam.runtime.realtime.writers import write_bytes_atomic

# (what the command does, reads and writes; an example), shown by its --help
HELP = {
    "emulate": ("A virtual RPLidar on a pseudo-terminal, answering the protocol and streaming "
                "scans of a simulated world (a robot exploring it) or a CARMEN log, with "
                "optional faults. Point `swarmslam lidar --port` at the link it prints.",
                "swarmslam emulate --world office --link /tmp/rplidar  # then: swarmslam "
                "lidar --port /tmp/rplidar"),
}


def add(sub) -> None:
    """The command's parser, under ``sub`` (the CLI's subparsers)."""
    em = sub.add_parser("emulate", help="a virtual RPLidar on a pseudo-terminal")
    source = em.add_mutually_exclusive_group()
    source.add_argument("--world", default="office", help="simulated world it scans")
    source.add_argument("--log", help="a CARMEN log it replays instead")
    em.add_argument("--model", default="a1", choices=MODELS)
    em.add_argument("--faults", help="e.g. garbage=0.01,corrupt=0.01,stall=10:2,vanish=30:1")
    em.add_argument("--link", help="also make this symlink point at the port (stable name)")
    em.add_argument("--seed", type=int, default=0)
    em.add_argument("--typical", metavar="MODE",
                    help="advertise this scan mode of the model as typical (to try a client)")
    em.add_argument("--record", metavar="FILE",
                    help="on stopping, write every byte the emulator sent to FILE")
    em.set_defaults(func=_emulate)


def _emulate(args) -> int:
    from swarmslam.hardware.emulator import Faults, VirtualRPLidar

    if args.log:
        from swarmslam.emulator_sources import CarmenSource

        source, what = CarmenSource(args.log), f"log {args.log}"
    else:
        from swarmslam.emulator_sources import WorldSource

        source, what = WorldSource(args.world, seed=args.seed), f"world {args.world}"
    faults = Faults.parse(args.faults or "")
    emulator = VirtualRPLidar(source, args.model, faults, args.seed, args.link,
                              typical=args.typical)
    emulator.record = bool(args.record)
    with sigterm_as_ctrl_c():
        path = emulator.start()
        print(f"virtual RPLidar {args.model.upper()} ({what}) on {path}")
        print(f"connect with: swarmslam lidar --port {path} --model {args.model}")
        if faults != Faults():
            print(f"faults: {faults}")
        print("Ctrl-C to stop", flush=True)
        try:
            while True:
                time.sleep(1.0)
        finally:
            emulator.stop()
            if args.record:
                write_bytes_atomic(args.record, bytes(emulator.sent))
            print(f"emulator: {emulator.stats}")


