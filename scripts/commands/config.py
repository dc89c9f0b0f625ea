"""``swarmslam config``: the SLAM's configuration: ``config show`` and ``config fields``."""

from __future__ import annotations

import sys

from swarmslam.runtime.config import (DEFAULT_PRESET, PRESETS, field_names, load_config, preset,
                                      shown, to_toml)

# (what the command does, reads and writes; an example), shown by its --help
HELP = {
    "config": ("The SLAM's configuration: one tree of validated fields, in presets per "
               "scanner. See docs/configuration.md.", "swarmslam config show --basic"),
    "config show": ("Print the effective configuration as TOML, each field with its meaning "
                    "(--basic: the fields a user sets; --all: with each stage's internals). "
                    "The output is a valid --config file.",
                    "swarmslam config show rplidar-a2 > mine.toml"),
    "config fields": ("Print every field as the Markdown tables of docs/configuration.md.",
                      "swarmslam config fields > fields.md"),
}


def add(sub) -> None:
    """The command's parser, under ``sub`` (the CLI's subparsers)."""
    cf = sub.add_parser("config", help="the SLAM's configuration")
    csub = cf.add_subparsers(dest="action", required=True)
    show = csub.add_parser("show", help="print the effective configuration as TOML "
                                        "(--basic, --all)")
    show.add_argument("preset", nargs="?", choices=list(PRESETS),
                      help=f"a preset (default: {DEFAULT_PRESET})")
    show.add_argument("--config", metavar="FILE", help="with this TOML file's changes")
    show.add_argument("--bare", action="store_true", help="without the comments")
    levels = show.add_mutually_exclusive_group()
    levels.add_argument("--basic", action="store_true",
                        help="only the fields a user is expected to set")
    levels.add_argument("--all", action="store_true",
                        help="every field, the stages' internals too")
    show.set_defaults(func=_config_show)
    csub.add_parser("fields", help="every field as the Markdown tables of "
                                   "docs/configuration.md").set_defaults(func=_config_fields)


def _config_show(args) -> int:
    config = preset(args.preset or DEFAULT_PRESET)
    if args.config:
        config = load_config(args.config, config)
    level = "basic" if args.basic else "all" if args.all else "standard"
    text = to_toml(config, comments=not args.bare, level=level)
    if level != "all" and not args.bare:
        hidden = sum(not shown(key, level) for key in field_names(config))
        which = "all but the basic ones" if args.basic else "the stages' internals"
        text += f"\n# {hidden} more fields ({which}): swarmslam config show --all\n"
    sys.stdout.write(text)
    return 0


def _config_fields(args) -> int:
    from swarmslam.config_doc import fields_markdown

    sys.stdout.write(fields_markdown())
    return 0


