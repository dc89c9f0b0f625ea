"""`bench runtime`'s recorded-rate pass: which scans it hands over, and when."""

import numpy as np

from swarmslam.bench.runtime import LOG_PAUSE, recording_times


def test_the_recorded_rate_keeps_the_logs_timing_and_cuts_its_pauses():
    stamps = np.array([100.0, 263.3, 263.9, 264.5, 264.5 + LOG_PAUSE, 264.5 + 2 * LOG_PAUSE + 1])
    times = recording_times(stamps)
    # a gap up to the pause is replayed as logged; a longer one not at all
    assert np.allclose(times, [0.0, 0.0, 0.6, 1.2, 1.2 + LOG_PAUSE, 1.2 + LOG_PAUSE])
    assert np.array_equal(recording_times(stamps, pause=1e9), stamps - stamps[0])
