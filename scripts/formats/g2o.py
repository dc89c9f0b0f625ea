"""2-D pose graphs in g2o's text format: ``VERTEX_SE2 id x y θ`` and
``EDGE_SE2 i j dx dy dθ I11 I12 I13 I22 I23 I33`` (upper triangle of the information matrix).

Vertex ids may be any integers; they are mapped to consecutive node indices in file order.
``FIX id`` lines are accepted (the optimizer always fixes the first pose).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from swarmslam.runtime.pose_graph import LOOP, ODOMETRY, PoseGraph
from swarmslam.runtime.realtime.text_records import DataFormatError, parse_numbers, records
from swarmslam.runtime.realtime.writers import write_text_atomic


class G2oFormatError(DataFormatError):
    pass


_EDGE_FIELDS = ("i", "j", "dx", "dy", "dtheta", "I11", "I12", "I13", "I22", "I23", "I33")


def _vertex_id(path, lineno: int, name: str, value: float) -> int:
    """A vertex id: a whole number (g2o ids are integers; 1.5 would alias vertex 1)."""
    if value != int(value) or abs(value) >= 2**62:
        raise G2oFormatError(path, lineno, name, f"vertex ids are integers, got {value!r}")
    return int(value)


def read_g2o(path, extra_nodes: int = 0, extra_edges: int = 0) -> tuple[PoseGraph, list]:
    """The graph and the original vertex ids (index → id)."""
    path = Path(path)
    ids: dict[int, int] = {}
    poses, edges = [], []
    for lineno, tokens in records(path):
        tag = tokens[0]
        if tag == "VERTEX_SE2":
            vid, x, y, t = parse_numbers(path, lineno, ("id", "x", "y", "theta"), tokens[1:],
                                         G2oFormatError)
            vid = _vertex_id(path, lineno, "id", vid)
            if vid in ids:
                raise G2oFormatError(path, lineno, "id", f"vertex {int(vid)} defined twice")
            ids[int(vid)] = len(poses)
            poses.append((x, y, t))
        elif tag == "EDGE_SE2":
            edges.append((lineno, parse_numbers(path, lineno, _EDGE_FIELDS, tokens[1:],
                                                G2oFormatError)))
        elif tag != "FIX":
            raise G2oFormatError(path, lineno, "tag", f"unsupported element {tag!r}")
    n_e = len(edges)
    ij = np.zeros((n_e, 2), np.int64)
    z = np.zeros((n_e, 3))
    info = np.zeros((n_e, 3, 3))
    kind = np.zeros(n_e, np.int8)
    for k, (lineno, v) in enumerate(edges):
        for col, name in ((0, "i"), (1, "j")):
            if _vertex_id(path, lineno, name, v[col]) not in ids:
                raise G2oFormatError(path, lineno, name, f"unknown vertex {int(v[col])}")
        ij[k] = (ids[int(v[0])], ids[int(v[1])])
        z[k] = v[2:5]
        i11, i12, i13, i22, i23, i33 = v[5:]
        info[k] = [[i11, i12, i13], [i12, i22, i23], [i13, i23, i33]]
        kind[k] = ODOMETRY if abs(int(v[1]) - int(v[0])) == 1 else LOOP
    graph = PoseGraph.from_arrays(poses, ij, z, info, kind,
                                  max_nodes=len(poses) + extra_nodes,
                                  max_edges=n_e + extra_edges)
    inverse = [0] * len(ids)
    for vid, idx in ids.items():
        inverse[idx] = vid
    return graph, inverse


def g2o_text(graph: PoseGraph, ids=None) -> str:
    ids = ids if ids is not None else range(graph.n_nodes)
    lines = [f"VERTEX_SE2 {ids[k]} {x:.9g} {y:.9g} {t:.9g}"
             for k, (x, y, t) in enumerate(graph.poses[: graph.n_nodes])]
    for k in range(graph.n_edges):
        i, j = graph.ij[k]
        m = graph.info[k]
        dx, dy, dt = graph.z[k]
        lines.append(
            f"EDGE_SE2 {ids[i]} {ids[j]} {dx:.9g} {dy:.9g} {dt:.9g} "
            f"{m[0, 0]:.9g} {m[0, 1]:.9g} {m[0, 2]:.9g} {m[1, 1]:.9g} {m[1, 2]:.9g} {m[2, 2]:.9g}"
        )
    if graph.n_nodes:
        lines.append(f"FIX {ids[0]}")
    return "\n".join(lines) + "\n"


def write_g2o(path, graph: PoseGraph, ids=None):
    return write_text_atomic(path, g2o_text(graph, ids))
