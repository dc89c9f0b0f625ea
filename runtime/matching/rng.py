"""A small random generator for compiled code: xoshiro256** on a ``uint64[4]`` state array.

numba's ``np.random`` keeps one hidden global state per thread; two matchers would then share a
stream and a run would depend on call order. Each optimizer instead owns its state array, seeded
explicitly (SplitMix64, as the xoshiro authors recommend), so the same seed gives the same run,
bit for bit, and nothing is allocated to draw a number.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, uint64

_MASK = 0xFFFFFFFFFFFFFFFF


def seed_state(seed: int, state: np.ndarray | None = None) -> np.ndarray:
    """Fill (or make) a ``uint64[4]`` state from an integer seed with SplitMix64."""
    if state is None:
        state = np.empty(4, dtype=np.uint64)
    if state.shape != (4,) or state.dtype != np.uint64:
        raise ValueError("rng state must be a uint64 array of shape (4,)")
    z = int(seed) & _MASK
    for i in range(4):
        z = (z + 0x9E3779B97F4A7C15) & _MASK
        r = z
        r = ((r ^ (r >> 30)) * 0xBF58476D1CE4E5B9) & _MASK
        r = ((r ^ (r >> 27)) * 0x94D049BB133111EB) & _MASK
        state[i] = r ^ (r >> 31)
    return state


@njit(cache=True, inline="always")
def _rotl(x, k):
    return (x << uint64(k)) | (x >> uint64(64 - k))


@njit(cache=True)
def next_u64(s):
    """xoshiro256**: next 64-bit output; advances ``s`` in place."""
    result = _rotl(s[1] * uint64(5), 7) * uint64(9)
    t = s[1] << uint64(17)
    s[2] ^= s[0]
    s[3] ^= s[1]
    s[1] ^= s[2]
    s[0] ^= s[3]
    s[2] ^= t
    s[3] = _rotl(s[3], 45)
    return result


@njit(cache=True)
def uniform(s):
    """Uniform double in ``[0, 1)`` from the top 53 bits."""
    return float(next_u64(s) >> uint64(11)) * (1.0 / 9007199254740992.0)


@njit(cache=True)
def randint(s, n):
    """Uniform integer in ``[0, n)``."""
    return min(int(uniform(s) * n), n - 1)


@njit(cache=True)
def normal(s):
    """Standard normal by Box–Muller (one of the pair; simplicity over speed)."""
    u1 = uniform(s)
    while u1 <= 1e-300:
        u1 = uniform(s)
    u2 = uniform(s)
    return math.sqrt(-2.0 * math.log(u1)) * math.cos(2.0 * math.pi * u2)
