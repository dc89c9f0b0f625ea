"""The three swarm optimizers behind one interface (docs/method.md §2).

``SwarmOptimizer(config).minimize(objective, lo, hi, seed)`` → ``OptimizeResult`` with the best
position, its value and the iterations used. Compiled callers (the scan matcher) drive the
same state with :func:`start`, :func:`ask` and :func:`tell` inside numba and never leave it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from swarmslam.runtime.config import OPTIMIZERS, SwarmConfig
from swarmslam.runtime.matching.optimizers import bee_colony, firefly, pso
from swarmslam.runtime.matching.optimizers.workspace import (
    BEST_VAL,
    DONE,
    EVALUATIONS,
    ITERATION,
    SwarmWorkspace,
    make_workspace,
    reset_run,
)
from swarmslam.runtime.matching.rng import seed_state

PSO, ABC, FA = (OPTIMIZERS.index(name) for name in ("pso", "abc", "fa"))

# Table 1: swarm / colony / fireflies.
DEFAULT_MEMBERS = {PSO: 50, ABC: 20, FA: 20}
_MODULES = {PSO: pso, ABC: bee_colony, FA: firefly}


@njit(cache=True, inline="always")
def start(kind, ws):
    """Scatter the swarm over the box ``ws.lo``–``ws.hi``; call after :func:`reset_run`."""
    if kind == PSO:
        pso.pso_start(ws)
    elif kind == ABC:
        bee_colony.abc_start(ws)
    else:
        firefly.fa_start(ws)


@njit(cache=True, inline="always")
def ask(kind, ws):
    """Write the next candidates into ``ws.cand``; return how many."""
    if kind == PSO:
        return pso.pso_ask(ws)
    if kind == ABC:
        return bee_colony.abc_ask(ws)
    return firefly.fa_ask(ws)


@njit(cache=True, inline="always")
def tell(kind, ws, m):
    """Take the values of the ``m`` candidates from ``ws.cand_val``; True when halted."""
    ws.scal[EVALUATIONS] += m
    if kind == PSO:
        pso.pso_tell(ws, m)
    elif kind == ABC:
        bee_colony.abc_tell(ws, m)
    else:
        firefly.fa_tell(ws, m)
    return ws.scal[DONE] != 0.0


def swarm_workspace(config: SwarmConfig, dim: int) -> SwarmWorkspace:
    """The buffers of ``config``'s swarm for a ``dim``-dimensional search, allocated once."""
    kind = config.kind
    module = _MODULES[kind]
    members = config.members if config.members is not None else DEFAULT_MEMBERS[kind]
    if kind == ABC:
        members //= 2  # employed bees = onlookers = food sources
    params = module.DEFAULTS if config.params is None else tuple(config.params)
    if len(params) != module.N_PARAMS:
        raise ValueError(
            f"{config.optimizer} takes {module.N_PARAMS} parameters, got {len(params)}"
        )
    ws = make_workspace(members, dim, module.N_PARAMS)
    ws.params[:] = params
    return ws


@dataclass(frozen=True)
class OptimizeResult:
    x: np.ndarray
    value: float
    iterations: int
    evaluations: int


class SwarmOptimizer:
    """Minimise an objective over a box with one of the swarm methods.

    The workspace is allocated once; every ``minimize`` reuses it. The random stream is
    reseeded when ``seed`` is given and otherwise continues, so a sequence of calls is
    reproducible from the constructor's seed.
    """

    def __init__(self, config: SwarmConfig | None = None, dim: int = 3, seed: int = 0):
        self.config = config or SwarmConfig()
        self.kind = self.config.kind
        self.dim = dim
        self.ws = swarm_workspace(self.config, dim)
        self.reseed(seed)

    def reseed(self, seed: int) -> None:
        """Restart the random stream from ``seed``, as the constructor starts it."""
        seed_state(seed, self.ws.rng)

    def prepare(self, lo, hi, seed: int | None = None) -> None:
        """Set the box and clear the run; the compiled callers' entry point."""
        lo = np.asarray(lo, dtype=np.float64)
        hi = np.asarray(hi, dtype=np.float64)
        if lo.shape != (self.dim,) or hi.shape != (self.dim,):
            raise ValueError(f"bounds must have shape ({self.dim},); got {lo.shape}, {hi.shape}")
        if not np.all(np.isfinite(lo)) or not np.all(np.isfinite(hi)) or np.any(hi <= lo):
            raise ValueError(f"bounds must be finite with lo < hi; got lo={lo}, hi={hi}")
        self.ws.lo[:] = lo
        self.ws.hi[:] = hi
        if seed is not None:
            self.reseed(seed)
        c = self.config
        reset_run(
            self.ws,
            c.max_iterations,
            c.stagnation_iterations,
            c.stagnation_tol,
            c.target_value,
            c.max_evaluations,
            c.stall_window,
            c.stall_tol,
        )
        start(self.kind, self.ws)

    def minimize(self, objective, lo, hi, seed: int | None = None) -> OptimizeResult:
        """Minimise ``objective`` (rows of an ``(m, dim)`` array → ``(m,)`` values) on ``[lo, hi]``."""
        self.prepare(lo, hi, seed)
        ws = self.ws
        while True:
            m = ask(self.kind, ws)
            if m:
                values = np.asarray(objective(ws.cand[:m]), dtype=np.float64)
                if values.shape != (m,):
                    raise ValueError(
                        f"objective must return shape ({m},) for {m} candidates, got {values.shape}"
                    )
                ws.cand_val[:m] = values
            if tell(self.kind, ws, m):
                break
        return self.result()

    def result(self) -> OptimizeResult:
        s = self.ws.scal
        return OptimizeResult(
            x=self.ws.best.copy(),
            value=float(s[BEST_VAL]),
            iterations=int(s[ITERATION]),
            evaluations=int(s[EVALUATIONS]),
        )
