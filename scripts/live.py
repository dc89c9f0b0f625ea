"""``swarmslam lidar``: live SLAM from a scanner on a serial port, at a fixed rate.

The driver's reader thread hands each whole rotation to the runtime's inbox; the runtime
ticks at ``rate_hz`` in this thread; a status line shows the scan rate, the pose, the tick
latency and the error counts once a second. On Ctrl-C (or after ``seconds``) it stops the
scanner and writes, atomically, the map (PGM + YAML for ROS map_server, and PNG), the
trajectory (TUM), the pose graph (g2o), a session file (``--resume`` extends it from wherever
the robot then starts) and ``summary.json``; with ``--localize`` only the trajectory and
``summary.json`` (the saved map is never changed).
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

from swarmslam.hardware.driver import RPLidar
from swarmslam.hardware.models import MODELS
from swarmslam.hardware.models import model as get_model
from swarmslam.runtime.config import SlamConfig, override, preset
from swarmslam.runtime.realtime.fixed_rate import SlamRuntime
from swarmslam.runtime.realtime.writers import write_json_atomic
from swarmslam.formats.bags import BagError, BagRecorder
from swarmslam.outputs import (UNUSABLE_REPORT, check_input_kept, check_writable, clean_stale,
                               output_set, report_beside, write_results)
from swarmslam.view.run_view import frame_of
from swarmslam.formats.tum import write_tum
from swarmslam.runs import RunOptions, open_runtime


def slam_config_for(model_name: str, rate_hz: float | None = None) -> SlamConfig:
    """The model's preset (stored scans sized for its samples per rotation, its range), at
    ``rate_hz`` ticks per second if given."""
    config = preset(f"rplidar-{get_model(model_name).name}")
    return config if rate_hz is None else override(config, {"runtime.rate_hz": rate_hz})


def run_live(port: str, model: str = "a1", mode: str = "typical", out_dir="swarmslam-live",
             rate_hz: float | None = None, seconds: float | None = None,
             options: RunOptions | None = None, echo=print,
             stop: threading.Event | None = None, watch=None, baud: int | None = None,
             bag=None) -> dict:
    """``options``: how the run starts (:class:`swarmslam.runs.RunOptions`): a new map with
    its configuration (default: the model's preset), resuming a session from wherever the
    scanner is in its map (found first), or localizing in one, never changed. ``rate_hz``
    overrides the tick rate, a session's too. ``watch``: a
    :class:`swarmslam.view.run_view.RunWatch` shown after every tick that took a scan.
    ``baud``: a rate to switch the link to after connecting (where the model allows).
    ``bag``: a ROS bag to record every scan to (its format from its name,
    :mod:`swarmslam.formats.bags`), written whole when the run ends."""
    options = options or RunOptions()
    out = Path(out_dir)
    check_writable(out)
    if options.localize:
        check_input_kept(out, options.localize, "the session")
    clean_stale(out)
    changes = {} if rate_hz is None else {"runtime.rate_hz": rate_hz}
    sensor = slam_config_for(model).sensor  # the scanner on the port now
    runtime = open_runtime(options, options.config or slam_config_for(model), changes, sensor)
    if options.localize:
        echo(f"localizing in {options.localize}: {runtime.slam.saved.n_nodes} saved nodes "
             f"(read-only)")
    elif options.resume:
        echo(f"resumed {options.resume}: {runtime.slam.n_nodes} nodes; finding where it starts")
    if runtime.session_note:
        echo(runtime.session_note)
    inbox = runtime.inbox
    recorder = None
    if bag is not None:  # (the extra 'bags' only when recording: refused now if missing)
        m = get_model(model)
        bins = 360 * max(1, round(m.samples_per_second / m.scan_hz / 360))
        recorder = BagRecorder(bag, bins, runtime.config.sensor.max_range)

    def on_scan(angles, ranges, stamp):
        inbox.put_ranges(angles=angles, ranges=ranges, stamp=stamp)
        if recorder is not None:
            recorder.put(angles, ranges, stamp)

    lidar = RPLidar(port, model, on_scan=on_scan)
    lidar.connect()
    if baud is not None:
        echo(f"{port}: link at {baud} bps (the scanner measured "
             f"{lidar.negotiate_baud(baud)})")
    info, health = lidar.get_info(), lidar.get_health()
    echo(f"{port}: model 0x{info.model:02X} firmware {info.firmware_major}.{info.firmware_minor:02d} "
         f"hardware {info.hardware} serial {info.serial_hex}; health "
         f"{['ok', 'warning', 'error'][min(health[0], 2)]} (code {health[1]})")
    mismatch = model_mismatch(info.major_model, model)
    if mismatch:
        echo(f"warning: {mismatch}")
    echo(f"warming up the compiled kernels: {runtime.warm_up():.1f} s")
    stop = stop or threading.Event()
    started = time.monotonic()
    last_print = [started, 0]
    last_scan = [started, 0]  # when the scan count last grew, and the count then

    def on_tick(rt, result):
        now = time.monotonic()
        if watch is not None and result is not None:
            watch.tick(rt, frame_of(rt, result, rt.scan.points, time.time(),
                                    rt.stats.last_latency))
        if seconds is not None and now - started >= seconds:
            stop.set()
        if now - last_print[0] >= 1.0:
            r, s = rt.report(), lidar.report()
            rate = (r["scans"] - last_print[1]) / (now - last_print[0])
            if r["scans"] > last_scan[1]:
                last_scan[0], last_scan[1] = now, r["scans"]
            silent = now - last_scan[0]
            status = rt.status if silent < NO_SCANS_SECONDS else \
                f"no scans for {silent:.0f} s (scanner gone, or another model?)"
            pose = rt.pose()
            graph = (f"saved {r['saved_nodes']:4d} lost {r['lost']:3d}" if rt.localizing else
                     f"nodes {r['nodes']:4d} loops {r['loops_accepted']:3d}")
            # a lockstep schedule never reads the clock, so it has no latencies to show
            p99 = (f"{r['latency_ms_p99']:5.1f} ms" if rt.config.runtime.schedule == "budgeted"
                   else "  n/a (lockstep)")
            echo(f"{rate:4.1f} scans/s  pose {pose[0]:7.2f} {pose[1]:7.2f} {pose[2]:6.2f}  "
                 f"{graph}  p99 {p99}  misses {r['deadline_misses']}  stale "
                 f"{r['stale_scans']}  checksum {s['checksum_errors']} resync {s['resyncs']} "
                 f"timeouts {s['timeouts']} reconnects {s['reconnects']}  {status}"
                 + (f"  {rt.inbox.skipped()}" if rt.inbox.skipped() else ""))
            last_print[0], last_print[1] = now, r["scans"]

    try:
        lidar.start(mode)
        runtime.run(stop, on_tick=on_tick, autosave=out / AUTOSAVE)
    except KeyboardInterrupt:
        echo("stopping (Ctrl-C or SIGTERM): saving")
    finally:
        lidar.close()
        if watch is not None:
            watch.close()
        if recorder is not None:  # a failed bag is said; the run's outputs are saved still
            try:
                echo(f"wrote {recorder.close()}: {recorder.recorded} scans"
                     + (f" ({recorder.dropped} dropped: the disk fell behind)"
                        if recorder.dropped else ""))
            except BagError as exc:
                echo(f"warning: {exc}")
    return save_outputs(runtime, out, lidar.report(), echo)


def save_outputs(runtime: SlamRuntime, out: Path, scanner: dict, echo=print) -> dict:
    """The run's output set, swapped in whole (scripts/outputs.py) once an autosave in
    progress has finished."""
    if runtime.autosave is not None:
        runtime.autosave.wait()
    runtime.drain()
    report = runtime.report()
    status = runtime.status if report["scans"] else NO_SCANS_STATUS
    summary = {"status": status, "runtime": report, "scanner": scanner}
    if not report["scans"]:  # an empty map must not replace what the folder held
        report_beside(out, summary)
        echo(f"nothing written to {out}/ but {UNUSABLE_REPORT} (what it held is as it was)")
        echo(f"status: {status}")
        return summary
    with output_set(out) as stage:
        if runtime.localizing:  # the saved map is unchanged: only where the robot went
            write_tum(stage / "trajectory.tum", *runtime.trajectory())
            write_json_atomic(stage / "summary.json", summary)
            wrote = "trajectory.tum summary.json"
        else:  # the whole set: never an earlier run's files beside it
            write_results(runtime.slam, stage)
            runtime.save(stage / "session.npz")
            write_json_atomic(stage / "summary.json", summary)
            wrote = "map.pgm map.yaml map.png trajectory.tum graph.g2o session.npz summary.json"
    for name in (AUTOSAVE, AUTOSAVE + ".prev"):  # the set holds all of it now
        (out / name).unlink(missing_ok=True)
    echo(f"wrote {out}/: {wrote}")
    if status != "ok":
        echo(f"status: {status}")
    return summary


# The session autosaved while a live run goes on, beside the output set and never in it: the
# set's own session.npz is the previous run's until this run's set replaces the whole set, and
# the autosave (what --resume takes after a power cut) is removed once it has.
AUTOSAVE = "session.autosave.npz"
NO_SCANS_SECONDS = 5.0  # a scanner silent this long is reported so on the status line
NO_SCANS_STATUS = "no scans received: nothing mapped (is the scanner on the port the model given?)"


def model_mismatch(major: int, asked: str) -> str:
    """What to warn of when the scanner on the port is not the model asked for ('' if it
    is): its scans would not decode."""
    want = get_model(asked)
    if major == want.major_id:
        return ""
    found = next((m.name.upper() for m in MODELS.values() if m.major_id == major),
                 f"of family {major}")
    return (f"the scanner reports itself an {found}, not the {want.name.upper()} asked for "
            f"(--model {want.name}): its scans may not decode")
