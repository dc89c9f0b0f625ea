"""The run in rerun: a live viewer (``--view``) and/or a recording (``--record FILE.rrd``).

Entities (map frame, metres, z = 0):

- ``world/map``: the occupancy map (``GridMap``; white free, black occupied, grey unknown)
- ``world/scan``: the current scan placed at the SLAM's pose; ``world/robot``: the pose
- ``world/trajectory`` (estimated), ``world/truth`` (the simulator's true path)
- ``world/graph/nodes``, ``world/graph/edges`` (tracking), ``world/graph/loops`` (closures, red)
- ``stats/latency_ms``, ``stats/evaluations``, ``stats/lambda``, ``stats/rejection_threshold``,
  ``stats/pose_error_m`` (where the truth is known)

Timelines: ``tick`` (sequence) and ``time`` (the scans' clock, from the first scan).
Without a display ``--view`` serves the web viewer and says where to open it: on rerun's usual
ports (gRPC 9876, web 9090), or on ports the system has free when another run holds those.
"""

from __future__ import annotations

import os
import socket
import sys
import threading

import numpy as np
import rerun as rr

from swarmslam.runtime.pose import compose
from swarmslam.runtime.pose_graph import ODOMETRY
from swarmslam.runtime.realtime.writers import AtomicFile
from swarmslam.view.map_painter import map_nodes

APP = "swarmslam"
GRPC_PORT, WEB_PORT = 9876, 9090  # rerun's own defaults: what its users expect to open


def free_port(preferred: int) -> int:
    """``preferred`` if nothing holds it on any interface, else a port the system has free
    (a second viewed run then serves beside the first instead of failing to listen and
    pointing at the first run's viewer)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        try:
            probe.bind(("0.0.0.0", preferred))
        except OSError:
            probe.bind(("0.0.0.0", 0))
        return probe.getsockname()[1]


def has_display() -> bool:
    return sys.platform in ("darwin", "win32") or bool(
        os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def _xyz(xy) -> np.ndarray:
    xy = np.asarray(xy, np.float64).reshape(-1, 2)
    return np.c_[xy, np.zeros(len(xy))]


class RerunView:
    def __init__(self, view: bool = False, record=None, echo=print):
        self.rec = rr.RecordingStream(APP)
        sinks = []
        if view and has_display():
            self.rec.spawn(connect=False)
            sinks.append(rr.GrpcSink())
            echo("rerun: viewer spawned")
        elif view:
            server = rr.GrpcServerSink(port=free_port(GRPC_PORT))
            sinks.append(server)
        # the recording appears complete at ``record`` when the run ends (written beside it)
        self.record = AtomicFile(record) if record else None
        if self.record is not None:
            sinks.append(rr.FileSink(self.record.tmp))
        self.rec.set_sinks(*sinks)
        if view and not has_display():
            web_port = free_port(WEB_PORT)
            rr.serve_web_viewer(web_port=web_port, open_browser=False, connect_to=server.uri)
            uri = server.uri.replace("0.0.0.0", "localhost")
            echo(f"rerun: no display here; open http://localhost:{web_port}/?url={uri} in a "
                 f"browser (from another machine: its address for localhost), or run "
                 f"`rerun {uri}`")
        self.serving = bool(view and not has_display())
        self.echo = echo
        self.first_stamp = None
        self.truth: list[np.ndarray] = []
        self.rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)

    def _time(self, tick: int, stamp: float) -> None:
        if self.first_stamp is None:
            self.first_stamp = stamp
        self.rec.set_time("tick", sequence=tick)
        self.rec.set_time("time", duration=stamp - self.first_stamp)

    def frame(self, tick: int, f) -> None:
        rec = self.rec
        self._time(tick, f.stamp)
        if np.all(np.isfinite(f.pose)):
            world = compose(f.pose, np.c_[f.points, np.zeros(len(f.points))])[:, :2]
            rec.log("world/scan", rr.Points3D(_xyz(world), radii=0.03, colors=[255, 120, 0]))
            heading = 0.5 * np.array([[np.cos(f.pose[2]), np.sin(f.pose[2]), 0.0]])
            rec.log("world/robot", rr.Arrows3D(origins=_xyz(f.pose[:2]), vectors=heading,
                                                colors=[220, 30, 30]))
        rec.log("stats/latency_ms", rr.Scalars(f.latency_ms))
        rec.log("stats/evaluations", rr.Scalars(float(f.evaluations)))
        if np.isfinite(f.error):
            rec.log("stats/lambda", rr.Scalars(f.error))
        if np.isfinite(f.rejection_threshold):
            rec.log("stats/rejection_threshold", rr.Scalars(f.rejection_threshold))
        if f.truth is not None:
            self.truth.append(f.truth[:2].copy())
            if np.all(np.isfinite(f.pose)):
                rec.log("stats/pose_error_m",
                        rr.Scalars(float(np.hypot(*(f.pose[:2] - f.truth[:2])))))

    def map(self, tick: int, stamp: float, painted, slam) -> None:
        """The redrawn map (a :class:`swarmslam.view.map_painter.PaintedMap`), the graph and the
        trajectories (each redraw, not each tick)."""
        rec = self.rec
        self._time(tick, stamp)
        grid = painted.grid
        image = painted.trinary  # row 0 at the lowest y: GridMap's lower-left origin
        h, w = image.shape
        rec.log("world/map", rr.GridMap(
            data=np.ascontiguousarray(image).tobytes(),
            format=rr.components.ImageFormat(width=w, height=h, color_model="L",
                                             channel_datatype="U8"),
            cell_size=grid.resolution, translation=[grid.origin[0], grid.origin[1], -0.01]))
        self.trajectory(tick, stamp, slam)
        self._graph(slam)

    def trajectory(self, tick: int, stamp: float, slam) -> None:
        """The estimated path (as optimised so far) and the true one."""
        rec = self.rec
        self._time(tick, stamp)
        _, poses = slam.trajectory()
        poses = poses[np.all(np.isfinite(poses), axis=1)]
        if len(poses) > 1:
            rec.log("world/trajectory", rr.LineStrips3D([_xyz(poses[:, :2])], radii=0.02,
                                                        colors=[30, 90, 230]))
        if len(self.truth) > 1:
            rec.log("world/truth", rr.LineStrips3D([_xyz(np.array(self.truth))], radii=0.02,
                                                   colors=[40, 170, 60]))

    def _graph(self, slam) -> None:
        node_poses, _, n, _ = map_nodes(slam)
        rec = self.rec
        rec.log("world/graph/nodes", rr.Points3D(_xyz(node_poses[:n, :2]), radii=0.05,
                                                 colors=[90, 90, 90]))
        graph = getattr(slam, "graph", None)
        if graph is None or getattr(slam, "saved", None) is not None:
            return
        ij, kind = graph.ij[: graph.n_edges], graph.kind[: graph.n_edges]
        for name, chosen, color in (("edges", kind == ODOMETRY, [150, 150, 150]),
                                    ("loops", kind != ODOMETRY, [230, 20, 20])):
            segments = [_xyz(node_poses[list(e), :2]) for e in ij[chosen]]
            rec.log(f"world/graph/{name}", rr.LineStrips3D(segments, radii=0.015, colors=color))

    def close(self) -> None:
        self.rec.flush()
        if self.serving and sys.stdin.isatty():  # the served data goes when the process does
            self.echo("rerun: the run is over; the viewer is served until Ctrl-C")
            try:
                threading.Event().wait()
            except KeyboardInterrupt:
                pass
        self.rec.disconnect()  # closes the file sink
        if self.record is not None:
            self.record.commit()
