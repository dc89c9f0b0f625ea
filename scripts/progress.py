"""Progress for long runs on stderr: a live line on a terminal, a line every few seconds in
a log (CI), so neither is flooded. No dependency needed."""

from __future__ import annotations

import sys
import time


class Progress:
    def __init__(self, total: int, label: str = "", stream=None, every: float | None = None):
        self.total, self.label = max(int(total), 1), label
        self.stream = stream if stream is not None else sys.stderr
        self.live = bool(getattr(self.stream, "isatty", lambda: False)())
        self.every = every if every is not None else (0.5 if self.live else 10.0)
        self.start = self._last = time.perf_counter()
        self.done = 0

    def update(self, n: int = 1, note: str = "") -> None:
        self.done += n
        now = time.perf_counter()
        if now - self._last >= self.every or self.done >= self.total:
            self._last = now
            rate = self.done / max(now - self.start, 1e-9)
            eta = (self.total - self.done) / rate if rate > 0 else 0.0
            pct = 100.0 * self.done / self.total
            start, end = ("\r", "") if self.live else ("", "\n")
            self.stream.write(
                f"{start}{self.label} {self.done}/{self.total} ({pct:5.1f}%) "
                f"{rate:7.1f}/s eta {eta:5.0f}s {note}{end}"
            )
            self.stream.flush()

    def close(self) -> None:
        if self.live:
            self.stream.write("\n")
            self.stream.flush()
