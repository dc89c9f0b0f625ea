"""The layering the project promises (README, "Layout"), read from the source itself:
``scripts`` → (``swarmslam_sim``, ``hardware``) → ``runtime``; ``runtime`` deploys alone on
numpy/scipy/numba; no import cycle, and none hidden by an import inside a function. Installed,
the folders are one namespace (``swarmslam.runtime``, ``swarmslam.hardware``, ``swarmslam``
for ``scripts``...; tests/source_layout.py), and the sources import each other by those names
only."""

import ast
import re
import sys
import zipfile
from pathlib import Path

import pytest

from source_layout import ROOT, package_dirs

FOLDERS = ("runtime", "hardware", "swarmslam_sim", "scripts", "worlds")
# What each folder may import from the project.
ALLOWED = {
    "runtime": {"runtime"},
    "hardware": {"hardware", "runtime"},
    "swarmslam_sim": {"swarmslam_sim", "runtime", "worlds"},
    "worlds": set(),
    "scripts": set(FOLDERS),
}
RUNTIME_THIRD_PARTY = {"numpy", "scipy", "numba", "tomli"}
# The folders' installed import names, longest first (``swarmslam`` holds ``scripts``).
INSTALLED = sorted(((name, folder.split("/")[0]) for name, folder in package_dirs().items()),
                   key=lambda item: -len(item[0]))
PACKAGE_OF = {folder: name for name, folder in package_dirs().items() if "/" not in folder}


def folder_of(module: str) -> str | None:
    """The repository folder an installed module name lives in (None: not the project's)."""
    for name, folder in INSTALLED:
        if module == name or module.startswith(name + "."):
            return folder
    return None


def module_name(path: Path) -> str:
    """A source file's installed module name."""
    folder = path.relative_to(ROOT).parts[0]
    parts = [*PACKAGE_OF[folder].split("."), *path.relative_to(ROOT / folder).with_suffix("").parts]
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imports(path: Path):
    """(imported module, line, inside a function?) for every import statement in ``path``."""
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    found = []

    def visit(node, in_function):
        for child in ast.iter_child_nodes(node):
            nested = in_function or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef))
            if isinstance(child, ast.Import):
                found.extend((a.name, child.lineno, in_function) for a in child.names)
            elif isinstance(child, ast.ImportFrom) and child.level == 0 and child.module:
                found.append((child.module, child.lineno, in_function))
                # ``from swarmslam.runtime import session``: the submodule is what is imported
                found.extend((f"{child.module}.{a.name}", child.lineno, in_function)
                             for a in child.names)
            visit(child, nested)

    visit(tree, False)
    return found


def project_graph():
    files = {module_name(p): p for folder in FOLDERS for p in (ROOT / folder).rglob("*.py")}
    edges = {}
    for name, path in files.items():
        targets = set()
        for target, line, in_function in imports(path):
            if folder_of(target) and target in files and target != name:
                targets.add((target, line, in_function))
        edges[name] = targets
    return files, edges


FILES, EDGES = project_graph()


def test_the_graph_covers_the_project():
    assert {"swarmslam.runtime.slam", "swarmslam.runtime.front_end.tracker",
            "swarmslam.runtime.back_end.slices", "swarmslam.runtime.config", "swarmslam.hardware.driver", "swarmslam_sim.env",
            "swarmslam.cli", "swarmslam.bench.slam", "swarmslam.worlds"} <= set(FILES)


@pytest.mark.parametrize("folder", FOLDERS)
def test_each_folder_imports_only_what_it_may(folder):
    wrong = [f"{src}:{line} imports {dst}" for src, targets in EDGES.items()
             if folder_of(src) == folder
             for dst, line, _ in targets if folder_of(dst) not in ALLOWED[folder]]
    assert not wrong, "\n".join(wrong)


def test_runtime_needs_numpy_scipy_numba_only():
    stdlib = set(sys.stdlib_module_names)
    wrong = []
    for name, path in FILES.items():
        if folder_of(name) != "runtime":
            continue
        for target, line, _ in imports(path):
            top = target.split(".")[0]
            if top not in stdlib and top not in RUNTIME_THIRD_PARTY \
                    and folder_of(target) != "runtime":
                wrong.append(f"{name}:{line} imports {target}")
    assert not wrong, "\n".join(wrong)


