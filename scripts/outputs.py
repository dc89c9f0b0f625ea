"""What a SLAM run leaves behind, each file written atomically: the map (PGM + YAML for ROS
map_server, and PNG), the trajectory of every scan (TUM, for ``evo``) and the pose graph
(g2o). docs/formats.md describes each."""

from __future__ import annotations

from pathlib import Path

from runtime.slam import GraphSlam
from scripts.g2o import write_g2o
from scripts.map_io import write_map
from scripts.tum import write_tum

RESULT_FILES = ("map.pgm", "map.yaml", "map.png", "trajectory.tum", "graph.g2o")


def write_results(slam: GraphSlam, out_dir) -> None:
    """The map, the trajectory and the pose graph of ``slam`` into ``out_dir``."""
    out = Path(out_dir)
    write_map(out / "map", slam.global_map())
    write_tum(out / "trajectory.tum", *slam.trajectory())
    write_g2o(out / "graph.g2o", slam.graph)
