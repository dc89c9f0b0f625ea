"""What the text-format readers (CARMEN, g2o, relations) share: line iteration that skips
blanks and comments, numeric fields parsed by name, and an error naming file, line, field."""

from __future__ import annotations

import math


class DataFormatError(ValueError):
    """A line of a data file that cannot be read; says where and what."""

    def __init__(self, path, line: int, field: str, problem: str):
        self.path, self.line, self.field = str(path), line, field
        super().__init__(f"{path}:{line}: {field}: {problem}")


def records(path, opener=open):
    """``(line number, tokens)`` of every non-blank, non-comment line."""
    with opener(path) as f:
        for lineno, line in enumerate(f, start=1):
            tokens = line.split()
            if tokens and not tokens[0].startswith("#"):
                yield lineno, tokens


def parse_numbers(path, lineno, names, tokens, error=DataFormatError) -> list[float]:
    """Exactly ``len(names)`` finite numbers, the failing one named in the error."""
    if len(tokens) != len(names):
        raise error(path, lineno, names[min(len(tokens), len(names) - 1)],
                    f"expected {len(names)} values, got {len(tokens)}")
    out = []
    for name, tok in zip(names, tokens):
        try:
            v = float(tok)
        except ValueError:
            raise error(path, lineno, name, f"not a number: {tok!r}") from None
        if not math.isfinite(v):
            raise error(path, lineno, name, f"not finite: {tok!r}")
        out.append(v)
    return out