def test_no_import_cycle_even_through_imports_inside_functions():
    graph = {src: {dst for dst, _, _ in targets} for src, targets in EDGES.items()}
    state, cycle = {}, []

    def visit(node, path):
        state[node] = "open"
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == "open":
                cycle.extend(path[path.index(nxt):] + [nxt] if nxt in path else [node, nxt])
                return True
            if nxt not in state and visit(nxt, path + [nxt]):
                return True
        state[node] = "done"
        return False

    for node in sorted(graph):
        if node not in state and visit(node, [node]):
            break
    assert not cycle, " -> ".join(cycle)


@pytest.mark.parametrize("folder", ["runtime", "hardware", "swarmslam_sim"])
def test_libraries_import_the_project_at_module_level_only(folder):
    """An import inside a function is where a cycle hides; the command line (swarmslam.cli)
    may import lazily to start fast, the libraries may not."""
    late = [f"{src}:{line} imports {dst} inside a function"
            for src, targets in EDGES.items() if folder_of(src) == folder
            for dst, line, in_function in targets if in_function]
    assert not late, "\n".join(late)


def test_a_cycle_is_found_when_there_is_one(tmp_path):
    """The checker itself: an import inside a function that closes a loop is seen."""
    (tmp_path / "a.py").write_text("import b\n")
    (tmp_path / "b.py").write_text("def f():\n    import a\n")
    found = imports(tmp_path / "b.py")
    assert found == [("a", 2, True)]


def test_every_citation_of_the_docs_points_at_a_section_that_exists():
    import re

    cited = []
    for name, path in FILES.items():
        text = path.read_text(encoding="utf-8")
        cited += [(name, doc, section) for doc, section in
                  re.findall(r"docs/(\w+\.md)(?:\s+§(\d+(?:\.\d+)?))?", text)]
    assert cited
    missing = []
    for name, doc, section in cited:
        path = ROOT / "docs" / doc
        if not path.exists():
            missing.append(f"{name} cites docs/{doc}, which does not exist")
        elif section and not re.search(rf"^#+ {re.escape(section)}\.? ", path.read_text(), re.M):
            missing.append(f"{name} cites docs/{doc} §{section}, which has no such section")
    assert not missing, "\n".join(missing)


def test_the_configuration_page_lists_every_field():
    import dataclasses

    from swarmslam.runtime.config import SlamConfig

    page = (ROOT / "docs" / "configuration.md").read_text(encoding="utf-8")

    def walk(section, prefix):
        for f in dataclasses.fields(section):
            value = getattr(section, f.name)
            if dataclasses.is_dataclass(value):
                yield from walk(value, f"{prefix}{f.name}.")
            else:
                yield prefix[:-1], f.name

    table = None
    absent = []
    for table, field in walk(SlamConfig(), ""):
        part = page.split(f"### `[{table}]`", 1)
        if len(part) < 2 or f"| `{field}` |" not in part[1].split("\n### ", 1)[0]:
            absent.append(f"{table}.{field}")
    assert not absent, absent


def test_the_sources_import_the_project_by_its_installed_names_only():
    """``import runtime`` or ``from scripts...`` would load a second copy of a module beside
    its ``swarmslam.`` one (or nothing at all, installed)."""
    wrong = [f"{path.relative_to(ROOT)}:{line} imports {target}"
             for folder in (*FOLDERS, "tests") for path in (ROOT / folder).rglob("*.py")
             for target, line, _ in imports(path)
             if target.split(".")[0] in {"runtime", "hardware", "scripts", "worlds"}]
    assert not wrong, "\n".join(wrong)


