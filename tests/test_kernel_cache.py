"""swarmslam.runtime.realtime.kernel_cache: numba caches made under other sources are dropped at import, so no
stale compiled kernel runs after an edit (numba keys a cache on its own file only)."""

from swarmslam.runtime.realtime.kernel_cache import STAMP, refresh


def test_caches_made_under_other_sources_are_dropped(tmp_path):
    package = tmp_path / "pkg"
    (package / "sub" / "__pycache__").mkdir(parents=True)
    (package / "__pycache__").mkdir()
    (package / "a.py").write_text("x = 1\n")
    (package / "sub" / "b.py").write_text("y = 2\n")
    caches = [package / "__pycache__" / "a.f-1.py311.nbi",
              package / "sub" / "__pycache__" / "b.g-3.py311.1.nbc"]
    kept = package / "__pycache__" / "a.cpython-311.pyc"  # Python's own: not numba's
    for path in (*caches, kept):
        path.write_bytes(b"compiled")
    assert refresh(package)  # no stamp yet: the caches' sources are unknown
    assert not any(p.exists() for p in caches) and kept.exists()
    assert (package / "__pycache__" / STAMP).is_file()
    for path in caches:  # compiled again under these sources
        path.write_bytes(b"compiled")
    assert not refresh(package) and all(p.exists() for p in caches)
    (package / "sub" / "b.py").write_text("y = 3\n")  # an edit in another file
    assert refresh(package) and not any(p.exists() for p in caches)
    assert not refresh(package)


def test_a_package_that_cannot_be_written_is_left_alone(tmp_path):
    package = tmp_path / "pkg"
    package.mkdir()
    (package / "a.py").write_text("x = 1\n")
    (package / "__pycache__").write_text("not a folder")  # any OSError: nothing is done
    assert not refresh(package)
