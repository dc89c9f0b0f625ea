"""Sessions as an older build saved them, made from a current state: what the migrations in
:mod:`swarmslam.runtime.realtime.session` must bring back."""

from __future__ import annotations

import copy

from swarmslam.runtime.config import (FIXED_FIELDS, RENAMED_FIELDS, SWITCHED_FIELDS, flat_tables,
                                      nested_tables)


def older_config_names(config: dict) -> dict:
    """A configuration's tables (``to_dict``) in the flat names of version 7: moved fields
    back in their section, ``enabled`` back as a sentinel, fixed fields at their values."""
    flat = flat_tables(config)
    for old, new in RENAMED_FIELDS.items():
        flat[old] = flat.pop(new)
    for old, (section, name, sentinel) in SWITCHED_FIELDS.items():
        on, value = flat.pop(f"{section}.enabled"), flat.pop(f"{section}.{name}")
        flat[old] = value if on else sentinel
    flat.update((k, list(v) if isinstance(v, tuple) else v) for k, v in FIXED_FIELDS.items())
    return nested_tables(flat)


def as_version_8(state: dict) -> dict:
    """A runtime's state as version 8 laid it out: one loop remembered as refused for its own
    error, the newest of today's group."""
    old = copy.deepcopy(state)
    if "slam" in old:
        be = old["slam"]["back_end"]
        be["strained"], be["strained_info"] = be["strained"][0], be["strained_info"][0]
    return old


def as_version_7(state: dict) -> dict:
    """A runtime's state as version 7 laid it out: its configuration in the flat names."""
    old = as_version_8(state)
    if "config" in old:
        old["config"] = older_config_names(old["config"])
    return old


def as_version_6(state: dict) -> dict:
    """A runtime's state (``SlamRuntime.state()``) as version 6 laid it out: the tallies flat,
    the five front-end counts it did not keep gone, the configuration in the flat names."""
    old = as_version_7(state)
    fe, be = old["slam"]["front_end"], old["slam"]["back_end"]
    counts = fe.pop("counts")
    fe["lost_matches"], fe["degenerate_matches"] = (counts["lost_matches"],
                                                    counts["degenerate_matches"])
    loops = be.pop("loops")
    be["loops"] = [loops["attempts"], loops["accepted"], loops["rejected_match"],
                   loops["rejected_consistency"]]
    for key in ("agreed", "given_up", "reanchored"):
        be[key] = loops[key]
    be.update(be.pop("counts"))
    return old


# What a version-6 session saved before a rule lacks; the migration supplies each.
BEFORE_THEIR_RULES = {
    "front_end": ("scan_odometry", "scan_reading", "odometry_rel", "odometry_scale",
                  "odometry_part", "pinned_base", "last_stamp", "last_interval", "submap_nodes",
                  "submap_poses", "previous_points", "stale_scans", "reading_scans",
                  "reading_step", "readings_rate", "readings_stamp", "readings_arrival",
                  "readings_scan_time", "readings_scan_intervals", "readings_period_time",
                  "readings_period_scans", "readings_periods", "readings_fewest",
                  "readings_long_gaps", "readings_lag"),
    "back_end": ("failed", "failed_node", "failed_revision", "wide_from", "rise_refused",
                 "strained", "strained_info", "agreed", "given_up", "reanchored"),
    "graph": ("odometry_part", "scale"),
}


def as_early_version_6(state: dict) -> dict:
    """:func:`as_version_6`, saved before any rule whose state a later build added."""
    old = as_version_6(state)
    for part, keys in BEFORE_THEIR_RULES.items():
        for key in keys:
            del old["slam"][part][key]
    for key in ("bad_stamps", "odometry_non_finite", "odometry_jumps", "odometry_out_of_range",
                "cut"):
        del old["inbox"][key]
    return old
