"""Firefly algorithm (Alg. 3, Fister et al. 2013; Eqs. 12–13), as ask/tell kernels.

Parameters (``params``): ``[alpha0, beta0, gamma, alpha_decay]``. Both scale-dependent terms
are taken in box-normalised coordinates, so Table 1's values mean the same on any box: the
distance ``r_ij`` of Eq. 13 (with raw metres and radians, ``exp(−γ·r²)`` vanishes over a 4 m
box and the fireflies never gather) and the random step ``α·ε`` (a fraction of the box width).
``α`` decays geometrically each iteration (the paper's ``newAlpha()``; 0.97 is usual).
"""

from __future__ import annotations

import math

from numba import njit

from swarmslam.runtime.matching.optimizers.workspace import (
    ALPHA,
    PHASE,
    ask_every_member,
    clip,
    end_iteration,
    offer_best,
)
from swarmslam.runtime.matching.rng import normal, uniform

ALPHA0, BETA0, GAMMA, ALPHA_DECAY = 0, 1, 2, 3
N_PARAMS = 4
DEFAULTS = (0.75, 0.2, 1.0, 0.97)  # Table 1: n = 20, alpha = 0.75, beta0 = 0.2, gamma = 1


@njit(cache=True)
def fa_start(ws):
    n, dim = ws.pos.shape
    for i in range(n):
        for d in range(dim):
            ws.pos[i, d] = ws.lo[d] + uniform(ws.rng) * (ws.hi[d] - ws.lo[d])
    ws.scal[ALPHA] = ws.params[ALPHA0]
    ws.scal[PHASE] = 0.0


@njit(cache=True)
def _move(ws):
    """Eq. 12: every firefly moves toward every brighter one (lower f is brighter), with a
    random step ``α·ε`` on each move; the brightest only walks at random."""
    n, dim = ws.pos.shape
    alpha = ws.scal[ALPHA]
    beta0, gamma = ws.params[BETA0], ws.params[GAMMA]
    pos, val, lo, hi, rng = ws.pos, ws.val, ws.lo, ws.hi, ws.rng
    for i in range(n):
        moved = False
        for j in range(n):
            if val[j] < val[i]:
                r2 = 0.0  # Eq. 13, squared, in box-normalised coordinates
                for d in range(dim):
                    diff = (pos[j, d] - pos[i, d]) / (hi[d] - lo[d])
                    r2 += diff * diff
                beta = beta0 * math.exp(-gamma * r2)
                for d in range(dim):
                    step = alpha * normal(rng) * (hi[d] - lo[d])
                    pos[i, d] = clip(pos[i, d] + beta * (pos[j, d] - pos[i, d]) + step, lo[d], hi[d])
                moved = True
        if not moved:
            for d in range(dim):
                x = pos[i, d] + alpha * normal(rng) * (hi[d] - lo[d])
                pos[i, d] = clip(x, lo[d], hi[d])
    ws.scal[ALPHA] = alpha * ws.params[ALPHA_DECAY]


@njit(cache=True)
def fa_ask(ws):
    if ws.scal[PHASE] != 0.0:
        _move(ws)
    return ask_every_member(ws)


@njit(cache=True)
def fa_tell(ws, m):
    for i in range(m):
        ws.val[i] = ws.cand_val[i]
        offer_best(ws.scal, ws.best, ws.pos, i, ws.val[i])
    if ws.scal[PHASE] != 0.0:
        end_iteration(ws, ws.val)
    ws.scal[PHASE] = 1.0
