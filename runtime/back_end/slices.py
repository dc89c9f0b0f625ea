"""The back end (global SLAM): the pose graph's loop-closure search (Alg. 7) and its
re-optimisation (Eq. 21), written once as a state machine of slices run from a dispatch
table; docs/runtime.md §3.

Each new node joins a queue of fixed capacity. Its search then runs as a chain of slices:

* ``SELECT``: the node's gated candidates (Alg. 7, steps 1–2; microseconds);
* ``ALIGN``: one candidate's alignment with the submap around it and the inlier test (Alg. 5
  on the loop matcher; :mod:`swarmslam.runtime.back_end.loop_alignment`);
* ``CLOSE``: loop verification (:mod:`swarmslam.runtime.back_end.loop_trial`): optimise a copy of the
  graph with the edge, one Gauss–Newton step per slice in the budgeted schedule, then keep the
  edge and the new poses (the consistency test) or drop them;
* ``WIDE``: when the node's candidates gave nothing and no closure with an old node was kept
  for ``wide_search.after`` nodes, the wide search (:mod:`swarmslam.runtime.back_end.wide_loop_search`) over the old nodes'
  map; its proposal, if any, is aligned and closed as a candidate is. In the budgeted schedule
  the search is itself a chain of WIDE slices (a part of its grid rendered or pooled, a share
  of its branch and bound), so that a wide window does not overrun a tick.

``work(clock, None)`` — the lockstep schedule — runs every pending slice now, so the whole of
Alg. 7 happens in the tick that added the node. ``work(clock, budget_end)`` runs a slice only
if its expected cost — the largest it took lately, fading by ``SLICE_COST_DECAY`` per tick —
fits before ``budget_end``; otherwise it waits for the next tick (counted as deferred), and
after ``max_deferred_ticks`` runs anyway (counted as forced): late, never lost. A full queue
drops its oldest node's search (counted; the runtime's status says so).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from swarmslam.runtime.config import SlamConfig
from swarmslam.runtime.back_end.loop_alignment import LoopAlignment
from swarmslam.runtime.back_end.loop_closure import LoopCloser
from swarmslam.runtime.back_end.loop_trial import ClosureTrial
from swarmslam.runtime.back_end.search_queue import FailedMatches, SearchQueue
from swarmslam.runtime.node_scans import NodeScans
from swarmslam.runtime.pose_graph import LOOP, PoseGraph
from swarmslam.runtime.tallies import restore_counts
from swarmslam.runtime.back_end.wide_loop_search import WIDE_REFINE_WINDOW, WideLoopSearch

SELECT, ALIGN, CLOSE, WIDE = 0, 1, 2, 3
SLICE_NAMES = ("select", "align", "close", "wide")
# A slice kind's expected cost: its largest lately, fading by SLICE_COST_DECAY per tick (one
# slow outlier is soon forgotten); a measured cost replaces it unless SLICE_COST_MEMORY × the
# estimate is larger.
SLICE_COST_DECAY = 0.97
SLICE_COST_MEMORY = 0.95


@dataclass
class SearchCounts:
    """The queue's and the slicing's tallies, saved with a session and reported whole."""

    enqueued: int = 0  # node searches queued
    searched: int = 0  # node searches finished
    dropped: int = 0  # searches dropped from a full queue
    deferred: int = 0  # ticks that ended with back-end work left undone for lack of time
    forced: int = 0  # slices run over budget after waiting max_deferred_ticks


class BackEnd:
    def __init__(self, config: SlamConfig, graph: PoseGraph, nodes: NodeScans, information,
                 seed: int = 0):
        """``information(loop=True)`` gives a new loop edge's information matrix (the front
        end's)."""
        lc, rc = config.loop_closure, config.runtime
        self.config = config
        self.graph, self.nodes, self.information = graph, nodes, information
        self.loops = LoopCloser(lc)
        self.wide = WideLoopSearch(lc, graph.max_nodes, config.sensor.max_points,
                                   config.matcher.max_gap)
        self.z = np.zeros(3)  # the aligned candidate's measurement, between ALIGN and CLOSE
        self.z_info = np.eye(3)  # and its information
        self.alignment = LoopAlignment(config, graph, nodes, self.loops, self.wide, information,
                                       self.z_info, seed)
        self.matcher = self.alignment.matcher
        # A closure on trial is optimised in a copy of the graph: the front end goes on
        # adding nodes to the graph itself between the trial's slices (docs/runtime.md §3).
        self.closure = ClosureTrial(config, graph, self.loops)
        self.revision = 0  # bumped whenever a kept closure moved the optimised poses
        # The queue of nodes awaiting their search, and the search under way.
        self.queue = SearchQueue(rc.loop_queue)
        self.candidates = np.zeros(lc.max_attempts, np.int64)
        self.failed = FailedMatches(lc.max_attempts)
        self.n_candidates = 0
        self.next_candidate = 0
        self.node = -1  # node whose search is under way (-1: none)
        self.phase = SELECT
        self.widened = False  # the search under way has gone wide: its candidate is a proposal
        self._wide_steps = None  # the wide search under way (WideLoopSearch.search), if any
        self._closing = None  # the closure on trial (ClosureTrial.steps), if any
        self.guess = np.zeros(3)  # the proposal: the node's pose in the candidate's frame
        self._wide_window = np.asarray(WIDE_REFINE_WINDOW, dtype=np.float64)
        self.last_closure = 0  # the last node closed with an old one (wide_search.min_gap back)
        self.wide_from = 0  # the first node a wide search may run at (wide_search.spacing after one
        # that fitted its scan nowhere)
        self.cost = np.zeros(len(SLICE_NAMES))  # expected seconds per slice kind (decaying max)
        self.waited = 0  # ticks the next slice has been deferred in a row
        self.counts = SearchCounts()
        self.slices = np.zeros(len(SLICE_NAMES), np.int64)  # slices run, by kind
        self._slice = (self._select, self._align, self._close, self._wide)  # by kind

    @property
    def status(self) -> str:
        return self.closure.status

    # ------------------------------------------------------------------ the queue
    def enqueue(self, node: int) -> None:
        """Queue ``node``'s loop search (Alg. 7 runs when :meth:`work` gets to it); a full
        queue drops its oldest search."""
        self.counts.dropped += self.queue.push(node)
        self.counts.enqueued += 1

    def pending(self) -> bool:
        return self.node >= 0 or self.queue.size > 0

    # ------------------------------------------------------------------ slicing
    def work(self, clock, budget_end: float | None) -> int:
        """Run slices while their expected cost fits before ``budget_end`` (None: all pending
        work, no clock consulted — the lockstep schedule). Returns the slices run."""
        rc = self.config.runtime
        ran = 0
        if budget_end is not None:
            self.cost *= SLICE_COST_DECAY  # one slow outlier is soon forgotten
        while self.pending():
            kind = self.phase if self.node >= 0 else SELECT
            start = clock() if budget_end is not None else 0.0
            if budget_end is not None and start + self.cost[kind] > budget_end:
                if self.waited < rc.max_deferred_ticks:
                    self.waited += 1
                    self.counts.deferred += 1
                    break
                self.counts.forced += 1
            self._run_slice(kind, budget_end is not None)
            self.slices[kind] += 1
            self.waited = 0
            ran += 1
            if budget_end is not None:
                took = clock() - start
                self.cost[kind] = max(took, SLICE_COST_MEMORY * self.cost[kind])
        return ran

    def _run_slice(self, kind: int, sliced: bool = False) -> None:
        """One slice of ``kind``; ``sliced``: a wide search or a trial goes on by one of its
        own slices rather than to its end (docs/runtime.md §3)."""
        if kind != SELECT and self.edges_full():
            self._finish()
            return
        self._slice[kind](sliced)

    def _select(self, sliced: bool) -> None:
        """The next queued node's candidates (Alg. 7, steps 1–2)."""
        self.node = self.queue.pop()
        if self._closed_lately(self.node):
            self._finish()
            return
        n = self.failed.take_untried(self.loop_candidates(self.node), self.node, self.revision,
                                     self.candidates)
        self.n_candidates = n
        self.next_candidate = 0
        self.phase = ALIGN
        if n == 0:
            self._exhausted()

    def _align(self, sliced: bool) -> None:
        """The next candidate aligned (step 3a); on to CLOSE if it matched."""
        candidate = int(self.candidates[self.next_candidate])
        z = (self.align_loop(candidate, self.node, self.guess, self._wide_window)
             if self.widened else self.align_loop(candidate, self.node))
        if z is None:
            if not self.widened:
                self.failed.add(candidate)
            self._next_candidate()
        else:
            self.z[:] = z
            self.phase = CLOSE

    def _close(self, sliced: bool) -> None:
        """One slice of the aligned candidate's loop verification (steps 3b–4)."""
        if self._closing is None:
            candidate = int(self.candidates[self.next_candidate])
            self._closing = self.closure.steps(candidate, self.node, self.z, self.z_info,
                                               self.widened)
        done, kept = _advance(self._closing, sliced)
        if not done:
            return  # the trial goes on in the next CLOSE slice
        self._closing = None
        if self._kept(kept, self.node):
            self._finish()
        else:
            self._next_candidate()

    def _wide(self, sliced: bool) -> None:
        """One slice of the wide search (step 5); its proposal, if any, goes to ALIGN."""
        if self._wide_steps is None:
            self._wide_steps = self.wide.search(self.graph.poses, self.nodes, self.node,
                                                self.last_closure, sliced)
        done, proposal = _advance(self._wide_steps, sliced)
        if not done:
            return  # the search goes on in the next WIDE slice
        self._wide_steps = None
        if self.wide.fitted == 0:  # new ground: the next nodes see much the same
            self.wide_from = self.node + self.loops.config.wide_search.spacing
        if proposal is None:
            self._finish()
            return
        self.candidates[0], self.guess[:] = proposal
        self.n_candidates, self.next_candidate = 1, 0
        self.phase = ALIGN

    def _kept(self, old_end: int, node: int) -> bool:
        """A verification's verdict (the kept edge's old end, −1: refused) taken: a kept one
        moved the poses, and one with the old map restarts the wide search's wait."""
        if old_end < 0:
            return False
        self.revision += 1
        if node - old_end >= self.loops.config.wide_search.min_gap:  # a closure with the old map
            self.last_closure = node
        return True

    def _closed_lately(self, node: int) -> bool:
        """Whether a loop closure was kept at one of the ``closure_spacing`` nodes before
        ``node``: its search is skipped, the graph having just been anchored there (as
        Cartographer samples its constraints; docs/method.md §5). Read off the graph's
        newest edges, which join the newest nodes."""
        spacing = self.loops.config.closure_spacing
        g = self.graph
        k = g.n_edges - 1
        while spacing > 0 and k >= 0 and max(g.ij[k, 0], g.ij[k, 1]) >= node - spacing:
            if g.kind[k] == LOOP and g.ij[k, 1] < node:
                return True
            k -= 1
        return False

    def _next_candidate(self) -> None:
        self.next_candidate += 1
        self.phase = ALIGN
        if self.next_candidate >= self.n_candidates:
            self._exhausted()

    def _exhausted(self) -> None:
        """The node's candidates gave nothing: search widely if a long drift may hide its loop
        (no closure with an old node kept for ``wide_search.after`` nodes), else the search is
        done."""
        wide = self.loops.config.wide_search
        if (not self.widened and wide.enabled
                and self.node - self.last_closure >= wide.after
                and self.node >= self.wide_from):
            self.widened = True
            self.phase = WIDE
        else:
            self._finish()

    def _finish(self) -> None:
        self._wide_steps = self._closing = None  # (cut short when the edges ran out)
        self.node = -1
        self.phase = SELECT
        self.widened = False
        self.counts.searched += 1

    # ------------------------------------------------------------------ Alg. 7's steps
    def seek_loop_closure(self, node: int) -> bool:
        """Alg. 7 for ``node`` now, through the same slices (with any other pending work);
        True if a closure was kept."""
        revision = self.revision
        self.enqueue(node)
        self.work(None, None)
        return self.revision != revision

    def loop_candidates(self, node: int) -> list[int]:
        """Steps 1–2: nearby nodes inside the 95% ellipse, closest first."""
        return self.loops.candidates(self.graph, self.nodes.cov, node)

    def align_loop(self, candidate: int, node: int, guess=None, window=None):
        """Step 3a (:meth:`LoopAlignment.align`): ``node``'s pose in ``candidate``'s frame, or
        None; its information in :attr:`z_info`."""
        return self.alignment.align(candidate, node, guess, window)

    def close_loop(self, candidate: int, node: int, z) -> bool:
        """Steps 3b–4 now (information :attr:`z_info`): add the loop edge, re-optimise (Eq. 21),
        and keep the edge only if the graph stays consistent; otherwise the graph is left as
        it was."""
        steps = self.closure.steps(candidate, node, z, self.z_info, self.widened)
        return self._kept(_advance(steps, sliced=False)[1], node)

    def edges_full(self) -> bool:
        """True (and said in the status) once the edge capacity leaves no room for a loop."""
        return self.closure.edges_full()

    # ------------------------------------------------------------------ state
    def state(self) -> dict:
        return {
            "matcher": self.matcher.state(), "counts": asdict(self.counts),
            "loops": asdict(self.loops.counts), "slices": self.slices.copy(),
            "queue": np.array(self.queue.queued(), np.int64),
            "candidates": self.candidates[: self.n_candidates].copy(),
            "z": self.z.copy(), "z_info": self.z_info.copy(), "cost": self.cost.copy(),
            "wide": self.wide.state(), "guess": self.guess.copy(),
            "widened": self.widened, "last_closure": self.last_closure,
            "wide_from": self.wide_from, **self.failed.state(),
            "node": self.node, "phase": self.phase, "next_candidate": self.next_candidate,
            "waited": self.waited, "revision": self.revision, "status": self.status,
            **self.closure.memory.state(),
        }

    def restore(self, state: dict) -> None:
        queue, cand = state["queue"], state["candidates"]
        if len(cand) > self.candidates.shape[0]:
            raise ValueError(f"{len(cand)} loop candidates exceed max_attempts "
                             f"{self.candidates.shape[0]}")
        n = self.graph.n_nodes
        node = int(state["node"])
        if any(not 0 <= int(v) < n for v in (*queue, *cand)) or not -1 <= node < n:
            raise ValueError("the loop search refers to nodes that do not exist")
        if (not SELECT <= int(state["phase"]) <= WIDE
                or not 0 <= int(state["next_candidate"]) <= len(cand)):
            raise ValueError("the loop search is in a state it never takes")
        self.queue.restore(queue)
        self.failed.restore(state, n)
        self.matcher.restore(state["matcher"])
        restore_counts(self.counts, state["counts"])
        restore_counts(self.loops.counts, state["loops"])
        self.n_candidates = len(cand)
        self.candidates[: self.n_candidates] = cand
        self.z[:], self.cost[:], self.slices[:] = state["z"], state["cost"], state["slices"]
        self.z_info[:] = state["z_info"]
        self.wide.restore(state["wide"])
        self.guess[:] = state["guess"]
        self.widened = bool(state["widened"])
        self._wide_steps = None  # a wide search under way begins again: it keeps no state
        self._closing = None  # and so does a closure on trial (the graph holds no trial edge)
        self.last_closure = int(state["last_closure"])
        self.wide_from = int(state["wide_from"])
        self.node = node
        self.phase, self.next_candidate, self.waited, self.revision = (
            int(state[k]) for k in ("phase", "next_candidate", "waited", "revision"))
        self.closure.status = str(state["status"])
        self.closure.memory.restore(state, n)


def _advance(steps, sliced: bool):
    """One slice of a chain of ``steps`` (a generator), or all that is left of it when not
    ``sliced``: (whether it finished, what it returned)."""
    try:
        next(steps)
        while not sliced:
            next(steps)
        return False, None
    except StopIteration as stop:
        return True, stop.value
