"""Particle swarm optimisation, global best (Alg. 1, Eqs. 7–8), as ask/tell kernels.

Parameters (``params``): ``[w, c1, c2, v_max]`` with ``v_max`` the velocity limit as a fraction
of the box width per dimension (a standard safeguard the paper does not state; 0.5 here).
"""

from __future__ import annotations

from numba import njit

from swarmslam.runtime.matching.optimizers.workspace import (
    PHASE,
    ask_every_member,
    clip,
    end_iteration,
    offer_best,
)
from swarmslam.runtime.matching.rng import uniform

W, C1, C2, V_MAX = 0, 1, 2, 3
N_PARAMS = 4
DEFAULTS = (0.7, 1.49, 1.49, 0.5)  # Table 1: n = 50, w = 0.7, c1 = c2 = 1.49


@njit(cache=True)
def pso_start(ws):
    """Particles uniform in the box, small random velocities, no memory yet."""
    n, dim = ws.pos.shape
    for i in range(n):
        for d in range(dim):
            width = ws.hi[d] - ws.lo[d]
            ws.pos[i, d] = ws.lo[d] + uniform(ws.rng) * width
            ws.aux[i, d] = (2.0 * uniform(ws.rng) - 1.0) * 0.1 * width
        ws.mem_val[i] = 1e300


@njit(cache=True)
def pso_ask(ws):
    """Every particle's position is evaluated each iteration."""
    return ask_every_member(ws)


@njit(cache=True)
def pso_tell(ws, m):
    n, dim = ws.pos.shape
    for i in range(n):
        v = ws.cand_val[i]
        ws.val[i] = v
        if v < ws.mem_val[i]:
            ws.mem_val[i] = v
            for d in range(dim):
                ws.mem[i, d] = ws.pos[i, d]
        offer_best(ws.scal, ws.best, ws.pos, i, v)
    end_iteration(ws, ws.mem_val)
    w, c1, c2 = ws.params[W], ws.params[C1], ws.params[C2]
    for i in range(n):
        for d in range(dim):
            width = ws.hi[d] - ws.lo[d]
            vmax = ws.params[V_MAX] * width
            # Eq. 7, with r1 and r2 drawn per dimension.
            v = (
                w * ws.aux[i, d]
                + c1 * uniform(ws.rng) * (ws.mem[i, d] - ws.pos[i, d])
                + c2 * uniform(ws.rng) * (ws.best[d] - ws.pos[i, d])
            )
            v = clip(v, -vmax, vmax)
            # Eq. 8; a particle that hits the wall stops there in that dimension.
            x = ws.pos[i, d] + v
            if x < ws.lo[d] or x > ws.hi[d]:
                x = clip(x, ws.lo[d], ws.hi[d])
                v = 0.0
            ws.pos[i, d] = x
            ws.aux[i, d] = v
    ws.scal[PHASE] = 1.0
