"""The back end of Alg. 4 — loop-closure search (Alg. 7) and re-optimisation (Eq. 21) — cut
into slices a fixed-rate tick can afford.

Each new node joins a queue of fixed capacity. Its search then runs as a chain of slices:

* ``SELECT``: the node's gated candidates (Alg. 7, steps 1–2; microseconds);
* ``ALIGN``: one candidate's alignment and inlier test (Alg. 5 on the loop matcher);
* ``CLOSE``: add the edge, optimise the graph, keep or undo it (consistency test).

A slice runs only if its expected cost — a maximum of what that kind of slice took, fading
by 3% per tick —
fits in the time the tick has left; otherwise it waits for the next tick (counted as deferred).
So the front end always runs, and the back end uses the slack. A slice that has waited
``max_deferred_ticks`` ticks runs anyway (counted as forced): work is late, never lost. A full
queue drops its oldest node's search (counted; the runtime's status says so).
"""

from __future__ import annotations

import numpy as np

SELECT, ALIGN, CLOSE = 0, 1, 2
SLICE_NAMES = ("select", "align", "close")


class BackEnd:
    def __init__(self, slam, queue_capacity: int = 64, max_deferred_ticks: int = 10):
        if queue_capacity < 1:
            raise ValueError(f"loop queue capacity must be >= 1, got {queue_capacity}")
        self.slam = slam
        self.queue = np.zeros(queue_capacity, np.int64)
        self.head = 0  # index of the oldest queued node
        self.size = 0
        attempts = slam.loops.config.max_attempts
        self.candidates = np.zeros(max(attempts, 1), np.int64)
        self.n_candidates = 0
        self.next_candidate = 0
        self.node = -1  # node whose search is under way (-1: none)
        self.phase = SELECT
        self.z = np.zeros(3)  # the aligned candidate's measurement, between ALIGN and CLOSE
        self.cost = np.zeros(3)  # expected seconds per slice kind (decaying maximum)
        self.max_deferred_ticks = max_deferred_ticks
        self.waited = 0  # ticks the next slice has been deferred in a row
        self.enqueued = 0
        self.searched = 0  # node searches finished
        self.dropped = 0  # searches dropped from a full queue
        self.slices = np.zeros(3, np.int64)
        self.deferred = 0  # ticks that ended with back-end work left undone for lack of time
        self.forced = 0  # slices run over budget after waiting max_deferred_ticks

    # ------------------------------------------------------------------ queue
    def enqueue(self, node: int) -> None:
        cap = self.queue.shape[0]
        if self.size == cap:  # drop the oldest search
            self.head = (self.head + 1) % cap
            self.size -= 1
            self.dropped += 1
        self.queue[(self.head + self.size) % cap] = node
        self.size += 1
        self.enqueued += 1

    def pending(self) -> bool:
        return self.node >= 0 or self.size > 0

    def queued(self) -> list[int]:
        cap = self.queue.shape[0]
        return [int(self.queue[(self.head + k) % cap]) for k in range(self.size)]

    # ------------------------------------------------------------------ slicing
    def work(self, clock, budget_end: float | None) -> int:
        """Run slices while their expected cost fits before ``budget_end`` (None: all pending
        work, no clock consulted — the lockstep schedule). Returns the slices run."""
        ran = 0
        if budget_end is not None:
            self.cost *= 0.97  # estimates fade per tick, so one slow outlier is soon forgotten
        while self.pending():
            kind = self.phase if self.node >= 0 else SELECT
            start = clock() if budget_end is not None else 0.0
            if budget_end is not None and start + self.cost[kind] > budget_end:
                if self.waited < self.max_deferred_ticks:
                    self.waited += 1
                    self.deferred += 1
                    break
                self.forced += 1
            self._run_slice(kind)
            self.slices[kind] += 1
            self.waited = 0
            ran += 1
            if budget_end is not None:
                took = clock() - start
                self.cost[kind] = max(took, 0.95 * self.cost[kind])
        return ran

    def _run_slice(self, kind: int) -> None:
        slam = self.slam
        if kind == SELECT:
            cap = self.queue.shape[0]
            self.node = int(self.queue[self.head])
            self.head = (self.head + 1) % cap
            self.size -= 1
            found = slam.loop_candidates(self.node)
            n = min(len(found), self.candidates.shape[0])
            for k in range(n):
                self.candidates[k] = found[k]
            self.n_candidates = n
            self.next_candidate = 0
            self.phase = ALIGN
            if n == 0:
                self._finish()
            return
        if slam.edges_full():
            self._finish()
            return
        candidate = int(self.candidates[self.next_candidate])
        if kind == ALIGN:
            z = slam.align_loop(candidate, self.node)
            if z is None:
                self._next_candidate()
            else:
                self.z[:] = z
                self.phase = CLOSE
            return
        if slam.close_loop(candidate, self.node, self.z):
            self._finish()
        else:
            self._next_candidate()

    def _next_candidate(self) -> None:
        self.next_candidate += 1
        self.phase = ALIGN
        if self.next_candidate >= self.n_candidates:
            self._finish()

    def _finish(self) -> None:
        self.node = -1
        self.phase = SELECT
        self.searched += 1

    # ------------------------------------------------------------------ sessions
    def state(self) -> dict:
        return {
            "queue": np.array(self.queued(), np.int64),
            "candidates": self.candidates[: self.n_candidates].copy(),
            "z": self.z.copy(),
            "cost": self.cost.copy(),
            "slices": self.slices.copy(),
            "scalars": np.array([self.node, self.phase, self.next_candidate, self.waited,
                                 self.enqueued, self.searched, self.dropped, self.deferred,
                                 self.forced], np.int64),
        }

    def restore(self, state: dict) -> None:
        queue = state["queue"]
        if len(queue) > self.queue.shape[0]:
            raise ValueError(f"{len(queue)} queued loop searches exceed the queue capacity "
                             f"{self.queue.shape[0]}")
        self.head, self.size = 0, len(queue)
        self.queue[: self.size] = queue
        cand = state["candidates"]
        self.n_candidates = len(cand)
        self.candidates[: self.n_candidates] = cand
        self.z[:] = state["z"]
        self.cost[:] = state["cost"]
        self.slices[:] = state["slices"]
        (self.node, self.phase, self.next_candidate, self.waited, self.enqueued, self.searched,
         self.dropped, self.deferred, self.forced) = (int(v) for v in state["scalars"])
