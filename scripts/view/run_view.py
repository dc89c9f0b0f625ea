"""Watching a run as it happens: ``--view`` and ``--record FILE.rrd`` (rerun) and ``--mcap FILE``
(Foxglove), shared by ``demo``, ``replay`` and ``lidar``.

The loop that drives the SLAM hands each tick's :class:`Frame` to :meth:`RunWatch.tick` *after*
the tick: nothing here runs inside the runtime's budget or changes the SLAM's state, so results
are identical with and without it. The map is redrawn a few nodes per tick
(:class:`swarmslam.view.map_painter.MapPainter`) and sent when a redraw completes.

rerun, mcap: optional extras (``pip install -e ".[view]"``); asking for a view without them is a
clear error before the run starts.
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass

import numpy as np

from swarmslam.view.map_painter import MapPainter


@dataclass
class Frame:
    """One tick as a viewer sees it."""

    stamp: float  # s, the scan's time
    pose: np.ndarray  # the SLAM's pose of the scan (map frame); NaN while not localized
    points: np.ndarray  # the scan, robot frame, (n, 2)
    latency_ms: float  # the tick's time
    node_added: bool = False
    loop_closed: bool = False
    error: float = float("nan")  # λ of the front end's match
    rejection_threshold: float = float("nan")
    evaluations: int = 0  # the swarm's objective evaluations this tick
    truth: np.ndarray | None = None  # the true pose, where known (simulator)


def frame_of(runtime, result, points, stamp: float, latency_s: float, truth=None) -> Frame:
    """The :class:`Frame` of a :class:`swarmslam.runtime.realtime.fixed_rate.SlamRuntime` tick that gave
    ``result`` (a :class:`swarmslam.runtime.step_result.StepResult`) for the scan ``points``."""
    slam = runtime.slam
    front_end = getattr(slam, "front_end", None)  # mapping; a localizer has none
    threshold = front_end.matcher.threshold.rejection_threshold if front_end else float("nan")
    return Frame(
        stamp=float(stamp), pose=np.array(result.pose, np.float64), points=points,
        latency_ms=1e3 * latency_s, node_added=bool(result.node_added),
        loop_closed=bool(result.loop_closed), error=float(result.error),
        rejection_threshold=float(threshold),
        evaluations=int(front_end.evaluations) if front_end else 0,
        truth=None if truth is None else np.asarray(truth, np.float64))


def require_extra(module: str, option: str) -> None:
    if importlib.util.find_spec(module) is None:
        raise ValueError(f"{option} needs the '{module}' package: pip install -e \".[view]\"")


class RunWatch:
    """The viewers of one run (any of: a live rerun view, an .rrd recording, an MCAP file),
    opened at the first tick, when the runtime's configuration is known."""

    def __init__(self, view: bool = False, record=None, mcap=None, echo=print,
                 nodes_per_tick: int = 40, refresh_seconds: float = 2.0):
        """``nodes_per_tick``: node scans drawn into the next map per tick;
        ``refresh_seconds``: of scan time between map redraws (and paths), which bounds a
        recording's size."""
        if view or record:
            require_extra("rerun", "--view/--record")
        if mcap:
            require_extra("mcap", "--mcap")
        self.view, self.record, self.mcap, self.echo = view, record, mcap, echo
        self.nodes_per_tick, self.refresh_seconds = nodes_per_tick, refresh_seconds
        self._refreshed = -np.inf  # scan time of the last refresh
        self.sinks = None
        self.painter = None
        self.ticks = 0

    @classmethod
    def from_args(cls, args, echo=print) -> RunWatch | None:
        """From a command's ``--view``/``--record``/``--mcap`` options; None when none is set."""
        view, record = getattr(args, "view", False), getattr(args, "record", None)
        mcap = getattr(args, "mcap", None)
        if not (view or record or mcap):
            return None
        return cls(view=view, record=record, mcap=mcap, echo=echo)

    def _open(self, config) -> None:
        self.sinks = []
        if self.view or self.record:
            from swarmslam.view.rerun_view import RerunView  # optional extra, imported only when asked

            self.sinks.append(RerunView(view=self.view, record=self.record, echo=self.echo))
        if self.mcap:
            from swarmslam.view.mcap_recording import McapRecording

            self.sinks.append(McapRecording(self.mcap, config.sensor.max_points))
        self.painter = MapPainter(config.map, self.nodes_per_tick)

    def tick(self, runtime, frame: Frame) -> None:
        """After a tick: the frame to every viewer, and the map and graph when redrawn."""
        if self.sinks is None:
            self._open(runtime.config)
        self.ticks += 1
        due = frame.stamp - self._refreshed >= self.refresh_seconds
        painted = None
        if due or self.painter.busy:
            painted = self.painter.paint(runtime.slam)  # a new pass starts if the graph changed
            if due:
                self._refreshed = frame.stamp
        for sink in self.sinks:
            sink.frame(self.ticks, frame)
            if painted is not None:
                sink.map(self.ticks, frame.stamp, painted, runtime.slam)
            elif due and hasattr(sink, "trajectory"):  # paths move without a redraw too
                sink.trajectory(self.ticks, frame.stamp, runtime.slam)

    def close(self) -> None:
        """Finish the recordings (also after an error: what was recorded is kept)."""
        for sink in self.sinks or ():
            sink.close()
        self.sinks = []
