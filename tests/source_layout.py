"""The installed layout of the sources, read from ``pyproject.toml``: the repository's folders
(``runtime/``, ``scripts/``, ...) become the ``swarmslam`` namespace (``swarmslam.runtime``,
``swarmslam``, ...) through setuptools' package-dir mapping."""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

ROOT = Path(__file__).resolve().parent.parent


def package_dirs() -> dict[str, str]:
    """Import name → the repository folder that holds it, for every packaged package."""
    setup = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    mapping = setup.get("package-dir", {})
    return {name: mapping.get(name, name.replace(".", "/")) for name in setup["packages"]}


def copy_installed_layout(dest: Path) -> Path:
    """The sources copied under ``dest`` as they install (``dest/swarmslam/runtime/...``),
    without compiled caches: ``dest`` on ``sys.path`` imports this copy."""
    dirs = package_dirs()
    for name in sorted(dirs, key=lambda n: n.count(".")):  # parents before their children
        target = dest.joinpath(*name.split("."))
        target.mkdir(parents=True, exist_ok=True)
        for path in (ROOT / dirs[name]).iterdir():
            if path.is_file():
                shutil.copy2(path, target / path.name)
    return dest
