"""Artificial bee colony (Alg. 2, Karaboga 2005; Eqs. 9–11), as ask/tell kernels.

One cycle is three asks: the employed bees' neighbours of every source, the onlookers'
neighbours of sources chosen by fitness, and (when a source is exhausted) one scout.
Members are the food sources; ``mem_val`` holds their trial counters.

Parameters (``params``): ``[limit]``. The colony has ``n`` bees and ``n/2`` food sources
(Table 1: colony 20, sources 10, limit 10); the workspace's member count is the source count.
"""

from __future__ import annotations

from numba import njit

from swarmslam.runtime.matching.optimizers.workspace import PHASE, clip, end_iteration, offer_best
from swarmslam.runtime.matching.rng import randint, uniform

LIMIT = 0
N_PARAMS = 1
DEFAULTS = (10.0,)

_INIT, _EMPLOYED, _ONLOOKER, _SCOUT = 0.0, 1.0, 2.0, 3.0


@njit(cache=True, inline="always")
def abc_start(ws):
    ws.scal[PHASE] = _INIT


# Helpers take the arrays they use, not the workspace: passing the 15-array workspace down
# a call chain costs more in reference counting than the helper's work. The phases that do
# take it are inlined into the caller's loop for the same reason (with ``ask``/``tell``: an
# alignment's ~3,700 evaluations spent 0.8 ms outside the objective, 0.4 ms inlined).
@njit(cache=True, inline="always")
def _random_source(cand, row, lo, hi, rng):
    """Eq. 9: ``x_j = l_j + r·(u_j − l_j)``."""
    for d in range(cand.shape[1]):
        cand[row, d] = lo[d] + uniform(rng) * (hi[d] - lo[d])


@njit(cache=True, inline="always")
def _neighbour(pos, cand, row, i, lo, hi, rng):
    """Eq. 11: move one random dimension of source ``i`` relative to another source ``k``."""
    n, dim = pos.shape
    k = randint(rng, n - 1)
    if k >= i:
        k += 1
    j = randint(rng, dim)
    phi = 2.0 * uniform(rng) - 1.0
    for d in range(dim):
        cand[row, d] = pos[i, d]
    cand[row, j] = clip(pos[i, j] + phi * (pos[i, j] - pos[k, j]), lo[j], hi[j])


@njit(cache=True, inline="always")
def _ask_init(ws):
    n = ws.pos.shape[0]
    for i in range(n):
        _random_source(ws.cand, i, ws.lo, ws.hi, ws.rng)
        ws.cand_idx[i] = i
    return n


@njit(cache=True, inline="always")
def _ask_employed(ws):
    n = ws.pos.shape[0]
    pos, cand, lo, hi, rng = ws.pos, ws.cand, ws.lo, ws.hi, ws.rng
    for i in range(n):
        _neighbour(pos, cand, i, i, lo, hi, rng)
        ws.cand_idx[i] = i
    return n


@njit(cache=True, inline="always")
def _ask_onlooker(ws):
    # Eq. 10 with fitness 1/(1+f) for f >= 0 (1+|f| below zero), as in Karaboga's code.
    n = ws.pos.shape[0]
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
        _neighbour(ws.pos, ws.cand, row, i, ws.lo, ws.hi, ws.rng)
        ws.cand_idx[row] = i
    return n


@njit(cache=True, inline="always")
def _ask_scout(ws):
    # The most-tried source beyond the limit is abandoned and re-initialised.
    worst = -1
    trials = ws.mem_val
    most = ws.params[LIMIT]
    for i in range(trials.shape[0]):
        if trials[i] > most:
            most = trials[i]
            worst = i
    if worst < 0:
        return 0
    _random_source(ws.cand, 0, ws.lo, ws.hi, ws.rng)
    ws.cand_idx[0] = worst
    return 1


@njit(cache=True, inline="always")
def abc_ask(ws):
    phase = ws.scal[PHASE]
    if phase == _INIT:
        return _ask_init(ws)
    if phase == _EMPLOYED:
        return _ask_employed(ws)
    if phase == _ONLOOKER:
        return _ask_onlooker(ws)
    return _ask_scout(ws)


@njit(cache=True, inline="always")
def _greedy(pos, val, trials, cand, cand_val, cand_idx, row, scal, best):
    """Keep candidate ``row`` if it beats its source, else count a failed trial."""
    i = cand_idx[row]
    v = cand_val[row]
    if v < val[i]:
        val[i] = v
        trials[i] = 0.0
        for d in range(pos.shape[1]):
            pos[i, d] = cand[row, d]
        offer_best(scal, best, pos, i, v)
    else:
        trials[i] += 1.0


@njit(cache=True, inline="always")
def abc_tell(ws, m):
    phase = ws.scal[PHASE]
    if phase == _INIT or phase == _SCOUT:
        for row in range(m):
            i = ws.cand_idx[row]
            ws.val[i] = ws.cand_val[row]
            ws.mem_val[i] = 0.0
            for d in range(ws.pos.shape[1]):
                ws.pos[i, d] = ws.cand[row, d]
            offer_best(ws.scal, ws.best, ws.pos, i, ws.val[i])
        if phase == _SCOUT:
            end_iteration(ws, ws.val)
        ws.scal[PHASE] = _EMPLOYED
        return
    for row in range(m):
        _greedy(ws.pos, ws.val, ws.mem_val, ws.cand, ws.cand_val, ws.cand_idx, row, ws.scal, ws.best)
    ws.scal[PHASE] = _ONLOOKER if phase == _EMPLOYED else _SCOUT