def test_the_distribution_installs_only_swarmslam_names(tmp_path):
    """The wheel ``pip install .`` installs: every top-level name starts with ``swarmslam``
    (``runtime`` or ``scripts`` would collide with other distributions), and the package
    data (worlds, udev rules) is inside."""
    import shutil
    import subprocess

    source = tmp_path / "source"
    source.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(ROOT / name, source / name)
    for folder in FOLDERS:
        shutil.copytree(ROOT / folder, source / folder,
                        ignore=shutil.ignore_patterns("__pycache__"))
    done = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps",
                           "--no-build-isolation", "-w", str(tmp_path / "wheel"), str(source)],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    (wheel,) = (tmp_path / "wheel").glob("swarmslam-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    top = {n.split("/")[0] for n in names if not n.split("/")[0].endswith(".dist-info")}
    assert top == {"swarmslam", "swarmslam_sim"}
    for expected in ("swarmslam/cli.py", "swarmslam/bench/slam.py", "swarmslam/runtime/slam.py",
                     "swarmslam/runtime/matching/optimizers/pso.py", "swarmslam/hardware/driver.py",
                     "swarmslam/worlds/office.world", "swarmslam/hardware/99-rplidar.rules",
                     "swarmslam_sim/env.py"):
        assert expected in names
    entry = next(n for n in names if n.endswith("entry_points.txt"))
    assert "swarmslam = swarmslam.cli:main" in zipfile.ZipFile(wheel).read(entry).decode()


# The public logs by name, and citations of the dated entries: figures measured on a log go
# stale in code; they belong in docs/experiments/ (or docs/method.md), never in runtime/.
DATASET_ANECDOTE = re.compile(
    r"\b(intel|aces3?|fr-?clinic|mit-csail|csail|fr-?079|m3500)\b|docs/experiments",
    re.IGNORECASE)


def runtime_sources():
    return sorted((ROOT / "runtime").rglob("*.py"))


def test_the_runtime_names_no_dataset_and_cites_no_experiment():
    found = [f"{path.relative_to(ROOT)}:{k}: {line.strip()}"
             for path in runtime_sources()
             for k, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
             if DATASET_ANECDOTE.search(line)]
    assert not found, "\n".join(found)


def test_the_anecdote_rule_finds_what_it_is_for():
    assert DATASET_ANECDOTE.search("the wrong closure on Intel raised χ² by 25.9")
    assert DATASET_ANECDOTE.search("fr-clinic seed 3") and DATASET_ANECDOTE.search("FR079")
    assert DATASET_ANECDOTE.search("(docs/experiments/2026-11-28-sweep.md)")
    assert not DATASET_ANECDOTE.search("the submap's surfaces and places")


def test_only_the_session_module_reads_a_state_with_a_fallback():
    """Each component restores required keys only; what an older session lacks, the
    migrations in runtime/realtime/session.py supply."""
    found = [f"{path.relative_to(ROOT)}:{k}" for path in runtime_sources()
             if path.name != "session.py"
             for k, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
             if re.search(r"\bstate\.get\(|\" in state\b", line)]
    assert not found, found


# The runtime's rooms (README, "Layout") and what each may import from the runtime: the
# matching is the ground floor, the front and back ends never meet but in the glue
# (``slam.py``), localization tracks as the front end does, and the fixed-rate runtime sits on
# top. "core" is the top-level modules the rooms share (configuration, poses, the pose graph,
# the node scans, the map); they stand on the matching alone.
ROOMS = ("matching", "front_end", "back_end", "localization", "realtime")
ROOM_ALLOWED = {
    "matching": {"matching", "core"},
    "front_end": {"front_end", "matching", "core"},
    "back_end": {"back_end", "matching", "core"},
    "localization": {"localization", "front_end", "matching", "core"},
    "core": {"core", "matching"},
}
GLUE = {"swarmslam.runtime", "swarmslam.runtime.slam"}


def room_of(module: str) -> str:
    parts = module.split(".")
    return parts[2] if len(parts) > 2 and parts[2] in ROOMS else "core"


def test_every_runtime_module_lives_in_a_room_or_is_the_core():
    core = sorted(name for name in FILES if folder_of(name) == "runtime" and name not in GLUE
                  and room_of(name) == "core")
    assert core == [f"swarmslam.runtime.{m}" for m in (
        "config", "node_scans", "occupancy_grid", "pose", "pose_graph", "resources",
        "step_result", "tallies")]
    assert {room_of(name) for name in FILES if folder_of(name) == "runtime"} == {*ROOMS, "core"}


def test_each_room_of_the_runtime_imports_only_what_it_may():
    wrong = [f"{src}:{line} imports {dst}" for src, targets in EDGES.items()
             if folder_of(src) == "runtime" and src not in GLUE
             and room_of(src) in ROOM_ALLOWED
             for dst, line, _ in targets
             if folder_of(dst) == "runtime" and dst not in GLUE
             and room_of(dst) not in ROOM_ALLOWED[room_of(src)]]
    assert not wrong, "\n".join(wrong)


def test_the_room_rule_finds_a_front_end_that_reaches_into_the_back_end():
    assert room_of("swarmslam.runtime.front_end.tracker") == "front_end"
    assert room_of("swarmslam.runtime.back_end.loop_trial") not in ROOM_ALLOWED["front_end"]
    assert room_of("swarmslam.runtime.pose_graph") in ROOM_ALLOWED["front_end"]


def test_every_package_folder_is_in_the_distribution():
    """A sub-package missing from pyproject.toml's list imports in an editable install (the
    folder is on the path) and is absent from a built one."""
    listed = set(package_dirs().values())
    folders = {str(init.parent.relative_to(ROOT)) for folder in FOLDERS
               for init in (ROOT / folder).rglob("__init__.py")}
    assert folders <= listed, sorted(folders - listed)
