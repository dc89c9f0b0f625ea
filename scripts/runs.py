"""How a run starts, shared by ``replay`` and ``lidar``: one options object, and one way to
open the runtime for a new run, a run localized in a saved session, or a resumed one.

    runtime = open_runtime(RunOptions(seed=1), SlamConfig())    # a new map, seed 1
    later = RunOptions(localize="out/session.npz")      # to localize in a map saved there

A saved session carries its own configuration: a localized or resumed run takes it, changed
only by ``session_changes`` (its search and tracking, :data:`SESSION_SECTIONS`), and a run
that gives both a configuration and a session is refused, with one message wherever it
comes from.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from swarmslam.runtime.config import SESSION_SECTIONS, SensorConfig, SlamConfig, override
from swarmslam.runtime.realtime.fixed_rate import SlamRuntime

SESSION_TAKES_ITS_CONFIGURATION = (
    "a localized or resumed run takes the configuration saved in its session; drop --preset "
    f"and the configuration (--config may change only its {', '.join(SESSION_SECTIONS)})")


@dataclass(frozen=True)
class RunOptions:
    """What starts a run, whatever feeds it scans.

    ``config``: a new run's whole configuration (None: the command's default). ``optimizer``
    overrides its swarm method, ``schedule`` its runtime schedule (None: the command's), and
    ``seed`` seeds a new run (a session's run keeps the session's seed and swarm method).
    ``localize`` / ``resume``: a session file to localize in (its map never changed) or to
    extend from wherever the run starts in it; at most one. ``session_changes``: what they
    change of the session's configuration.
    """

    config: SlamConfig | None = None
    optimizer: str | None = None
    seed: int = 0
    schedule: str | None = None
    localize: str | Path | None = None
    resume: str | Path | None = None
    session_changes: dict | None = None

    def __post_init__(self):
        if self.localize is not None and self.resume is not None:
            raise ValueError("localize in a session or resume it, not both")
        if self.session is not None and self.config is not None:
            raise ValueError(SESSION_TAKES_ITS_CONFIGURATION)
        if self.session is not None and self.optimizer is not None:
            # the swarm's state is saved with the session, sized for its own method
            raise ValueError("a localized or resumed run keeps its session's swarm method; "
                             "drop --optimizer")

    @property
    def session(self) -> str | Path | None:
        """The saved session the run starts from, if any."""
        return self.localize if self.localize is not None else self.resume


def open_runtime(options: RunOptions, config: SlamConfig | None, changes: dict | None = None,
                 sensor: SensorConfig | None = None, scans: int = 0) -> SlamRuntime:
    """The runtime ``options`` start, with ``changes`` (dotted fields the command itself
    sets: the schedule, the tick rate) and ``options``' optimizer and schedule applied: new
    from ``config`` (the command's, made from ``options.config``; unused for a session's
    run), or from the saved session's configuration with ``options.session_changes`` too.
    ``sensor``: the scanner now feeding it, where it may not be the session's. ``scans``: how
    many scans the run brings (a localized run's trajectory is sized for them, a resumed one
    grows by them)."""
    given = {"matcher.swarm.optimizer": options.optimizer, "runtime.schedule": options.schedule}
    changes = {**{k: v for k, v in given.items() if v is not None}, **(changes or {})}
    if options.session is None:
        return SlamRuntime(override(config, changes) if changes else config, seed=options.seed)
    changes = {**(options.session_changes or {}), **changes}  # (the optimizer: refused above)
    if options.localize is not None:
        if scans:
            changes["capacity.max_scans"] = scans
        return SlamRuntime.localize(options.localize, changes=changes, sensor=sensor)
    return SlamRuntime.resume(options.resume, anywhere=True, changes=changes, sensor=sensor,
                              more_scans=scans)
