"""The configuration tree: one validation, presets, TOML in and out, and the CLI's view of it."""

import dataclasses
import math

import pytest

from swarmslam.hardware.models import MODELS
from swarmslam.runtime.config import (
    OPTIMIZERS,
    PRESETS,
    REMOVED_FIELDS,
    RPLIDAR_MODELS,
    SIMULATED_LIDARS,
    ConfigError,
    SlamConfig,
    from_dict,
    from_toml,
    load_config,
    override,
    preset,
    rplidar_points,
    session_changes,
    to_dict,
    to_toml,
)
from swarmslam.runtime.matching.objectives import KERNELS
from swarmslam.runtime.matching.optimizers import ABC, FA, PSO
from swarmslam.cli import main
from swarmslam_sim.lidar import PRESETS as SIM_LIDARS


def leaves(config, prefix=""):
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        key = f"{prefix}{f.name}"
        if dataclasses.is_dataclass(value):
            yield from leaves(value, key + ".")
        else:
            yield key, f, value


def test_every_field_is_documented():
    missing = [key for key, f, _ in leaves(SlamConfig()) if not f.metadata.get("doc")]
    assert not missing


@pytest.mark.parametrize("name", list(PRESETS))
def test_toml_round_trips_every_preset(name):
    config = preset(name)
    assert from_toml(to_toml(config)) == config
    assert from_toml(to_toml(config, comments=False)) == config


def test_one_changed_field_changes_that_field_only(tmp_path):
    path = tmp_path / "mine.toml"
    path.write_text("[front_end]\nnode_distance = 0.4\n")
    changed = load_config(path)
    before, after = to_dict(SlamConfig()), to_dict(changed)
    assert after["front_end"]["node_distance"] == 0.4
    after["front_end"]["node_distance"] = before["front_end"]["node_distance"]
    assert after == before


def test_none_and_integers_where_floats_are_expected(tmp_path):
    config = from_toml('[front_end]\nodometry_gate = "none"\nnode_angle = 1\n')
    assert config.front_end.odometry_gate is None
    assert config.front_end.node_angle == 1.0 and isinstance(config.front_end.node_angle, float)


@pytest.mark.parametrize("text, message", [
    ("[front_end]\nnode_distanse = 0.4\n", r"mine.toml: front_end.node_distanse: unknown key"),
    ("[frontend]\nnode_distance = 0.4\n", r"mine.toml: frontend: unknown key"),
    ("[front_end]\nnode_distance = \"far\"\n", r"front_end.node_distance: must be a number"),
    ("[front_end]\nnode_distance = -1\n", r"front_end.node_distance: must be > 0, got -1"),
    ("[capacity]\nmax_nodes = 10.5\n", r"capacity.max_nodes: must be a whole number"),
    ("[matcher.swarm]\noptimizer = \"gwo\"\n", r"matcher.swarm.optimizer: must be one of"),
    ("[matcher]\nguess_window = [0.3, 0.3]\n", r"matcher.guess_window: needs 3 values"),
    ("[runtime]\nrate_hz = 100\ntick_budget = 0.05\n", r"runtime.tick_budget: must fit the period"),
    ("[front_end]\nrecovery_heading_step = 0.001\n",
     r"front_end.recovery_heading_step: must be 0 or >= 0.005"),
    ("[front_end]\nnode_distance = 0.4\n[[oops\n", r"mine.toml: not valid TOML"),
    ("[front_end]\ninformation = true\n", r"front_end.information: must be a string"),
    ("[matcher]\nscan_to_map = 1\n", r"matcher.scan_to_map: must be true or false"),
])
def test_bad_fields_are_named(tmp_path, text, message):
    path = tmp_path / "mine.toml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=message):
        load_config(path)


def test_built_configs_are_validated_too():
    with pytest.raises(ConfigError, match="front_end.node_distance: must be > 0"):
        override(SlamConfig(), {"front_end.node_distance": 0.0})
    with pytest.raises(ConfigError, match="map.resolution: must be finite"):
        override(SlamConfig(), {"map.resolution": math.nan})


def test_a_saved_sessions_search_and_tracking_may_change_its_map_settings_not(tmp_path):
    path = tmp_path / "mine.toml"
    path.write_text("[relocalization]\ndistinct_distance = 1\nrefine_window = [0.2, 0.2, 0.05]\n"
                    "[localization]\nconfirm_misses = 3\n")
    changes = session_changes(path)
    changed = override(SlamConfig(), changes)
    assert changed.relocalization.distinct_distance == 1.0
    assert changed.relocalization.refine_window == (0.2, 0.2, 0.05)
    assert changed.localization.confirm_misses == 3.0
    assert dataclasses.replace(changed, relocalization=SlamConfig().relocalization,
                               localization=SlamConfig().localization) == SlamConfig()
    for text, message in [
        ("[front_end]\nnode_distance = 0.4\n", r"mine.toml: \[front_end\]: a saved session "
         r"keeps the configuration its map was made with; only \[localization\], "
         r"\[relocalization\] may change"),
        ("seed = 3\n", r"mine.toml: \[seed\]"),
        ("[relocalization]\ndistinct_distanse = 1\n",
         r"mine.toml: relocalization.distinct_distanse: unknown key"),
        ("[localization]\nconfirm_misses = -1\n", r"mine.toml: localization.confirm_misses"),
    ]:
        path.write_text(text)
        with pytest.raises(ConfigError, match=message):
            session_changes(path)


