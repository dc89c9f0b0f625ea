"""The "Fields" part of docs/configuration.md, made from the configuration tree itself
(``swarmslam config fields``), so the page cannot drift from the code."""

from __future__ import annotations

from dataclasses import fields, is_dataclass

from swarmslam.runtime.config import BASIC, EXPERT, SlamConfig, _toml_value


def _allowed(meta) -> str:
    parts = [f"{sym} {meta[key]:g}" for key, sym in (("gt", ">"), ("ge", "≥"), ("lt", "<"),
                                                      ("le", "≤")) if meta.get(key) is not None]
    if meta.get("choices"):
        parts.append("one of " + ", ".join(meta["choices"]))
    return ", ".join(parts)


def fields_markdown(config=None) -> str:
    """Per section, a table of its fields: name, default, meaning, allowed values, and its
    level: **basic** (set by users), standard, or expert (``config show --all`` only)."""
    config = config or SlamConfig()
    out = ["## Fields"]

    def emit(section, table):
        plain = [f for f in fields(section) if not is_dataclass(getattr(section, f.name))]
        if table and plain:
            out.extend(["", f"### `[{table}]`", "", "| field | default | meaning | allowed | level |",
                        "|---|---|---|---|---|"])
            for f in plain:
                own = f.metadata["level"]
                level = ("**basic**" if own == BASIC else "expert" if own == EXPERT
                         else "standard")
                out.append(f"| `{f.name}` | `{_toml_value(getattr(section, f.name))}` | "
                           f"{f.metadata.get('doc', '')} | {_allowed(f.metadata)} | {level} |")
        for f in fields(section):
            if is_dataclass(getattr(section, f.name)):
                emit(getattr(section, f.name), f"{table}.{f.name}" if table else f.name)

    emit(config, "")
    return "\n".join(out) + "\n"
