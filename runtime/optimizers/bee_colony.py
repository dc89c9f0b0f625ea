"""Artificial bee colony (Alg. 2, Karaboga 2005; Eqs. 9–11), as ask/tell kernels.

One cycle is three asks: the employed bees' neighbours of every source, the onlookers'
neighbours of sources chosen by fitness, and (when a source is exhausted) one scout.
Members are the food sources; ``mem_val`` holds their trial counters.

Parameters (``params``): ``[limit]``. The colony has ``n`` bees and ``n/2`` food sources
(Table 1: colony 20, sources 10, limit 10); the workspace's member count is the source count.
"""

from __future__ import annotations

from numba import njit

from runtime.optimizers.workspace import PHASE, clip, end_iteration, offer_best
from runtime.rng import randint, uniform

LIMIT = 0
N_PARAMS = 1
DEFAULTS = (10.0,)

_INIT, _EMPLOYED, _ONLOOKER, _SCOUT = 0.0, 1.0, 2.0, 3.0


@njit(cache=True)
def abc_start(ws):
    ws.scal[PHASE] = _INIT


@njit(cache=True)
def _random_source(ws, row):
    """Eq. 9: ``x_j = l_j + r·(u_j − l_j)``."""
    for d in range(ws.pos.shape[1]):
        ws.cand[row, d] = ws.lo[d] + uniform(ws.rng) * (ws.hi[d] - ws.lo[d])


@njit(cache=True)
def _neighbour(ws, row, i):
    """Eq. 11: move one random dimension of source ``i`` relative to another source ``k``."""
    n, dim = ws.pos.shape
    k = randint(ws.rng, n - 1)
    if k >= i:
        k += 1
    j = randint(ws.rng, dim)
    phi = 2.0 * uniform(ws.rng) - 1.0
    for d in range(dim):
        ws.cand[row, d] = ws.pos[i, d]
    ws.cand[row, j] = clip(ws.pos[i, j] + phi * (ws.pos[i, j] - ws.pos[k, j]), ws.lo[j], ws.hi[j])
    ws.cand_idx[row] = i


@njit(cache=True)
def abc_ask(ws):
    n = ws.pos.shape[0]
    phase = ws.scal[PHASE]
    if phase == _INIT:
        for i in range(n):
            _random_source(ws, i)
            ws.cand_idx[i] = i
        return n
    if phase == _EMPLOYED:
        for i in range(n):
            _neighbour(ws, i, i)
        return n
    if phase == _ONLOOKER:
        # Eq. 10 with fitness 1/(1+f) for f >= 0 (1+|f| below zero), as in Karaboga's code.
        total = 0.0
        for i in range(n):
            f = ws.val[i]
            ws.fit[i] = 1.0 / (1.0 + f) if f >= 0.0 else 1.0 + abs(f)
            total += ws.fit[i]
        for row in range(n):
            r = uniform(ws.rng) * total
            i = 0
            acc = ws.fit[0]
            while acc < r and i < n - 1:
                i += 1
                acc += ws.fit[i]
            _neighbour(ws, row, i)
        return n
    # Scout: the most-tried source beyond the limit is abandoned and re-initialised.
    worst = -1
    most = ws.params[LIMIT]
    for i in range(n):
        if ws.mem_val[i] > most:
            most = ws.mem_val[i]
            worst = i
    if worst < 0:
        return 0
    _random_source(ws, 0)
    ws.cand_idx[0] = worst
    return 1


@njit(cache=True)
def _greedy(ws, row):
    i = ws.cand_idx[row]
    v = ws.cand_val[row]
    if v < ws.val[i]:
        ws.val[i] = v
        ws.mem_val[i] = 0.0
        for d in range(ws.pos.shape[1]):
            ws.pos[i, d] = ws.cand[row, d]
        offer_best(ws, ws.pos[i], v)
    else:
        ws.mem_val[i] += 1.0


@njit(cache=True)
def abc_tell(ws, m):
    phase = ws.scal[PHASE]
    if phase == _INIT or phase == _SCOUT:
        for row in range(m):
            i = ws.cand_idx[row]
            ws.val[i] = ws.cand_val[row]
            ws.mem_val[i] = 0.0
            for d in range(ws.pos.shape[1]):
                ws.pos[i, d] = ws.cand[row, d]
            offer_best(ws, ws.pos[i], ws.val[i])
        if phase == _SCOUT:
            end_iteration(ws, ws.val)
        ws.scal[PHASE] = _EMPLOYED
        return
    for row in range(m):
        _greedy(ws, row)
    ws.scal[PHASE] = _ONLOOKER if phase == _EMPLOYED else _SCOUT
