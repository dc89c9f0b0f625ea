"""The back end (global SLAM): the pose graph's loop-closure search (Alg. 7) and its
re-optimisation (Eq. 21), written once as a state machine of slices; docs/runtime.md §3.

Each new node joins a queue of fixed capacity. Its search then runs as a chain of slices:

* ``SELECT``: the node's gated candidates (Alg. 7, steps 1–2; microseconds);
* ``ALIGN``: one candidate's alignment with the submap around it and the inlier test (Alg. 5
  on the loop matcher);
* ``CLOSE``: optimise a copy of the graph with the edge, one Gauss–Newton step per slice in
  the budgeted schedule, then keep the edge and the new poses (the consistency test) or drop
  them;
* ``WIDE``: when the node's candidates gave nothing and no closure with an old node was kept
  for ``wide_after`` nodes, the wide search (:mod:`swarmslam.runtime.wide_loop_search`) over the old nodes'
  map; its proposal, if any, is aligned and closed as a candidate is. In the budgeted schedule
  the search is itself a chain of WIDE slices (a part of its grid rendered or pooled, a share
  of its branch and bound), so that a wide window does not overrun a tick.

``work(clock, None)`` — the lockstep schedule — runs every pending slice now, so the whole of
Alg. 7 happens in the tick that added the node. ``work(clock, budget_end)`` runs a slice only
if its expected cost — the largest it took lately, fading by ``slice_cost_decay`` per tick —
fits before ``budget_end``; otherwise it waits for the next tick (counted as deferred), and
after ``max_deferred_ticks`` runs anyway (counted as forced): late, never lost. A full queue
drops its oldest node's search (counted; the runtime's status says so).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from swarmslam.runtime.config import SlamConfig
from swarmslam.runtime.degeneracy import Degeneracy
from swarmslam.runtime.graph_optimizer import GaussNewton
from swarmslam.runtime.loop_closure import LoopCloser, relative_guess, visibility
from swarmslam.runtime.node_scans import NodeScans
from swarmslam.runtime.pose import between, compose, wrap_angle
from swarmslam.runtime.pose_graph import LOOP, PoseGraph
from swarmslam.runtime.scan import PointScan
from swarmslam.runtime.scan_matcher import ScanMatcher, beyond_margin
from swarmslam.runtime.sparse_ldl import FactorCapacityError
from swarmslam.runtime.wide_loop_search import WideLoopSearch

SELECT, ALIGN, CLOSE, WIDE = 0, 1, 2, 3
SLICE_NAMES = ("select", "align", "close", "wide")
EDGES_FULL_STATUS = "capacity reached: no more loop closures"


class BackEnd:
    def __init__(self, config: SlamConfig, graph: PoseGraph, nodes: NodeScans, information,
                 seed: int = 0):
        """``information(loop=True)`` gives a new loop edge's information matrix (the front
        end's)."""
        lc, rc = config.loop_closure, config.runtime
        self.config = config
        self.graph, self.nodes, self.information = graph, nodes, information
        # A closure on trial is optimised in a copy of the graph: the front end goes on
        # adding nodes to the graph itself between the trial's slices (docs/runtime.md §3).
        self.trial = PoseGraph(graph.max_nodes, graph.max_edges)
        self.optimizer = GaussNewton(self.trial, config.optimizer)
        self.loops = LoopCloser(lc)
        self.wide = WideLoopSearch(lc, graph.max_nodes, config.sensor.max_points,
                                   config.matcher.max_gap)
        # a loop's guess is the graph's estimate, never trusted as a prediction
        self.matcher = ScanMatcher(replace(config.matcher, guess_window=lc.search_window,
                                           predict_first=0.0),
                                   seed=seed)
        self.reference = self.matcher.new_reference()
        points = config.sensor.max_points
        self._scan = PointScan(points)
        self._submap = PointScan(points * (2 * lc.submap_nodes + 1))
        self._members = np.zeros(2 * lc.submap_nodes + 1, np.int64)  # the submap's nodes
        self._saved_poses = np.zeros((graph.max_nodes, 3))
        self._image = np.zeros(lc.bearing_bins)
        self._state = np.zeros(points, np.int64)
        self._seen = np.zeros(2, np.int64)
        self._window = np.zeros(3)
        self._wide_window = np.asarray(lc.wide_refine_window, dtype=np.float64)
        self.revision = 0  # bumped whenever a kept closure moved the optimised poses
        self.status = "ok"
        # The queue of nodes awaiting their search, and the search under way.
        self.queue = np.zeros(rc.loop_queue, np.int64)
        self.head = 0  # index of the oldest queued node
        self.size = 0
        self.candidates = np.zeros(lc.max_attempts, np.int64)
        self.failed = np.zeros(lc.max_attempts, np.int64)  # candidates whose match failed ...
        self.n_failed = 0
        self.failed_node = -1  # ... for this node's search
        self.failed_revision = -1  # ... with the graph at this revision
        self.n_candidates = 0
        self.next_candidate = 0
        self.node = -1  # node whose search is under way (-1: none)
        self.phase = SELECT
        self.z = np.zeros(3)  # the aligned candidate's measurement, between ALIGN and CLOSE
        self.z_info = np.eye(3)  # and its information
        self.widened = False  # the search under way has gone wide: its candidate is a proposal
        self._wide_steps = None  # the wide search under way (WideLoopSearch.search), if any
        self._closing = None  # the closure on trial (_close_steps), if any
        self.guess = np.zeros(3)  # the proposal: the node's pose in the candidate's frame
        self.last_closure = 0  # the last node closed with an old one (wide_min_gap back)
        # The last loop refused for the rise of the total alone (its own error passed): the
        # candidate, the node and its measurement; a later one that agrees with it is judged
        # by its own error (docs/method.md §5, step 4).
        self.rise_refused = np.array([-1.0, -1.0, 0.0, 0.0, 0.0])
        # The last loop refused for its own error (the graph could not absorb it), as above,
        # and its information: one that agrees with it may take the place of the kept loops
        # the two strain most (docs/method.md §5, step 4).
        self.strained = np.array([-1.0, -1.0, 0.0, 0.0, 0.0])
        self.strained_info = np.zeros((3, 3))
        self._chi2_before = np.zeros(graph.max_edges)
        self._given_up = np.zeros(max(lc.max_given_up, 1), np.int64)
        self.wide_from = 0  # the first node a wide search may run at (wide_spacing after one
        # that fitted its scan nowhere)
        self.cost = np.zeros(len(SLICE_NAMES))  # expected seconds per slice kind (decaying max)
        self.waited = 0  # ticks the next slice has been deferred in a row
        self.enqueued = 0
        self.searched = 0  # node searches finished
        self.dropped = 0  # searches dropped from a full queue
        self.slices = np.zeros(len(SLICE_NAMES), np.int64)
        self.deferred = 0  # ticks that ended with back-end work left undone for lack of time
        self.forced = 0  # slices run over budget after waiting max_deferred_ticks

    # ------------------------------------------------------------------ the queue
    def enqueue(self, node: int) -> None:
        """Queue ``node``'s loop search (Alg. 7 runs when :meth:`work` gets to it)."""
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
        rc = self.config.runtime
        ran = 0
        if budget_end is not None:
            self.cost *= rc.slice_cost_decay  # one slow outlier is soon forgotten
        while self.pending():
            kind = self.phase if self.node >= 0 else SELECT
            start = clock() if budget_end is not None else 0.0
            if budget_end is not None and start + self.cost[kind] > budget_end:
                if self.waited < rc.max_deferred_ticks:
                    self.waited += 1
                    self.deferred += 1
                    break
                self.forced += 1
            self._run_slice(kind, budget_end is not None)
            self.slices[kind] += 1
            self.waited = 0
            ran += 1
            if budget_end is not None:
                took = clock() - start
                self.cost[kind] = max(took, rc.slice_cost_memory * self.cost[kind])
        return ran

    def _run_slice(self, kind: int, sliced: bool = False) -> None:
        """One slice of ``kind``; ``sliced``: a wide search goes on by one of its own slices
        rather than to its end (docs/runtime.md §3)."""
        if kind == SELECT:
            cap = self.queue.shape[0]
            self.node = int(self.queue[self.head])
            self.head = (self.head + 1) % cap
            self.size -= 1
            if self._closed_lately(self.node):
                self._finish()
                return
            n = self._take_untried(self.loop_candidates(self.node))
            self.failed_node, self.failed_revision, self.n_failed = self.node, self.revision, 0
            self.n_candidates = n
            self.next_candidate = 0
            self.phase = ALIGN
            if n == 0:
                self._exhausted()
            return
        if self.edges_full():
            self._finish()
            return
        if kind == WIDE:
            if self._wide_steps is None:
                self._wide_steps = self.wide.search(self.graph.poses, self.nodes, self.node,
                                                    self.last_closure, sliced)
            done, proposal = _advance(self._wide_steps, sliced)
            if not done:
                return  # the search goes on in the next WIDE slice
            self._wide_steps = None
            if self.wide.fitted == 0:  # new ground: the next nodes see much the same
                self.wide_from = self.node + self.loops.config.wide_spacing
            if proposal is None:
                self._finish()
                return
            self.candidates[0], self.guess[:] = proposal
            self.n_candidates, self.next_candidate = 1, 0
            self.phase = ALIGN
            return
        candidate = int(self.candidates[self.next_candidate])
        if kind == ALIGN:
            z = (self.align_loop(candidate, self.node, self.guess, self._wide_window)
                 if self.widened else self.align_loop(candidate, self.node))
            if z is None:
                if not self.widened and self.n_failed < self.failed.shape[0]:
                    self.failed[self.n_failed] = candidate
                    self.n_failed += 1
                self._next_candidate()
            else:
                self.z[:] = z
                self.phase = CLOSE
            return
        if self._closing is None:
            self._closing = self._close_steps(candidate, self.node, self.z)
        done, kept = _advance(self._closing, sliced)
        if not done:
            return  # the trial goes on in the next CLOSE slice
        self._closing = None
        if kept:
            self._finish()
        else:
            self._next_candidate()

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

    def _take_untried(self, found) -> int:
        """Keep the first ``max_attempts`` of ``found`` as the node's candidates, passing over
        those whose match failed for the node just before with the graph as it is now: half
        a metre on, against the same submap, such a match fails again (MIT-CSAIL: 93% of
        them), and the attempt is better spent on the next candidate (docs/method.md §5,
        step 3). Returns how many."""
        repeat = self.failed_node == self.node - 1 and self.failed_revision == self.revision
        n = 0
        for candidate in found:
            if n == self.candidates.shape[0]:
                break
            if repeat and candidate in self.failed[: self.n_failed]:
                continue
            self.candidates[n] = candidate
            n += 1
        return n

    def _next_candidate(self) -> None:
        self.next_candidate += 1
        self.phase = ALIGN
        if self.next_candidate >= self.n_candidates:
            self._exhausted()

    def _exhausted(self) -> None:
        """The node's candidates gave nothing: search widely if a long drift may hide its loop
        (no closure with an old node kept for ``wide_after`` nodes), else the search is
        done."""
        lc = self.loops.config
        if (not self.widened and lc.wide_after > 0
                and self.node - self.last_closure >= lc.wide_after
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
        self.searched += 1

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
        """Step 3a: ``node``'s pose in ``candidate``'s frame by Alg. 5 against the submap
        around the candidate — in a box around ``guess`` (default: the graph's estimate) of
        half-widths ``window`` (default: :meth:`LoopCloser.window`) — or None when the match
        ends at the edge of its box, or the submap's surfaces hold too few of its points and
        its scans saw too little of where the match puts them, or saw through too many.

        The submap: the candidate's scan and ``submap_nodes`` either side. A ``guess`` given is
        a wide search's proposal: the submap is then the old nodes nearest to where it puts
        ``node`` (the map the proposal was found in) and the submap tests are left to the
        search's own (docs/method.md §5, step 5)."""
        loops = self.loops
        c = loops.config
        loops.attempts += 1
        members = self._members
        proposal = guess is not None
        if not proposal:
            first, last = loops.submap_span(candidate, node)
            n_members = last - first + 1
            for k in range(n_members):
                members[k] = first + k
        else:
            n_members = self.wide.members(self.graph.poses, node, candidate, guess, members)
        submap = self.nodes.place(self.graph.poses, members[:n_members], candidate,
                                  self._submap)
        scan = self.nodes.load(node, self._scan)
        if not proposal:
            guess = relative_guess(self.graph, candidate, node)
        if window is None:
            window = self.loops.window(self.graph, self.nodes.cov, candidate, node,
                                       self._window)
        # the fine field only for a global stage that ended inside the box
        match = self.matcher.align_inside(scan, submap, self.reference, guess, window,
                                          c.window_margin)
        if match is None or self._at_edge(match.pose, guess, window):  # at or beyond the box
            loops.rejected_match += 1
            return None
        pose, reference = match.pose, self.reference
        self.z_info[:] = self.information(loop=True)
        ratio = self.config.front_end.degeneracy_ratio
        if ratio > 0:  # along a corridor the guess stands in, the edge weak there
            fc = self.config.front_end
            h = self.matcher.curvature(scan, reference, pose, fc.curvature_step)
            degeneracy = Degeneracy(h, ratio, fc.degenerate_information)
            pose = degeneracy.remap(pose, guess)
            # An ordinary search's guess is the graph's own estimate: along the axis the edge
            # repeats it rather than measuring it, and would pin the drift it holds (Intel's
            # first corridor, 0.87 m); the floor frees it (docs/method.md §5, step 3).
            share = None if proposal else c.degenerate_information
            self.z_info[:] = degeneracy.information(self.z_info, share)
        if proposal:
            return pose  # the wide search's own tests stand (runtime/wide_loop_search.py)
        return self._submap_agrees(scan, reference, pose, candidate, members, n_members)

    def _submap_agrees(self, scan, reference, pose, candidate, members, n_members):
        """The ordinary loop match's tests: inliers on the submap, or what its scans saw."""
        loops = self.loops
        c = loops.config
        inliers = self.matcher.inlier_fraction(scan, reference, pose, c.inlier_distance,
                                               c.inlier_slope)
        seen = self._seen  # both tests always run: one cost per attempt, every kernel warm
        visibility(self.nodes.points, self.nodes.counts, self.graph.poses, members, n_members,
                   candidate, scan.buffer, scan.count, float(pose[0]), float(pose[1]),
                   float(pose[2]), c.inlier_distance, c.inlier_slope, self._image, self._state,
                   seen)
        on, through = int(seen[0]), int(seen[1])
        if inliers >= c.min_inliers or (on >= c.min_overlap * scan.count
                                        and through <= c.max_violations * (on + through)):
            return pose
        loops.rejected_match += 1
        return None

    def _at_edge(self, pose, centre, window) -> bool:
        """The match ended within ``window_margin`` of its box's edge."""
        return beyond_margin(pose, centre, window, self.loops.config.window_margin)

    def close_loop(self, candidate: int, node: int, z) -> bool:
        """Step 3b now: add the loop edge, re-optimise (Eq. 21), and keep the edge only if the
        graph stays consistent; otherwise the graph is left as it was."""
        return _advance(self._close_steps(candidate, node, z), sliced=False)[1]

    def _close_steps(self, candidate: int, node: int, z):
        """Step 3b as a chain of CLOSE slices (a generator returning whether the edge was
        kept): the graph is copied with the edge added and optimised one Gauss–Newton step
        per slice; a consistent result is then written back, with the nodes the front end
        added meanwhile carried along by their edges (docs/runtime.md §3). The edge's old end
        is the candidate's steadiest node (:meth:`LoopCloser.steadiest`, docs/method.md §5,
        step 3), ``z`` re-expressed in its frame."""
        g, trial, loops = self.graph, self.trial, self.loops
        if self.edges_full():
            return False
        steady = loops.steadiest(g, candidate, node)
        if steady != candidate:  # the same place of the map, from a node whose pose fits it
            z = between(compose(g.poses[candidate], z), g.poses[steady])
            candidate = steady
            loops.reanchored += 1
        total_before = g.chi2()
        trial.copy_from(g)
        trial.rescale(trial.scale_target)  # odometry's scale fitted now, judged with the loop
        n, m = g.n_nodes, g.n_edges
        edge = trial.add_edge(candidate, node, z, self.z_info, LOOP)
        try:  # on trial: judged at its full weight; one Gauss–Newton does not absorb is
            # refused without the Levenberg–Marquardt restart (a deadline's worth of steps)
            settled = (yield from self.optimizer.steps(exempt=edge)).converged
        except FactorCapacityError as exc:  # the graph as it was; localising goes on
            self.status = f"capacity reached: {exc}"
            return False
        absorbed, contained = (loops.verdicts(trial, edge, total_before) if settled
                               else (False, False))
        if not (absorbed and (contained or self.widened)):
            # (the graph's own poses: the trial moved none, the front end only adds nodes)
            if not (absorbed and self._agrees(self.rise_refused, candidate, node, z)):
                if settled and not absorbed and not self.widened:
                    if self._agrees(self.strained, candidate, node, z):
                        kept = yield from self._give_up_steps(candidate, node, z)
                        if kept:
                            return True
                    self.strained[:2] = candidate, node
                    self.strained[2:] = z
                    self.strained_info[:] = self.z_info
                loops.rejected_consistency += 1
                if absorbed and not self.widened:  # refused for the rise alone
                    self.rise_refused[:2] = candidate, node
                    self.rise_refused[2:] = z
                return False
            loops.agreed += 1  # kept past the rise by agreeing with the one refused
        self.rise_refused[:2] = -1.0
        if self.edges_full():  # the front end took the last edges meanwhile
            return False
        self._take_trial_poses(n, m)
        g.add_edge(candidate, node, z, self.z_info, LOOP)
        loops.accepted += 1
        self.revision += 1
        if node - candidate >= loops.config.wide_min_gap:  # a closure with the old map
            self.last_closure = node
        return True

    def _agrees(self, refused, candidate: int, node: int, z) -> bool:
        """Whether the loop ``candidate`` → ``node`` (measurement ``z``) agrees with one
        refused before (``refused``: its candidate, node and measurement; the last refused
        for the rise of the total alone, or for its own error): made from a node at most
        ``agreement_nodes`` before ``node``, and placing ``node`` within
        ``agreement_distance`` and ``agreement_angle`` of where this one does, through the
        graph's short chains between the two nodes and between the two candidates. Two scans
        matched apart that put the robot in the same place of the old map are evidence that
        the drift the rise measures is real, or that a kept loop the two contradict is not
        (docs/method.md §5, step 4)."""
        c = self.loops.config
        old, was = int(refused[0]), int(refused[1])
        if old < 0 or self.widened or not 0 < node - was <= c.agreement_nodes:
            return False
        p = self.graph.poses
        there = compose(compose(p[old], refused[2:]), between(p[node], p[was]))
        here = compose(p[candidate], z)
        return bool(math.hypot(here[0] - there[0], here[1] - there[1]) <= c.agreement_distance
                    and abs(wrap_angle(here[2] - there[2])) <= c.agreement_angle)

    def _give_up_steps(self, candidate: int, node: int, z):
        """Two loops the graph could not absorb, the last one refused so (:attr:`strained`)
        and ``candidate`` → ``node`` which agrees with it, tried together (CLOSE slices, a
        generator returning whether both were kept): the kept loop whose error the two raise
        the most (by more than ``min_strain``) is given up and the trial optimised again, up
        to ``max_given_up`` loops, until the graph absorbs both and raises no kept loop's error
        by more than ``chi2_gate``; both are kept when the rest of the graph's total rose by
        at most a consistent constraint's ``total_gate`` each (two the graph absorbs with none
        given up are refused, as each was alone). One wrong closure kept, a
        corner's L matched onto the other L of a corridor's corner, otherwise refuses every
        right closure of the place after it: the map holds the corridor twice
        (docs/method.md §5, step 4)."""
        g, trial, loops = self.graph, self.trial, self.loops
        c = loops.config
        if c.max_given_up <= 0 or g.n_edges + 2 > g.max_edges:
            return False
        n, m = g.n_nodes, g.n_edges
        before = self._chi2_before[:m]
        before[:] = g.edge_chi2()
        total_before = float(np.sum(before))
        trial.copy_from(g)
        trial.rescale(trial.scale_target)
        old = self.strained
        first = trial.add_edge(int(old[0]), int(old[1]), old[2:], self.strained_info, LOOP)
        edge = trial.add_edge(candidate, node, z, self.z_info, LOOP)
        count = 0
        while True:
            try:
                settled = (yield from self.optimizer.steps(exempt=edge)).converged
            except FactorCapacityError as exc:
                self.status = f"capacity reached: {exc}"
                return False
            if not settled:
                return False
            chi2 = trial.edge_chi2()
            strained, strain = -1, c.min_strain
            for k in range(m):  # the kept loop the two strain most (one given up has no Ω)
                if (trial.kind[k] == LOOP and trial.info[k, 2, 2] > 0.0
                        and chi2[k] - before[k] > strain):
                    strained, strain = k, float(chi2[k] - before[k])
            if (chi2[first] <= c.chi2_gate and chi2[edge] <= c.chi2_gate
                    and (strained < 0 or strain <= c.chi2_gate)):
                break
            if strained < 0 or count == c.max_given_up:
                return False
            trial.info[strained] = 0.0
            self._given_up[count] = strained
            count += 1
        given = self._given_up[:count]
        rest = total_before
        for k in given:
            rest -= float(before[k])
        if count == 0 or trial.chi2() - rest > 2.0 * c.total_gate or self.edges_full():
            return False
        self._take_trial_poses(n, m)
        g.remove_edges(given)
        g.add_edge(int(old[0]), int(old[1]), old[2:], self.strained_info, LOOP)
        g.add_edge(candidate, node, z, self.z_info, LOOP)
        loops.accepted += 2
        loops.given_up += count
        self.revision += 1
        self.rise_refused[:2] = -1.0
        self.strained[:2] = -1.0
        if node - candidate >= c.wide_min_gap:
            self.last_closure = node
        return True

    def _take_trial_poses(self, n: int, m: int) -> None:
        """The trial's optimised poses for the graph's first ``n`` nodes; each node the front
        end added since (by edges ``m`` on) keeps its place relative to the node its edge
        comes from, as that node moved."""
        g = self.graph
        old = self._saved_poses[: g.n_nodes]
        old[:] = g.poses[: g.n_nodes]
        g.poses[:n] = self.trial.poses[:n]
        if self.trial.scale != g.scale:  # the trial's edges at its scale, later ones brought to it
            g.z[:m] = self.trial.z[:m]
            g.rescale(self.trial.scale, first=m)
            g.scale = self.trial.scale
        for e in range(m, g.n_edges):
            i, j = int(g.ij[e, 0]), int(g.ij[e, 1])
            if i < j and j >= n:
                g.poses[j] = compose(g.poses[i], between(old[j], old[i]))

    def edges_full(self) -> bool:
        """True (and said in the status) once the edge capacity leaves no room for a loop."""
        if self.graph.n_edges < self.graph.max_edges:
            return False
        self.status = EDGES_FULL_STATUS
        return True

    # ------------------------------------------------------------------ state
    def state(self) -> dict:
        return {
            "matcher": self.matcher.state(),
            "loops": [self.loops.attempts, self.loops.accepted, self.loops.rejected_match,
                      self.loops.rejected_consistency],
            "queue": np.array(self.queued(), np.int64),
            "candidates": self.candidates[: self.n_candidates].copy(),
            "z": self.z.copy(), "z_info": self.z_info.copy(), "cost": self.cost.copy(),
            "wide": self.wide.state(), "guess": self.guess.copy(),
            "widened": self.widened, "last_closure": self.last_closure,
            "wide_from": self.wide_from,
            "failed": self.failed[: self.n_failed].copy(), "failed_node": self.failed_node,
            "failed_revision": self.failed_revision,
            "slices": self.slices.copy(),
            "node": self.node, "phase": self.phase, "next_candidate": self.next_candidate,
            "waited": self.waited, "enqueued": self.enqueued, "searched": self.searched,
            "dropped": self.dropped, "deferred": self.deferred, "forced": self.forced,
            "revision": self.revision, "status": self.status,
            "rise_refused": self.rise_refused.copy(), "agreed": self.loops.agreed,
            "strained": self.strained.copy(), "strained_info": self.strained_info.copy(),
            "given_up": self.loops.given_up, "reanchored": self.loops.reanchored,
        }

    def restore(self, state: dict) -> None:
        queue, cand = state["queue"], state["candidates"]
        if len(queue) > self.queue.shape[0]:
            raise ValueError(f"{len(queue)} queued loop searches exceed the queue capacity "
                             f"{self.queue.shape[0]}")
        if len(cand) > self.candidates.shape[0]:
            raise ValueError(f"{len(cand)} loop candidates exceed max_attempts "
                             f"{self.candidates.shape[0]}")
        n = self.graph.n_nodes
        node = int(state["node"])
        failed = np.asarray(state.get("failed", ()), np.int64)  # older sessions: none
        if (any(not 0 <= int(v) < n for v in (*queue, *cand, *failed)) or not -1 <= node < n
                or len(failed) > self.failed.shape[0]):
            raise ValueError("the loop search refers to nodes that do not exist")
        if (not SELECT <= int(state["phase"]) <= WIDE
                or not 0 <= int(state["next_candidate"]) <= len(cand)):
            raise ValueError("the loop search is in a state it never takes")
        self.matcher.restore(state["matcher"])
        (self.loops.attempts, self.loops.accepted, self.loops.rejected_match,
         self.loops.rejected_consistency) = (int(v) for v in state["loops"])
        self.head, self.size = 0, len(queue)
        self.queue[: self.size] = queue
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
        self.wide_from = int(state.get("wide_from", 0))  # older sessions: none kept
        self.n_failed = len(failed)
        self.failed[: self.n_failed] = failed
        self.failed_node = int(state.get("failed_node", -1))
        self.failed_revision = int(state.get("failed_revision", -1))
        self.node = node
        (self.phase, self.next_candidate, self.waited, self.enqueued, self.searched,
         self.dropped, self.deferred, self.forced, self.revision) = (
            int(state[k]) for k in ("phase", "next_candidate", "waited", "enqueued", "searched",
                                    "dropped", "deferred", "forced", "revision"))
        self.status = str(state["status"])
        refused = np.asarray(state.get("rise_refused", [-1.0, -1.0, 0.0, 0.0, 0.0]), np.float64)
        if (refused.shape != (5,) or not np.all(np.isfinite(refused))
                or not -1 <= refused[0] < n or not -1 <= refused[1] < n):
            raise ValueError("the loop refused for its rise refers to nodes that do not exist")
        self.rise_refused[:] = refused
        self.loops.agreed = int(state.get("agreed", 0))
        # (saved before a strained loop was kept: none)
        strained = np.asarray(state.get("strained", [-1.0, -1.0, 0.0, 0.0, 0.0]), np.float64)
        info = np.asarray(state.get("strained_info", np.zeros((3, 3))), np.float64)
        if (strained.shape != (5,) or info.shape != (3, 3) or not np.all(np.isfinite(strained))
                or not np.all(np.isfinite(info)) or not -1 <= strained[0] < n
                or not -1 <= strained[1] < n):
            raise ValueError("the loop refused for its own error refers to nodes that do not "
                             "exist")
        self.strained[:], self.strained_info[:] = strained, info
        self.loops.given_up = int(state.get("given_up", 0))
        self.loops.reanchored = int(state.get("reanchored", 0))  # (0: saved before the rule)


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
