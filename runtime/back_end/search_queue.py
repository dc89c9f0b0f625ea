"""The back end's bookkeeping between searches: the queue of nodes awaiting their loop search,
and the candidates whose match failed for the node searched last."""

from __future__ import annotations

import numpy as np


class SearchQueue:
    """Nodes awaiting their loop search, oldest first, in a ring of fixed capacity: a full
    ring drops its oldest node's search (counted by the caller, which :meth:`push` tells)."""

    def __init__(self, capacity: int):
        self.nodes = np.zeros(capacity, np.int64)
        self.head = 0  # index of the oldest queued node
        self.size = 0

    def push(self, node: int) -> bool:
        """Queue ``node``; True if the oldest search was dropped to make room."""
        cap = self.nodes.shape[0]
        dropped = self.size == cap
        if dropped:
            self.head = (self.head + 1) % cap
            self.size -= 1
        self.nodes[(self.head + self.size) % cap] = node
        self.size += 1
        return dropped

    def pop(self) -> int:
        """The oldest queued node, taken off the queue."""
        node = int(self.nodes[self.head])
        self.head = (self.head + 1) % self.nodes.shape[0]
        self.size -= 1
        return node

    def queued(self) -> list[int]:
        cap = self.nodes.shape[0]
        return [int(self.nodes[(self.head + k) % cap]) for k in range(self.size)]

    def restore(self, queued) -> None:
        if len(queued) > self.nodes.shape[0]:
            raise ValueError(f"{len(queued)} queued loop searches exceed the queue capacity "
                             f"{self.nodes.shape[0]}")
        self.head, self.size = 0, len(queued)
        self.nodes[: self.size] = queued


class FailedMatches:
    """The candidates whose match failed for the node searched last, with the graph at one
    revision. Half a metre on, against the same submap, such a match mostly fails again: the
    next node's search passes over them while the graph is unchanged, and its attempts go to
    the next candidates (docs/method.md §5, step 3)."""

    def __init__(self, capacity: int):
        self.failed = np.zeros(capacity, np.int64)
        self.n_failed = 0
        self.node = -1  # the node whose search they failed for
        self.revision = -1  # the graph's revision then

    def take_untried(self, found, node: int, revision: int, out: np.ndarray) -> int:
        """The first of ``found`` into ``out`` (at most its length), passing over those that
        failed for ``node - 1`` at this ``revision``; then forgets them, to record ``node``'s
        own. Returns how many were taken."""
        repeat = self.node == node - 1 and self.revision == revision
        n = 0
        for candidate in found:
            if n == out.shape[0]:
                break
            if repeat and candidate in self.failed[: self.n_failed]:
                continue
            out[n] = candidate
            n += 1
        self.node, self.revision, self.n_failed = node, revision, 0
        return n

    def add(self, candidate: int) -> None:
        """``candidate``'s match failed (past the capacity: not remembered)."""
        if self.n_failed < self.failed.shape[0]:
            self.failed[self.n_failed] = candidate
            self.n_failed += 1

    def state(self) -> dict:
        return {"failed": self.failed[: self.n_failed].copy(), "failed_node": self.node,
                "failed_revision": self.revision}

    def restore(self, state: dict, n_nodes: int) -> None:
        failed = np.asarray(state["failed"], np.int64)
        if len(failed) > self.failed.shape[0] or any(not 0 <= int(v) < n_nodes for v in failed):
            raise ValueError("the loop search refers to nodes that do not exist")
        self.n_failed = len(failed)
        self.failed[: self.n_failed] = failed
        self.node = int(state["failed_node"])
        self.revision = int(state["failed_revision"])
