"""The configuration tree: one validation, presets, TOML in and out, and the CLI's view of it."""

import dataclasses
import math

import pytest

from swarmslam.hardware.models import MODELS
from swarmslam.runtime.config import (
    OPTIMIZERS,
    PRESETS,
    BASIC,
    DOC_LENGTH,
    EXPERT,
    FIXED_FIELDS,
    REMOVED_FIELDS,
    RENAMED_FIELDS,
    RPLIDAR_MODELS,
    SIMULATED_LIDARS,
    STANDARD,
    SWITCHED_FIELDS,
    ConfigError,
    SlamConfig,
    field_level,
    field_names,
    from_dict,
    from_toml,
    nested_tables,
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
    config = from_toml('[optimizer]\nrobust_loops = "none"\n[front_end]\nnode_angle = 1\n')
    assert config.optimizer.robust_loops is None
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
    ("[front_end.recovery]\nheading_step = 0.001\n",
     r"front_end.recovery.heading_step: must be 0 or >= 0.005"),
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


def test_config_show_lists_at_most_60_fields_and_all_at_most_150(capsys):
    """Each field declares its level in its own metadata; the listings follow it."""
    every = field_names()
    levels = {key: field_level(key) for key in every}
    assert set(levels.values()) == {BASIC, STANDARD, EXPERT}
    shown = [key for key in every if levels[key] != EXPERT]
    assert _shown_fields([], capsys) == [key.rsplit(".", 1)[1] for key in shown]
    assert len(shown) <= 60
    assert len(_shown_fields(["--basic"], capsys)) == list(levels.values()).count(BASIC) <= 20
    assert len(_shown_fields(["--all"], capsys)) == len(every) <= 150


def test_every_field_doc_is_short():
    """Unit, what, what its default means: a rule's reasoning is docs/method.md's."""
    long = {key: len(f.metadata["doc"]) for key, f, _ in leaves(SlamConfig())
            if len(f.metadata["doc"]) > DOC_LENGTH}
    assert not long, long


def test_a_switch_is_an_enabled_flag_not_a_sentinel():
    """A component that can be off has ``enabled``; off, its rule never runs."""
    config = SlamConfig()
    sections = [config.front_end.odometry_gate, config.front_end.heading_prior,
                config.front_end.previous_scan_check, config.front_end.odometry_scale,
                config.loop_closure.agreement, config.loop_closure.wide_search]
    assert all(section.enabled is True for section in sections)
    off = override(config, {"front_end.odometry_gate.enabled": False})
    assert off.front_end.odometry_gate.tolerance == config.front_end.odometry_gate.tolerance


@pytest.mark.parametrize("level", ["basic", "standard"])
def test_a_shorter_listing_is_a_valid_file_of_the_fields_it_shows(level):
    """Read back over the preset, the listing gives the shown fields' values; what it leaves
    out keeps the preset's."""
    base = preset("rplidar-a2")
    config = override(base, {"front_end.node_distance": 0.3,
                             "loop_closure.wide_search.max_radius": 90.0})
    back = from_toml(to_toml(config, level=level), base=base)
    assert back.front_end.node_distance == 0.3  # basic: shown at every level
    internal = base.loop_closure.wide_search.max_radius  # expert: left out
    assert back.loop_closure.wide_search.max_radius == internal
    assert back == override(config, {"loop_closure.wide_search.max_radius": internal})


def test_no_older_name_is_a_field_again():
    """A name the older-names mapping takes is read as that mapping says: one this version has
    again would be renamed or dropped without a word (odometry_scale_dead_zone was)."""
    every = set(field_names())
    older = set(REMOVED_FIELDS) | set(FIXED_FIELDS) | set(RENAMED_FIELDS) | set(SWITCHED_FIELDS)
    assert not older & every
    assert set(RENAMED_FIELDS.values()) <= every
    changed = from_dict({"front_end": {"odometry_scale": {"limits": [0.9, 1.1]}}})
    assert changed.front_end.odometry_scale.limits == (0.9, 1.1)


def test_an_older_files_moved_and_switched_names_read_as_this_versions():
    """A file (or session) in the flat names of the version before: a moved field takes its
    new place, a sentinel turns its component off, any other value switches it on with it."""
    older = {"front_end": {"odometry_gate_share": [0.3, 0.4], "odometry_gate": "none",
                           "odometry_heading_weight": 2.5, "previous_scan_gain": 1.0,
                           "calibrate_odometry_scale": False, "recovery_heading_step": 0.1},
             "loop_closure": {"wide_after": 0, "wide_radius": 40.0, "agreement_nodes": 4,
                              "max_given_up": 1}}
    config = from_dict(older)
    fe, lc = config.front_end, config.loop_closure
    assert fe.odometry_gate.share == (0.3, 0.4) and not fe.odometry_gate.enabled
    assert fe.heading_prior.enabled and fe.heading_prior.weight == 2.5
    assert not fe.previous_scan_check.enabled and not fe.odometry_scale.enabled
    assert fe.recovery.heading_step == 0.1
    assert not lc.wide_search.enabled and lc.wide_search.radius == 40.0
    assert lc.agreement.nodes == 4 and lc.agreement.max_given_up == 1
    assert override(SlamConfig(), {"front_end.odometry_gate": [0.1, 0.05]}
                    ).front_end.odometry_gate.tolerance == (0.1, 0.05)  # dotted, too


def test_a_fixed_field_at_its_value_reads_and_another_is_refused_by_name():
    """A field that became a constant: an older file naming it at that value reads as before;
    another value is refused, naming the field and the constant."""
    older = from_dict_tables(dict(FIXED_FIELDS))
    assert from_dict(older) == SlamConfig()
    with pytest.raises(ConfigError, match=r"loop_closure.wide_levels = 5: this field is now a "
                                          r"constant, 6"):
        override(SlamConfig(), {"loop_closure.wide_levels": 5})


def test_the_fixed_fields_values_are_the_constants_the_code_uses():
    from swarmslam.runtime.back_end import loop_alignment, loop_closure, loop_trial, slices
    from swarmslam.runtime.back_end import wide_loop_search as wide
    from swarmslam.runtime.back_end.graph_optimizer import GaussNewton
    from swarmslam.runtime.front_end import odometry_gate, odometry_readings, odometry_scale
    from swarmslam.runtime.front_end import recovery, tracker
    from swarmslam.runtime.front_end.between_scans import BetweenSmoothing
    from swarmslam.runtime.localization import localizer, map_tracking, relocalization
    from swarmslam.runtime.matching import scan_matcher
    from swarmslam.runtime.node_scans import BEARING_BINS
    from swarmslam.runtime.realtime import fixed_rate, inbox
    code = {
        "input.jump_slack": inbox.JUMP_SLACK, "input.turn_slack": inbox.TURN_SLACK,
        "front_end.track_inlier_slope": scan_matcher.INLIER_SLOPE,
        "front_end.weak_information_factor": tracker.WEAK_INFORMATION_FACTOR,
        "front_end.odometry_gate_distance": odometry_gate.OVERRULE_DISTANCE,
        "front_end.odometry_heading_sigma": odometry_gate.HEADING_SIGMA,
        "front_end.previous_scan_fit": odometry_gate.PREVIOUS_SCAN_FIT,
        "front_end.recovery_seek_ratio": recovery.SEEK_RATIO,
        "front_end.window_margin": scan_matcher.BOX_MARGIN,
        "front_end.curvature_step": scan_matcher.CURVATURE_STEP,
        "front_end.period_restart_gaps": odometry_readings.RESTART_GAPS,
        "front_end.odometry_scale_prior_travel": odometry_scale.PRIOR_TRAVEL,
        "front_end.odometry_scale_dead_zone": odometry_scale.DEAD_ZONE,
        "front_end.between_significance": BetweenSmoothing().significance,
        "front_end.between_gate": BetweenSmoothing().gate,
        "matcher.surface_gap_ratio": scan_matcher.SURFACE_GAP_RATIO,
        "matcher.coarse_radius": scan_matcher.COARSE_RADIUS,
        "matcher.polish_step": scan_matcher.POLISH_STEP,
        "matcher.polish_halvings": scan_matcher.POLISH_HALVINGS,
        "matcher.occupied_radius": scan_matcher.OCCUPIED_RADIUS,
        "loop_closure.agreement_distance": loop_closure.AGREEMENT_DISTANCE,
        "loop_closure.agreement_angle": loop_closure.AGREEMENT_ANGLE,
        "loop_closure.min_strain": loop_trial.MIN_STRAIN,
        "loop_closure.max_violations": loop_alignment.MAX_VIOLATIONS,
        "loop_closure.inlier_slope": scan_matcher.INLIER_SLOPE,
        "loop_closure.bearing_bins": BEARING_BINS,
        "loop_closure.position_floor": loop_closure.POSITION_FLOOR,
        "loop_closure.window_margin": scan_matcher.BOX_MARGIN,
        "loop_closure.wide_hit_sigma": wide.HIT_SIGMA,
        "loop_closure.wide_surface_tolerance": wide.SURFACE_TOLERANCE,
        "loop_closure.wide_levels": wide.LEVELS, "loop_closure.wide_query_range": wide.QUERY_RANGE,
        "loop_closure.wide_query_points": wide.QUERY_POINTS,
        "loop_closure.wide_ratio": wide.RIVAL_RATIO,
        "loop_closure.wide_distinct_distance": wide.DISTINCT_DISTANCE,
        "loop_closure.wide_agreement": wide.AGREEMENT,
        "loop_closure.wide_refine_window": wide.WIDE_REFINE_WINDOW,
        "optimizer.lm_initial_damping": GaussNewton.LM_INITIAL_DAMPING,
        "optimizer.lm_iteration_factor": GaussNewton.LM_ITERATION_FACTOR,
        "relocalization.coarse_hit_sigma": relocalization.COARSE_HIT_SIGMA,
        "relocalization.coarse_points": relocalization.COARSE_POINTS,
        "relocalization.coarse_min_score": relocalization.COARSE_MIN_SCORE,
        "relocalization.coarse_ratio": relocalization.COARSE_RATIO,
        "relocalization.coarse_candidates": relocalization.COARSE_CANDIDATES,
        "relocalization.coarse_distinct_distance": relocalization.COARSE_DISTINCT_DISTANCE,
        "relocalization.coarse_distinct_angle": relocalization.COARSE_DISTINCT_ANGLE,
        "relocalization.refine_moves": relocalization.REFINE_MOVES,
        "relocalization.heading_levels": relocalization.HEADING_LEVELS,
        "relocalization.query_spacing": relocalization.QUERY_SPACING,
        "relocalization.refine_nodes": relocalization.REFINE_NODES,
        "localization.heading_weight": map_tracking.HEADING_WEIGHT,
        "localization.reanchor_distance": map_tracking.REANCHOR_DISTANCE,
        "localization.merge_distance": localizer.MERGE_DISTANCE,
        "localization.merge_angle": localizer.MERGE_ANGLE,
        "localization.confirm_miss_floor": localizer.CONFIRM_MISS_FLOOR,
        "runtime.min_evaluation_share": fixed_rate.MIN_EVALUATION_SHARE,
        "runtime.front_end_cost_smoothing": fixed_rate.FRONT_END_COST_SMOOTHING,
        "runtime.slice_cost_decay": slices.SLICE_COST_DECAY,
        "runtime.slice_cost_memory": slices.SLICE_COST_MEMORY,
        "runtime.malloc_mmap_threshold": fixed_rate.MALLOC_MMAP_THRESHOLD,
        "runtime.warm_up_scans": fixed_rate.WARM_UP_SCANS}
    assert code == FIXED_FIELDS


def from_dict_tables(dotted: dict) -> dict:
    """Dotted names as the nested tables a TOML file holds (its lists for tuples)."""
    return nested_tables({key: list(value) if isinstance(value, tuple) else value
                          for key, value in dotted.items()})


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
