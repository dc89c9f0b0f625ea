"""The front door: the README and docs a newcomer reads say what the code does — figures come
from the benchmarks' JSON, every command and flag named exists, every link resolves, every
Python example runs — and nothing cites an issue number."""

import argparse
import json
import re
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from swarmslam.bench.report import BEGIN, END, bench_report, headline, results_page
from swarmslam.cli import HELP, build_parser

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
# The pages a user reads as the current state; docs/experiments/ are dated records of past
# rounds (their commands are those of their commit) and are left out of the command check.
PAGES = [README, ROOT / "hardware" / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def test_the_readme_is_at_most_300_lines():
    assert len(README.read_text(encoding="utf-8").splitlines()) <= 300


def test_the_results_page_and_the_readme_block_are_what_the_json_gives():
    assert bench_report(ROOT / "bench-results", ROOT / "docs" / "results.md", README,
                        check=True, echo=lambda text: None) == 0


def _posegraph(chi2=215.8302, ms=8.84):
    return {"benchmark": "posegraph", "graphs": {"INTEL": {
        "chi2": chi2, "chi2_g2o": 215.830, "ms_median": ms, "g2o_ms": 12.0}},
        "meta": {"commit": "0123456789abcdef", "dirty": False, "date": "2026-11-25T20:00:00",
                 "command": "swarmslam bench posegraph --json p.json", "cpu": "CPU X",
                 "cpu_target": "znver4", "cores": 2, "python": "3.11", "numba": "0.68",
                 "shared_machine": False}}


def test_a_report_shows_the_json_figures_and_a_check_fails_when_they_change(tmp_path):
    results = tmp_path / "results"
    results.mkdir()
    (results / "posegraph.json").write_text(json.dumps(_posegraph()))
    readme = tmp_path / "README.md"
    readme.write_text(f"# X\n\n{BEGIN}\nold\n{END}\n\nrest\n")
    page = tmp_path / "results.md"
    assert bench_report(results, page, readme, echo=lambda text: None) == 0
    text = page.read_text()
    assert "| INTEL | 215.830 | 215.830 | 8.8 | 12 |" in text
    assert "swarmslam bench posegraph --json p.json" in text and "Commit 0123456" in text
    assert "CPU X (znver4) × 2 cores" in text
    assert "nothing else heavy running" in text and "χ² as g2o's — **met**" in text
    assert readme.read_text().endswith(f"{END}\n\nrest\n") and "old" not in readme.read_text()
    assert bench_report(results, page, readme, check=True, echo=lambda text: None) == 0
    (results / "posegraph.json").write_text(json.dumps(_posegraph(chi2=300.0)))
    told = []
    assert bench_report(results, page, readme, check=True, echo=told.append) == 1
    assert any(str(page) in t for t in told)
    assert "**missed**" in results_page(results)
    assert headline(results).startswith(BEGIN)


def _slam_row(audited=True, unexplained=(0, 0)):
    row = {"dataset": "mit", "optimizer": "abc", "odometry": True, "eT_mean": 0.0286,
           "eT_worst": 0.0289, "eR_deg_mean": 0.401, "eR_deg_worst": 0.405,
           "eR_short_median_deg_mean": 0.27, "eR_short_p99_deg_mean": 1.79,
           "eR_short_max_deg_mean": 8.8, "real_time_factor_min": 32.8}
    if audited:
        row.update(eR_short_confirmed_deg_mean=0.37, eR_short_confirmed_p99_deg_mean=1.71,
                   eR_short_over_10deg_confirmed_mean=float(np.mean(unexplained)),
                   eR_short_over_10deg_confirmed_worst=float(max(unexplained)))
    return row


def test_the_slam_table_shows_short_relations_over_those_the_scans_do_not_contradict(tmp_path):
    results = tmp_path / "results"
    results.mkdir()
    slam = {"benchmark": "slam", "seeds": [0, 1], "summary": [_slam_row()]}
    (results / "slam.json").write_text(json.dumps(slam))
    page = results_page(results)
    assert "| 0.27 / 1.79 / 8.8 | 0.37 / 1.71 / 0.0 (0) | 32.8 |" in page
    assert ("MIT-CSAIL: no short relation above 10° that its scans do not contradict — **met**"
            in page)
    slam["summary"] = [_slam_row(unexplained=(0, 2))]
    (results / "slam.json").write_text(json.dumps(slam))
    page = results_page(results)
    assert "| 0.37 / 1.71 / 1.0 (2) |" in page
    assert "do not contradict — **missed**" in page
    slam["summary"] = [_slam_row(audited=False)]  # results recorded before the audit
    (results / "slam.json").write_text(json.dumps(slam))
    page = results_page(results)
    assert "| 0.27 / 1.79 / 8.8 | — | 32.8 |" in page and "contradict —" not in page


def _commands(parser, prefix=()):
    """Every command path of the parser, with its options."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                path = (*prefix, name)
                options = {o for a in sub._actions for o in a.option_strings}
                yield path, sub, options
                yield from _commands(sub, path)


def _mentions(text):
    """(command words, flags) of each ``swarmslam ...`` the text names, up to the end of its
    line, a pipe, a ``#`` comment, a backtick or a shell separator."""
    for match in re.finditer(r"swarmslam ((?:[a-z][\w-]*)(?: [^\n`|#;&)]*)?)", text):
        yield match.group(1).split()


def test_a_mention_is_read_as_its_command_and_flags():
    assert list(_mentions("run `swarmslam replay x --bogus` now; swarmslam bench env # y")) == [
        ["replay", "x", "--bogus"], ["bench", "env"]]


def test_every_command_and_flag_the_readme_and_docs_name_exists():
    commands = {path: options for path, _, options in _commands(build_parser())}
    missing = []
    for page in PAGES:
        for words in _mentions(page.read_text(encoding="utf-8")):
            path = ()
            for word in words:
                if (*path, word) in commands:
                    path = (*path, word)
                else:
                    break
            if not path:  # a word after "swarmslam" that is no command
                missing.append(f"{page.name}: swarmslam {' '.join(words)}")
                continue
            for flag in (w.split("=")[0] for w in words if w.startswith("--")):
                if flag not in commands[path]:
                    missing.append(f"{page.name}: swarmslam {' '.join(path)} {flag}")
    assert not missing, "\n".join(missing)


def test_every_command_has_a_description_and_an_example_that_parses():
    parser = build_parser()
    for path, sub, _ in _commands(parser):
        description, example = HELP[" ".join(path)]
        assert sub.description and sub.epilog.startswith("example:")
        words = shlex.split(re.split(r"[#>|;]", example)[0])  # the command, not the shell
        assert words[0] == "swarmslam" and tuple(words[1:len(path) + 1]) == path
        parser.parse_args(words[1:])  # the example is a valid command line


def test_every_relative_link_resolves():
    broken = []
    for page in [*PAGES, *sorted((ROOT / "docs" / "experiments").glob("*.md"))]:
        for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", page.read_text(encoding="utf-8")):
            if "://" in target or target.startswith("mailto:"):
                continue
            if not (page.parent / target).exists():
                broken.append(f"{page.relative_to(ROOT)}: {target}")
    assert not broken, "\n".join(broken)


def test_nothing_in_the_repository_cites_an_issue_number():
    pattern = re.compile(r"\bissues? #?\d+|\(#\d+\)", re.IGNORECASE)
    files = subprocess.run(["git", "-C", str(ROOT), "ls-files", "--cached", "--others",
                            "--exclude-standard"], capture_output=True, text=True).stdout.split()
    found = []
    for name in files:
        path = ROOT / name
        if path.suffix not in (".py", ".md", ".toml", ".txt", ".rules", ".world", ".cfg") \
                or not path.exists() or path == Path(__file__):
            continue
        for k, line in enumerate(path.read_text(encoding="utf-8", errors="replace")
                                 .splitlines(), 1):
            if pattern.search(line):
                found.append(f"{name}:{k}: {line.strip()[:80]}")
    assert not found, "\n".join(found)


@pytest.mark.parametrize("index", range(4))
def test_every_python_example_in_the_readme_runs(index, tmp_path):
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(encoding="utf-8"), re.S)
    assert len(blocks) == 4
    done = subprocess.run([sys.executable, "-c", blocks[index]], cwd=tmp_path,
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip()


def test_the_robustness_section_names_each_gross_seed_and_the_spread_target(tmp_path):
    results = tmp_path / "results"
    results.mkdir()
    row = {"runs": 10, "eT_scored_median": 0.0503, "eT_scored_worst": 0.0563,
           "eT_scored_spread": 1.12, "eR_deg_median": 0.505, "eR_deg_worst": 0.520,
           "eT_global_median": 0.064, "eT_global_worst": 0.066, "gross": []}
    bent = dict(row, eT_scored_worst=0.176, eT_scored_spread=3.5,
                gross=[{"seed": 7, "why": ["eT 0.176 m"]}])
    (results / "robustness.json").write_text(json.dumps(
        {"benchmark": "robustness", "gross_ratio": 2.0, "gross_eT": 0.1, "seeds": list(range(10)),
         "summary": {"fr079/raw": row, "intel/every-2nd": bent}}))
    page = results_page(results)
    assert ("| FR079 / raw | 10 | 0.0503 / 0.0563 | 1.12 | 0.505 / 0.520 | 0.064 / 0.066 "
            "| none |") in page
    assert "| Intel / every-2nd | 10 | 0.0503 / 0.1760 | 3.50 |" in page and "| seed 7 |" in page
    assert "FR079 / raw: no gross run — **met**" in page
    assert "Intel / every-2nd: no gross run — **missed**" in page
    assert "Intel / every-2nd: worst ÷ median eT ≤ 1.25 — **missed**" in page
