"""Where the public benchmark datasets are (they live beside the project, never inside it)."""

from __future__ import annotations

import os
from pathlib import Path

ENV = "SWARMSLAM_DATASETS"


class DatasetsNotFound(FileNotFoundError):
    pass


def find_datasets(explicit=None) -> Path:
    """The datasets folder: ``explicit``, ``$SWARMSLAM_DATASETS``, or ``../shared/datasets``
    seen from the working directory or from the project checkout."""
    if explicit:  # asked for by name: that folder or an error, never a silent substitute
        if not Path(explicit).is_dir():
            raise DatasetsNotFound(f"datasets folder {explicit} does not exist")
        return Path(explicit).resolve()
    here = Path(__file__).resolve().parent.parent
    candidates = [
        os.environ.get(ENV),
        Path.cwd() / ".." / "shared" / "datasets",
        here / ".." / "shared" / "datasets",
    ]
    tried = []
    for c in candidates:
        if not c:
            continue
        p = Path(c)
        tried.append(str(p))
        if p.is_dir():
            return p.resolve()
    raise DatasetsNotFound(
        "benchmark datasets not found (looked in: "
        + ", ".join(tried)
        + f"); pass --data DIR or set {ENV}"
    )


def require(path: Path) -> Path:
    if not path.exists():
        raise DatasetsNotFound(f"{path}: missing dataset file")
    return path
