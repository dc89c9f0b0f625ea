"""The dynamic rejection threshold, the paper's "mean strategy" (docs/method.md §3, step 3).

After every alignment the running mean ``μλ`` and standard deviation ``σλ`` of the matching
error λ are updated incrementally (Welford), and the threshold becomes ``ε = μλ + σλ``. Until
two values have been seen the threshold is infinite: nothing is rejected on no evidence.
``σλ`` is also the matcher's noise level behind the graph's information matrices (Eq. 20).
"""

from __future__ import annotations

import math


class RejectionThreshold:
    def __init__(self):
        self.count = 0
        self.mean = 0.0
        self._m2 = 0.0

    def update(self, error: float) -> None:
        self.count += 1
        delta = error - self.mean
        self.mean += delta / self.count
        self._m2 += delta * (error - self.mean)

    @property
    def std(self) -> float:
        return math.sqrt(self._m2 / (self.count - 1)) if self.count > 1 else 0.0

    @property
    def rejection_threshold(self) -> float:
        return self.mean + self.std if self.count > 1 else math.inf

    def state(self) -> tuple[int, float, float]:
        return self.count, self.mean, self._m2

    def restore(self, state) -> None:
        self.count, self.mean, self._m2 = int(state[0]), float(state[1]), float(state[2])
