"""``swarmslam tune`` (swarmslam.tune): Ray Tune with an Optuna search over configuration
fields, end to end on two tiny simulated logs, writes a configuration ``--config`` loads."""

import json

import pytest

from swarmslam.runtime.config import SlamConfig, load_config
from swarmslam.cli import main
from swarmslam.simlog import write_simlog
from swarmslam.sweep import SpecError
from swarmslam.tune import objective, read_tune_spec

SEARCH = """
[search]
"front_end.node_distance" = { low = 0.2, high = 0.6 }
"matcher.refine_evaluations" = { low = 200, high = 900 }
"matcher.swarm.optimizer" = { choices = ["abc", "pso"] }
"""


@pytest.fixture(scope="module")
def spec_path(tmp_path_factory):
    folder = tmp_path_factory.mktemp("tune")
    for seed in (2, 3):
        write_simlog(folder / f"hall{seed}.clf", "hall", seed=seed, lidar="rplidar-a1",
                     rate_hz=4.0, seconds=20)
    spec = folder / "tune.toml"
    spec.write_text('logs = ["hall2.clf", "hall3.clf"]\nseeds = [0]\ntrials = 6\nseed = 1\n'
                    'out = "best.toml"\n[reference]\n"hall2.clf" = 0.05\n"hall3.clf" = 0.05\n'
                    + SEARCH)
    return spec


def test_six_trials_end_to_end_write_a_loadable_best_configuration(spec_path, capsys):
    assert main(["tune", str(spec_path), "--workers", "1"]) == 0
    said = capsys.readouterr().out
    assert "best of 6 trials" in said
    best = spec_path.parent / "best.toml"
    config = load_config(best, SlamConfig())  # what --config does
    assert 0.2 <= config.front_end.node_distance <= 0.6
    assert 200 <= config.matcher.refine_evaluations <= 900
    assert config.matcher.swarm.optimizer in ("abc", "pso")
    # the file's configuration scores what the search said it did
    spec = read_tune_spec(spec_path)
    changes = {"front_end.node_distance": config.front_end.node_distance,
               "matcher.refine_evaluations": config.matcher.refine_evaluations,
               "matcher.swarm.optimizer": config.matcher.swarm.optimizer}
    score = objective(spec, changes)["objective"]
    assert f"worst ratio to the reference {score:.3f}" in said
    # every trial is kept beside it; the file's is the best of them
    trials = json.loads((spec_path.parent / "best.json").read_text())["trials"]
    assert len(trials) == 6 and min(t["objective"] for t in trials) == pytest.approx(score)
    assert len({t["objective"] for t in trials}) > 1  # the search did try different things


@pytest.mark.parametrize("text, said", [
    ("", "[search] names no configuration field"),
    ('[search]\n"front_end.node_distance" = [0.2, 0.6]\n', "must be a table"),
    ('[search]\n"front_end.node_distance" = { low = 0.6, high = 0.2 }\n', "low < high"),
    ('[search]\n"front_end.nowhere" = { low = 0.1, high = 0.2 }\n', "nowhere"),
])
def test_a_bad_tune_spec_is_refused_naming_the_field(spec_path, tmp_path, text, said):
    bad = tmp_path / "bad.toml"
    bad.write_text(f'logs = ["{spec_path.parent / "hall2.clf"}"]\n'
                   f'[reference]\n"{spec_path.parent / "hall2.clf"}" = 0.05\n' + text)
    with pytest.raises(SpecError, match="bad.toml") as raised:
        read_tune_spec(bad)
    assert said in str(raised.value)


def test_a_log_without_a_reference_is_refused(spec_path, tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text(f'logs = ["{spec_path.parent / "hall2.clf"}"]\n' + SEARCH)
    with pytest.raises(SpecError, match="has no published figure"):
        read_tune_spec(bad)


def test_a_log_without_relations_is_refused_before_any_trial(spec_path, tmp_path):
    bare = tmp_path / "bare.clf"
    bare.write_bytes((spec_path.parent / "hall2.clf").read_bytes())  # no bare.relations
    bad = tmp_path / "bad.toml"
    bad.write_text(f'logs = ["{bare}"]\n[reference]\n"{bare}" = 0.05\n' + SEARCH)
    with pytest.raises(SpecError, match="has no relations beside it"):
        read_tune_spec(bad)
