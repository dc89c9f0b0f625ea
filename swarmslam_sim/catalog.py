"""Worlds by name: the built-in ``.world`` files (package data of ``worlds``), the seeded
generators, or a path."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from swarmslam_sim.generators import GENERATORS
from swarmslam_sim.world import World, load_world


def builtin_worlds() -> list[str]:
    return sorted(p.name[: -len(".world")] for p in resources.files("swarmslam.worlds").iterdir()
                  if p.name.endswith(".world"))


def get_world(spec, seed: int = 0) -> World:
    """A world from a name: a built-in world (``office``), a generator (``rooms``, ``maze``,
    ``clutter``, seeded by ``seed``), or a path to a ``.world`` file. A World passes through."""
    if isinstance(spec, World):
        return spec
    spec = str(spec)
    if spec in GENERATORS:
        return GENERATORS[spec](seed)
    packaged = resources.files("swarmslam.worlds") / f"{spec}.world"
    if packaged.is_file():
        with resources.as_file(packaged) as p:
            return load_world(p)
    if spec.endswith(".world") or Path(spec).exists():
        return load_world(spec)
    raise ValueError(f"unknown world {spec!r}: not a built-in ({', '.join(builtin_worlds())}), "
                     f"a generator ({', '.join(GENERATORS)}), or a .world file")
