""""No memory allocated per match after warm-up", proved two ways (see the numba notes):
tracemalloc for Python objects, numba's runtime counters for allocations in compiled code."""

import json
import os
import subprocess
import sys
import tracemalloc

import numpy as np
from numba.core.runtime import rtsys

from swarmslam.runtime.config import SensorConfig
from swarmslam.runtime.matching.optimizers import SwarmConfig
from swarmslam.runtime.matching.scan import PointScan
from swarmslam.runtime.matching.scan_matcher import N_OUT, MatcherConfig, ScanMatcher
from swarmslam.runtime.matching.sweep_motion import SweepMotion
from swarmslam.runtime.realtime.warm_up import pose_after, room_world, scan_at

ANGLES = np.deg2rad(np.arange(-180, 180, 1.0))


def scans():
    world = room_world(0)
    a = scan_at(world, [3.0, 3.0, 0.3], ANGLES)
    b = scan_at(world, pose_after([3.0, 3.0, 0.3], [0.5, 0.2, 0.3]), ANGLES)
    return PointScan.from_ranges(a, ANGLES, 0.05, 12.0), PointScan.from_ranges(b, ANGLES, 0.05, 12.0)


def traced_growth(run, warm: int, measured: int) -> tuple[int, int]:
    """``run(warm)``, then ``run(measured)`` traced: the bytes still held after it, and the
    most held at once during it, beyond what was held before it."""
    tracemalloc.start()
    try:
        run(warm)
        before, _ = tracemalloc.get_traced_memory()
        tracemalloc.reset_peak()
        run(measured)
        after, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return after - before, peak - before


def traced_matches() -> tuple[int, int]:
    """:func:`traced_growth` of 5,000 matches after 4,000."""
    # A small budget keeps the test quick; the per-match path is the same at any budget.
    config = MatcherConfig(swarm=SwarmConfig(max_evaluations=100), refine_evaluations=40,
                           scan_to_map=True)
    matcher = ScanMatcher(config)
    ref, cur = scans()
    reference = matcher.new_reference()
    out = np.zeros(N_OUT)

    def match(n):
        for _ in range(n):
            matcher.build_reference(ref, reference)
            matcher.align_into(cur, reference, None, out)

    return traced_growth(match, 4000, 5000)  # warm-up: compilation, dispatch caches


def traced_sweeps() -> tuple[int, int]:
    """:func:`traced_growth` of 3,000 sweeps undone, matched and settled, after 2,000."""
    matcher = ScanMatcher(MatcherConfig(swarm=SwarmConfig(max_evaluations=100),
                                        refine_evaluations=40))
    sweep = SweepMotion(SensorConfig(sweep_seconds=0.18), 400)
    ref, cur = scans()
    reference = matcher.new_reference()
    matcher.build_reference(ref, reference)
    motion = np.array([0.1, 0.0, 0.3])

    def undistort_and_settle(n):
        for _ in range(n):
            first = sweep.undistort(cur, motion, 0.18)
            match = matcher.align_scans(first, reference, motion)
            matcher.settle(sweep.undistort(cur, match.pose, 0.18), reference, match)

    return traced_growth(undistort_and_settle, 2000, 3000)


def traced_headings_sought() -> tuple[int, int]:
    """:func:`traced_growth` of 1,000 lost matches sought again from headings 3° apart across
    a ±0.6 rad box (the front end's recovery), after 500."""
    matcher = ScanMatcher(MatcherConfig(swarm=SwarmConfig(max_evaluations=100),
                                        refine_evaluations=40))
    ref, cur = scans()
    reference = matcher.new_reference()
    matcher.build_reference(ref, reference)
    guess, window = np.array([0.4, 0.2, 0.0]), np.array([0.3, 0.3, 0.6])

    def seek(n):
        for _ in range(n):
            matcher.align_scans(cur, reference, guess, window)
            matcher.seek_headings(cur, reference, np.radians(3.0))

    return traced_growth(seek, 500, 1000)


def in_fresh_interpreter(call: str, env=None):
    """``call`` (a function of this module) run in a new interpreter; its result, from JSON.
    tracemalloc counts every thread's allocations, pytest-xdist's messaging thread among them,
    and caches other tests filled or left unfilled in this process: a measurement here would
    depend on which tests ran first and on the workers' traffic."""
    code = (f"import json, sys; sys.path.insert(0, {os.path.dirname(__file__)!r}); "
            f"import test_allocation as t; print(json.dumps(t.{call}()))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          env=env, cwd=os.path.dirname(os.path.dirname(__file__)), timeout=600)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_no_traced_memory_growth_per_match_after_warm_up():
    grown, peak = in_fresh_interpreter("traced_matches")
    assert grown <= 256, f"traced memory grew {grown} B over 5000 matches"
    # Transient objects (the call's arguments) exist, but never more than a few at a time.
    assert peak < 4096, peak


def test_no_traced_memory_growth_per_undistorted_sweep_after_warm_up():
    """A sweep's two passes (runtime/matching/sweep_motion.py) and the settled match: nothing kept."""
    grown, peak = in_fresh_interpreter("traced_sweeps")
    assert grown <= 256, f"traced memory grew {grown} B over 3000 sweeps"
    assert peak < 4096, peak


def test_no_traced_memory_growth_per_heading_search_after_warm_up():
    grown, peak = in_fresh_interpreter("traced_headings_sought")
    assert grown <= 256, f"traced memory grew {grown} B over 1000 searches"
    assert peak < 4096, peak


def nrt_per_call() -> dict:
    """Numba's runtime allocations and frees per call (NUMBA_NRT_STATS must be set before
    numba starts): a match at two budgets, and the match's curvature."""
    ref, cur = scans()
    out = np.zeros(N_OUT)
    per_call = {}
    for budget in (100, 3000):
        m = ScanMatcher(MatcherConfig(swarm=SwarmConfig(max_evaluations=budget), scan_to_map=True))
        r = m.new_reference()
        for _ in range(3):
            m.build_reference(ref, r)
            m.align_into(cur, r, None, out)
        s0 = rtsys.get_allocation_stats()
        for _ in range(20):
            m.build_reference(ref, r)
            m.align_into(cur, r, None, out)
        s1 = rtsys.get_allocation_stats()
        per_call[str(budget)] = [(s1.alloc - s0.alloc) / 20, (s1.free - s0.free) / 20]
    pose, step = np.zeros(3), (0.05, 0.01)
    m.curvature(cur, r, pose, step)  # the degeneracy test's Hessian, every tick
    s0 = rtsys.get_allocation_stats()
    for _ in range(20):
        m.curvature(cur, r, pose, step)
    s1 = rtsys.get_allocation_stats()
    per_call["curvature"] = [(s1.alloc - s0.alloc) / 20, (s1.free - s0.free) / 20]
    return per_call


def test_compiled_code_allocation_does_not_scale_with_work():
    per_call = in_fresh_interpreter("nrt_per_call", dict(os.environ, NUMBA_NRT_STATS="1"))
    small, large = per_call["100"], per_call["3000"]
    # The only NRT allocations are the array arguments' wrappers at the Python boundary
    # (one per array argument, freed on return): the same count for 30x the evaluations,
    # and every one freed.
    assert small == large, per_call
    assert small[0] == small[1]
    assert small[0] < 64
    # The match's curvature (front end, every tick): its four array arguments only (the
    # finite differences once built a small list per probe: 36 more allocations a call).
    assert per_call["curvature"] == [4.0, 4.0], per_call
