"""What the text-format readers (CARMEN, g2o, relations) share: line iteration that skips
blanks and comments, numeric fields parsed by name, and an error naming file, line, field."""

from __future__ import annotations

import math
import zlib


class DataFormatError(ValueError):
    """A line of a data file that cannot be read; says where and what."""

    def __init__(self, path, line: int, field: str, problem: str):
        self.path, self.line, self.field = str(path), line, field
        super().__init__(f"{path}:{line}: {field}: {problem}")


# A text line longer than this is no record of ours (a 1,440-beam scan's is about 10 kB).
MAX_LINE_BYTES = 2**20

# What reading a damaged file raises: a truncated gzip stream (EOFError), a corrupted one
# (zlib.error, gzip.BadGzipFile is an OSError), a device or permission failure (OSError).
READ_ERRORS = (OSError, EOFError, zlib.error)


def records(path, opener=open, encoding: str = "utf-8", errors: str = "strict"):
    """``(line number, tokens)`` of every non-blank, non-comment line. ``opener(path, "rb")``
    opens the file as bytes; each line is decoded alone, so a binary file or a damaged
    stream is reported with its file and line (:class:`DataFormatError`), never as a bare
    decoding or zlib error."""
    lineno = 0
    with opener(path, "rb") as f:  # a missing file raises as it is: it names the path
        try:
            while True:
                # (bounded: a line of junk is never read whole into memory)
                raw = f.readline(MAX_LINE_BYTES + 1)
                if not raw:
                    break
                lineno += 1
                if len(raw) > MAX_LINE_BYTES:
                    raise DataFormatError(path, lineno, "text", f"a line longer than "
                                          f"{MAX_LINE_BYTES // 2**20} MiB (not a data file?)")
                if b"\0" in raw:
                    raise DataFormatError(path, lineno, "text", "a NUL byte: not plain text "
                                          "(UTF-16, or a binary file?)")
                try:
                    line = raw.decode(encoding, errors)
                except UnicodeDecodeError as exc:
                    raise DataFormatError(path, lineno, "text", f"not {encoding} text (a binary "
                                          f"file?): byte {exc.start + 1} is "
                                          f"{raw[exc.start]:#04x}") from None
                tokens = line.split()
                if tokens and not tokens[0].startswith("#"):
                    yield lineno, tokens
        except READ_ERRORS as exc:
            detail = (exc.strerror if isinstance(exc, OSError) and exc.strerror else
                      str(exc) or type(exc).__name__)
            raise DataFormatError(path, lineno + 1, "file",
                                  f"unreadable after line {lineno}: {detail}") from None


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