def test_one_list_of_optimizers_and_kernels():
    assert (OPTIMIZERS[PSO], OPTIMIZERS[ABC], OPTIMIZERS[FA]) == ("pso", "abc", "fa")
    assert set(KERNELS) == {"paper", "cauchy"}


def test_presets_agree_with_the_hardware_and_simulator_tables():
    for name, (sps, hz, reach) in RPLIDAR_MODELS.items():
        m = MODELS[name]
        assert (m.max_samples_per_second, m.scan_hz, m.max_range) == (sps, hz, reach)
        c = preset(f"rplidar-{name}")
        assert c.sensor.max_points == rplidar_points(sps, hz) and c.map.max_range == reach
        # the reference grid holds the scanner's reach both ways and its submaps' spread
        side = c.matcher.grid_cells * c.matcher.resolution
        assert side >= 2 * (reach + 5.0) and (reach > 20.0) == (c.matcher.grid_cells > 1024)
    assert preset("rplidar-a1").sensor.max_points == 973  # 4000 / 5.5 × 1.25 + 64
    for name, (beams, lo, hi) in SIMULATED_LIDARS.items():
        lidar = SIM_LIDARS[name]
        assert (lidar.beams, lidar.min_range, lidar.max_range) == (beams, lo, hi)
        assert preset(f"sim-{name}").sensor.max_points == beams
        assert preset(f"sim-{name}").matcher.grid_cells == (1024 if hi <= 20.0 else 2048)


def test_config_show_prints_the_defaults_and_a_file_changes_one_field(tmp_path, capsys):
    assert main(["config", "show", "--bare"]) == 0
    assert from_toml(capsys.readouterr().out) == SlamConfig()
    path = tmp_path / "mine.toml"
    path.write_text("[loop_closure]\nmin_overlap = 0.4\n")
    assert main(["config", "show", "rplidar-a2", "--config", str(path)]) == 0
    shown = from_toml(capsys.readouterr().out)
    assert shown == override(preset("rplidar-a2"), {"loop_closure.min_overlap": 0.4})


def test_a_bad_config_file_is_a_clear_error_from_the_cli(tmp_path, capsys):
    path = tmp_path / "bad.toml"
    path.write_text("[front_end]\nnode_distanse = 0.4\n")
    assert main(["replay", "nowhere.clf", "--config", str(path)]) == 2
    assert "bad.toml: front_end.node_distanse: unknown key" in capsys.readouterr().err


def _shown_fields(argv, capsys) -> list[str]:
    assert main(["config", "show", *argv]) == 0
    return [line.split(" = ")[0] for line in capsys.readouterr().out.splitlines()
            if " = " in line and not line.startswith("#")]


def test_config_show_lists_at_most_100_fields_and_basic_at_most_20(capsys):
    from swarmslam.runtime.config import BASIC_FIELDS, EXPERT_FIELDS, field_names

    every = field_names()
    assert (BASIC_FIELDS | EXPERT_FIELDS) <= set(every)  # no level names a field that is gone
    assert not BASIC_FIELDS & EXPERT_FIELDS
    assert len(_shown_fields([], capsys)) == len(every) - len(EXPERT_FIELDS) <= 100
    assert len(_shown_fields(["--basic"], capsys)) == len(BASIC_FIELDS) <= 20
    assert len(_shown_fields(["--all"], capsys)) == len(every)


@pytest.mark.parametrize("level", ["basic", "standard"])
def test_a_shorter_listing_is_a_valid_file_of_the_fields_it_shows(level):
    """Read back over the preset, the listing gives the shown fields' values; what it leaves
    out keeps the preset's."""
    base = preset("rplidar-a2")
    config = override(base, {"front_end.node_distance": 0.3, "loop_closure.wide_levels": 5})
    back = from_toml(to_toml(config, level=level), base=base)
    assert back.front_end.node_distance == 0.3  # basic: shown at every level
    assert back.loop_closure.wide_levels == base.loop_closure.wide_levels  # internal: left out
    assert back == override(config, {"loop_closure.wide_levels": base.loop_closure.wide_levels})


def test_no_removed_field_is_a_field_again():
    """A name in REMOVED_FIELDS is dropped from every file and session that names it: one the
    configuration has again would be ignored without a word (odometry_scale_dead_zone was)."""
    fields = to_dict(SlamConfig())
    again = [path for path in REMOVED_FIELDS
             if path.split(".")[1] in fields[path.split(".")[0]]]
    assert not again, again
    changed = from_dict({"front_end": {"odometry_scale_dead_zone": 0.02}})
    assert changed.front_end.odometry_scale_dead_zone == 0.02


def test_a_removed_field_left_off_reads_and_one_turned_on_is_refused_by_name():
    """A session or file from the version that still had the opt-ins: their keys at the
    values that left them off read as before; one that turned its path on needs that version."""
    older = to_dict(SlamConfig())
    older["front_end"].update(odometry_noise_window=0, match_heading_sigma=[0.0035, 0.014],
                              odometry_scale_window=0)
    older["loop_closure"].update(wide_total_gate="none", degenerate_share="floor",
                                 stale_turn_window=0.6)
    assert from_dict(older) == SlamConfig()
    older["front_end"]["odometry_noise_window"] = 200
    with pytest.raises(ConfigError, match=r"front_end.odometry_noise_window = 200: this opt-in "
                                          r"was removed.*docs/configuration.md"):
        from_dict(older)
