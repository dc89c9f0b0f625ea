"""The preallocated state every swarm optimizer works in, and the paper's halting rules.

All three optimizers (PSO, ABC, FA) are written as *ask/tell* kernels over one layout of
arrays, so the same compiled loop can drive any of them with any compiled objective, and a
Python objective can drive them too. Nothing here is allocated after construction.

Cost note: a compiled call that receives the workspace can cost ~250 ns of reference counting
on its arrays, more than an evaluation; so the optimizers ask and tell in batches (a whole
iteration, or an ABC phase) and their helpers take only the arrays they use.

Halting (docs/method.md §2, Section 5.1 of the paper): at most ``max_iterations`` iterations; stop when
the spread between the best and the worst member changed by no more than ``stagnation_tol`` for
``stagnation_iterations`` iterations in a row; stop at once when ``f < target_value``. Beyond the
paper, an optional ``max_evaluations`` budget ends the run at the end of the iteration that
reaches it: evaluations, not iterations, are what a tick's time is spent on, and they compare
across optimizers whose iterations cost 20 or 50 evaluations. And, optionally, a run ends after
``stall_iterations`` iterations in a row in which the best found improved by no more than
``stall_tol``: a swarm that has settled in its basin spends the rest of a budget on gains the
local stages make anyway (the spread rule rarely fires: a swarm's members keep moving).
"""

from __future__ import annotations

from collections import namedtuple

import numpy as np
from numba import njit

# Indices into ``scal`` (float64 scalars of the run).
BEST_VAL = 0
ITERATION = 1
STAGNANT = 2
LAST_SPREAD = 3
PHASE = 4
EVALUATIONS = 5
DONE = 6
ALPHA = 7  # firefly randomisation, decays per iteration
MAX_ITERATIONS = 8
STAGNATION_ITERATIONS = 9
STAGNATION_TOL = 10
TARGET_VALUE = 11
MAX_EVALUATIONS = 12  # beyond the paper: a budget that bounds a fixed-rate tick
STALL_ITERATIONS = 13  # beyond the paper: iterations without a gain in the best (0: off)
STALL_TOL = 14  # what counts as a gain in the best
BEST_AT_GAIN = 15  # the best when it last gained
STALLED = 16  # iterations since
N_SCAL = 17

SwarmWorkspace = namedtuple(
    "SwarmWorkspace",
    [
        "pos",  # (n, D) members: particles, food sources or fireflies
        "val",  # (n,) objective at pos
        "aux",  # (n, D) PSO velocities
        "mem",  # (n, D) PSO personal bests
        "mem_val",  # (n,) PSO personal-best values; ABC trial counters
        "cand",  # (n, D) candidates asked for evaluation
        "cand_val",  # (n,) their objective values, filled by the caller
        "cand_idx",  # (n,) int64: member each candidate belongs to
        "fit",  # (n,) scratch: ABC selection probabilities
        "best",  # (D,) best position found so far
        "lo",  # (D,) lower bounds of the search box
        "hi",  # (D,) upper bounds
        "params",  # algorithm parameters (see each optimizer)
        "scal",  # run scalars, indices above
        "rng",  # uint64[4] xoshiro256** state
    ],
)


def make_workspace(n_members: int, dim: int, n_params: int) -> SwarmWorkspace:
    """Allocate a workspace for ``n_members`` members in ``dim`` dimensions."""
    if n_members < 2:
        raise ValueError(f"a swarm needs at least 2 members, got {n_members}")
    if dim < 1:
        raise ValueError(f"dimension must be >= 1, got {dim}")
    f = np.float64
    return SwarmWorkspace(
        pos=np.zeros((n_members, dim), f),
        val=np.full(n_members, np.inf),
        aux=np.zeros((n_members, dim), f),
        mem=np.zeros((n_members, dim), f),
        mem_val=np.full(n_members, np.inf),
        cand=np.zeros((n_members, dim), f),
        cand_val=np.full(n_members, np.inf),
        cand_idx=np.zeros(n_members, np.int64),
        fit=np.zeros(n_members, f),
        best=np.zeros(dim, f),
        lo=np.zeros(dim, f),
        hi=np.ones(dim, f),
        params=np.zeros(max(n_params, 1), f),
        scal=np.zeros(N_SCAL, f),
        rng=np.zeros(4, np.uint64),
    )


@njit(cache=True)
def reset_run(
    ws, max_iterations, stagnation_iterations, stagnation_tol, target_value, max_evaluations,
    stall_iterations, stall_tol
):
    """Clear the run scalars before a new minimisation (``max_evaluations`` <= 0: no budget;
    ``stall_iterations`` 0: no stall rule)."""
    s = ws.scal
    s[:] = 0.0
    s[BEST_VAL] = np.inf
    s[LAST_SPREAD] = np.inf
    s[MAX_ITERATIONS] = max_iterations
    s[STAGNATION_ITERATIONS] = stagnation_iterations
    s[STAGNATION_TOL] = stagnation_tol
    s[TARGET_VALUE] = target_value
    s[MAX_EVALUATIONS] = max_evaluations if max_evaluations > 0 else np.inf
    s[STALL_ITERATIONS] = stall_iterations if stall_iterations > 0 else np.inf
    s[STALL_TOL] = stall_tol
    s[BEST_AT_GAIN] = np.inf


@njit(cache=True, inline="always")
def offer_best(scal, best, members, i, value):
    """Keep member ``i`` as the best-so-far if it improves on it; halt on the target value.

    It runs per evaluation, so it takes arrays and a row index: passing the workspace or a
    row view costs reference counting worth more than the work.
    """
    if value < scal[BEST_VAL]:
        scal[BEST_VAL] = value
        for d in range(best.shape[0]):
            best[d] = members[i, d]
        if value < scal[TARGET_VALUE]:
            scal[DONE] = 1.0


@njit(cache=True)
def end_iteration(ws, values):
    """Count one iteration and apply the stagnation, stall and iteration-limit rules.

    ``values`` are the swarm members' current values; their spread (worst − best) is what
    must stop changing for the swarm to be called stagnant. The stall rule watches the best
    found instead.
    """
    s = ws.scal
    lo = np.inf
    hi = -np.inf
    for v in values:
        if v < lo:
            lo = v
        if v > hi:
            hi = v
    spread = hi - lo
    if abs(spread - s[LAST_SPREAD]) <= s[STAGNATION_TOL]:
        s[STAGNANT] += 1.0
    else:
        s[STAGNANT] = 0.0
    s[LAST_SPREAD] = spread
    if s[BEST_VAL] < s[BEST_AT_GAIN] - s[STALL_TOL]:
        s[BEST_AT_GAIN] = s[BEST_VAL]
        s[STALLED] = 0.0
    else:
        s[STALLED] += 1.0
    s[ITERATION] += 1.0
    if (
        s[ITERATION] >= s[MAX_ITERATIONS]
        or s[STAGNANT] >= s[STAGNATION_ITERATIONS]
        or s[EVALUATIONS] >= s[MAX_EVALUATIONS]
        or s[STALLED] >= s[STALL_ITERATIONS]
    ):
        s[DONE] = 1.0


@njit(cache=True, inline="always")
def clip(v, lo, hi):
    return lo if v < lo else (hi if v > hi else v)


@njit(cache=True)
def ask_every_member(ws):
    """Candidates = the members' current positions (PSO and FA evaluate all each iteration)."""
    n, dim = ws.pos.shape
    for i in range(n):
        ws.cand_idx[i] = i
        for d in range(dim):
            ws.cand[i, d] = ws.pos[i, d]
    return n
