"""Loop verification: a loop edge on trial in a copy of the graph (Alg. 7, step 3b, and the
consistency test of step 4; docs/method.md §5, docs/runtime.md §3).

    kept = yield from trial.steps(candidate, node, z, info, widened)   # CLOSE slices

The graph is copied with the edge added and optimised one Gauss–Newton step per slice, the
front end adding nodes to the graph itself meanwhile. A consistent result is written back, with
the nodes added meanwhile carried along by their edges; otherwise the graph is left as it was,
and the refusal is remembered (:class:`VerdictMemory`): a later loop that agrees with it may be
kept past the test that refused it, or, with the loops refused before that it agrees with, as a
group judged by its joint error, in place of the kept loops the group strains most.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2 as chi_squared

from swarmslam.runtime.config import SlamConfig
from swarmslam.runtime.back_end.graph_optimizer import GaussNewton
from swarmslam.runtime.back_end.loop_closure import GROUP, LoopCloser, VerdictMemory
from swarmslam.runtime.pose import between, compose
from swarmslam.runtime.pose_graph import LOOP, PoseGraph
from swarmslam.runtime.back_end.sparse_ldl import FactorCapacityError

EDGES_FULL_STATUS = "capacity reached: no more loop closures"
# A kept loop is given up for a group that agrees only when it raises its eᵀΩe by more than this.
MIN_STRAIN = 1.0


class ClosureTrial:
    def __init__(self, config: SlamConfig, graph: PoseGraph, loops: LoopCloser):
        self.graph, self.loops = graph, loops
        self.trial = PoseGraph(graph.max_nodes, graph.max_edges)
        self.optimizer = GaussNewton(self.trial, config.optimizer)
        self.memory = VerdictMemory(config.loop_closure)
        self._saved_poses = np.zeros((graph.max_nodes, 3))
        self._chi2_before = np.zeros(graph.max_edges)
        self._given_up = np.zeros(max(config.loop_closure.agreement.max_given_up, 1), np.int64)
        # χ² at 3·k degrees of freedom, at the level of a consistent loop's total_gate (χ²₃),
        # for a group of k loops
        level = chi_squared.cdf(config.loop_closure.total_gate, 3)
        self.joint_gate = np.array([chi_squared.ppf(level, 3 * k) for k in range(GROUP + 1)])
        self.status = "ok"

    def edges_full(self) -> bool:
        """True (and said in the status) once the edge capacity leaves no room for a loop."""
        if self.graph.n_edges < self.graph.max_edges:
            return False
        self.status = EDGES_FULL_STATUS
        return True

    def steps(self, candidate: int, node: int, z, info, widened: bool):
        """The trial of the loop ``candidate`` → ``node`` (measurement ``z``, information
        ``info``; ``widened``: a wide search's proposal) as a chain of CLOSE slices: a
        generator returning the kept edge's old end, −1 when it was refused. The edge's old end
        is the candidate's steadiest node (:meth:`LoopCloser.steadiest`, docs/method.md §5,
        step 3), ``z`` re-expressed in its frame."""
        g, trial, loops, memory = self.graph, self.trial, self.loops, self.memory
        if self.edges_full():
            return -1
        steady = loops.steadiest(g, candidate, node)
        if steady != candidate:  # the same place of the map, from a node whose pose fits it
            z = between(compose(g.poses[candidate], z), g.poses[steady])
            candidate = steady
            loops.counts.reanchored += 1
        total_before = g.chi2()
        trial.copy_from(g)
        trial.rescale(trial.scale_target)  # odometry's scale fitted now, judged with the loop
        n, m = g.n_nodes, g.n_edges
        edge = trial.add_edge(candidate, node, z, info, LOOP)
        try:  # on trial: judged at its full weight; one Gauss–Newton does not absorb is
            # refused without the Levenberg–Marquardt restart (a deadline's worth of steps)
            settled = (yield from self.optimizer.steps(exempt=edge)).converged
        except FactorCapacityError as exc:  # the graph as it was; localising goes on
            self.status = f"capacity reached: {exc}"
            return -1
        absorbed, contained = (loops.verdicts(trial, edge, total_before) if settled
                               else (False, False))
        if not (absorbed and (contained or widened)):
            # (the graph's own poses: the trial moved none, the front end only adds nodes)
            if not (absorbed and not widened
                    and memory.agrees(memory.rise_refused, g, candidate, node, z)):
                if settled and not absorbed:
                    group = memory.agreeing(g, candidate, node, z)
                    if len(group):
                        kept = yield from self._group_steps(group, candidate, node, z, info,
                                                            widened)
                        if kept >= 0:
                            return kept
                    memory.strain(candidate, node, z, info)
                loops.counts.rejected_consistency += 1
                if absorbed and not widened:  # refused for the rise alone
                    memory.remember(memory.rise_refused, candidate, node, z)
                return -1
            loops.counts.agreed += 1  # kept past the rise by agreeing with the one refused
        memory.rise_refused[:2] = -1.0
        if self.edges_full():  # the front end took the last edges meanwhile
            return -1
        self._take_trial_poses(n, m)
        g.add_edge(candidate, node, z, info, LOOP)
        loops.counts.accepted += 1
        return candidate

    def _group_steps(self, group, candidate: int, node: int, z, info, widened: bool):
        """The loop ``candidate`` → ``node`` the graph could not absorb, tried with the loops
        refused so before that it agrees with (``group``: rows of
        :attr:`VerdictMemory.strained`; CLOSE slices, a generator returning the old end, −1
        unless all were kept). The group is kept when its joint error passes χ² at its degrees
        of freedom (3 a loop) at ``total_gate``'s level: consistent evidence from several
        matches in a row that no single one gives. Until it does, and until no kept loop's
        error rises by more than ``chi2_gate`` and the rest of the graph's total by at most a
        consistent constraint's ``total_gate`` a loop (unless the newest is a wide proposal,
        judged, as one alone is, without the rise), the kept loop whose error the group raises
        the most (by more than ``MIN_STRAIN``) is given up and the trial optimised again, up to
        ``agreement.max_given_up`` loops. One wrong closure kept, a corner's L matched onto the
        other L of a corridor's corner, otherwise refuses every right closure of the place
        after it: the map holds the corridor twice."""
        g, trial, loops, memory = self.graph, self.trial, self.loops, self.memory
        c, most = loops.config, loops.config.agreement.max_given_up
        size = len(group) + 1
        if g.n_edges + size > g.max_edges:
            return -1
        n, m = g.n_nodes, g.n_edges
        before = self._chi2_before[:m]
        before[:] = g.edge_chi2()
        total_before = float(np.sum(before))
        trial.copy_from(g)
        trial.rescale(trial.scale_target)
        self._add_group(trial, group, candidate, node, z, info)
        count = 0
        while True:
            try:  # the whole group exempt from the robust kernel: judged at its full weight
                settled = (yield from self.optimizer.steps(exempt=m)).converged
            except FactorCapacityError as exc:
                self.status = f"capacity reached: {exc}"
                return -1
            if not settled:
                return -1
            chi2 = trial.edge_chi2()
            strained, strain = -1, MIN_STRAIN
            for k in range(m):  # the kept loop the group strains most (one given up has no Ω)
                if (trial.kind[k] == LOOP and trial.info[k, 2, 2] > 0.0
                        and chi2[k] - before[k] > strain):
                    strained, strain = k, float(chi2[k] - before[k])
            rise = float(np.sum(chi2)) - total_before
            for k in self._given_up[:count]:
                rise += float(before[k])
            if (float(np.sum(chi2[m:m + size])) <= self.joint_gate[size]
                    and (strained < 0 or strain <= c.chi2_gate)
                    and (widened or rise <= size * c.total_gate)):
                break
            if strained < 0 or count == most:
                return -1
            trial.info[strained] = 0.0
            self._given_up[count] = strained
            count += 1
        given = self._given_up[:count]
        if self.edges_full():
            return -1
        self._take_trial_poses(n, m)
        g.remove_edges(given)
        self._add_group(g, group, candidate, node, z, info)
        loops.counts.accepted += size
        loops.counts.given_up += count
        memory.rise_refused[:2] = -1.0
        memory.forget_strained()
        return candidate

    def _add_group(self, graph: PoseGraph, group, candidate: int, node: int, z, info) -> None:
        """The group's loop edges added to ``graph``: the remembered ones, oldest first, then
        the newest."""
        strained, strained_info = self.memory.strained, self.memory.strained_info
        for row in group[::-1]:
            graph.add_edge(int(strained[row, 0]), int(strained[row, 1]), strained[row, 2:],
                           strained_info[row], LOOP)
        graph.add_edge(candidate, node, z, info, LOOP)

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
