"""Numba's on-disk kernel cache, kept true to the sources (docs/runtime.md §8).

``njit(cache=True)`` keys each kernel's cache on its own file alone: a kernel that calls (or
inlines) a kernel of another file keeps the callee it was compiled with after that file
changes. An edit could thus leave stale machine code running — measured here: a replay's
figures differed from a clean checkout's until the caches were cleared. So at import each
package fingerprints its sources, and when they differ from the fingerprint its caches were
made under, those caches are dropped and the kernels compile afresh once.

    refresh(Path(__file__).parent)   # in a package's __init__.py
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from pathlib import Path

import numba
from numba.misc.appdirs import AppDirs

STAMP = "kernel-sources.sha256"  # in the package's __pycache__
CACHE_SUFFIXES = (".nbi", ".nbc")  # numba's index and compiled-code files


def _writable(folder: Path) -> bool:
    """Whether a file can be made in ``folder`` (made if missing): tried, not assumed."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        tempfile.TemporaryFile(dir=folder).close()
        return True
    except OSError:
        return False


def ensure_cache_folder(package: Path) -> Path | None:
    """Where numba can cache the package's kernels. It caches beside the sources, or where
    those cannot be written (an installed package) in the user's cache folder; where that
    cannot be written either (a HOME that cannot be), every ``cache=True`` kernel would fail
    at import. Then a folder of this user's in the temporary directory takes them. Returns
    the folder chosen here (None: numba's own choice stands)."""
    if numba.config.CACHE_DIR or _writable(package / "__pycache__"):
        return None
    if _writable(Path(AppDirs(appname="numba", appauthor=False).user_cache_dir)):
        return None
    fallback = Path(tempfile.gettempdir()) / f"swarmslam-numba-{os.getuid()}"
    if _writable(fallback):
        numba.config.CACHE_DIR = str(fallback)
        return fallback
    return None


def source_digest(package: Path) -> str:
    """SHA-256 over the package's Python sources (names and contents, in a fixed order)."""
    h = hashlib.sha256()
    for path in sorted(package.rglob("*.py")):
        h.update(str(path.relative_to(package)).encode())
        h.update(b"\0")
        h.update(path.read_bytes())
    return h.hexdigest()


def refresh(package) -> bool:
    """Drop ``package``'s numba caches if its sources changed since they were made; True if
    they were dropped. A package that cannot be written (an installed one, whose sources do
    not change) is left as it is."""
    package = Path(package)
    ensure_cache_folder(package)
    digest = source_digest(package)
    stamp = package / "__pycache__" / STAMP
    try:
        if stamp.is_file() and stamp.read_text() == digest:
            return False
        for folder in package.rglob("__pycache__"):
            for path in folder.iterdir():
                if path.suffix in CACHE_SUFFIXES:
                    path.unlink(missing_ok=True)
        stamp.parent.mkdir(exist_ok=True)
        temporary = stamp.with_name(f"{STAMP}.{os.getpid()}.tmp")
        temporary.write_text(digest)
        os.replace(temporary, stamp)  # processes starting together see one stamp or none
        return True
    except OSError:
        return False
