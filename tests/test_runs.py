"""How a run starts (swarmslam.runs): one options object and one way to open a new, localized or
resumed run, shared by replay and lidar."""

import pytest

from swarmslam.cli import main
from swarmslam.runs import SESSION_TAKES_ITS_CONFIGURATION, RunOptions, open_runtime
from swarmslam.runtime.config import SlamConfig, override
from swarmslam.runtime.matching.scan import PointScan
from swarmslam.runtime.realtime.fixed_rate import SlamRuntime
from swarmslam.runtime.realtime.warm_up import LoopDrive


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """A few scans mapped by a run of seed 7 running PSO, saved."""
    config = override(SlamConfig(), {"matcher.swarm.optimizer": "pso",
                                     "runtime.schedule": "lockstep"})
    runtime = SlamRuntime(config, seed=7)
    drive = LoopDrive(seed=2, steps_per_lap=60)
    scan = PointScan(len(drive.angles))
    for k in range(20):
        _, odometry, ranges = drive.next()
        scan.set_ranges(ranges, drive.angles, 0.05, drive.max_range)
        runtime.process(scan, odometry, 0.1 * k)
    path = tmp_path_factory.mktemp("saved") / "session.npz"
    runtime.save(path)
    return path


def test_a_new_run_takes_its_seed_optimizer_and_schedule():
    runtime = open_runtime(RunOptions(seed=3, optimizer="pso", schedule="budgeted"),
                           SlamConfig(), {"runtime.rate_hz": 5.0})
    assert runtime.seed == 3
    assert runtime.config.matcher.swarm.optimizer == "pso"
    assert runtime.config.runtime.schedule == "budgeted"
    assert runtime.config.runtime.rate_hz == 5.0
    assert open_runtime(RunOptions(), SlamConfig()).config == SlamConfig()


def test_a_resumed_run_keeps_the_sessions_configuration_and_seed_with_the_changes_given(session):
    runtime = open_runtime(RunOptions(resume=session, seed=99, schedule="budgeted"), None,
                           {"runtime.rate_hz": 5.0}, scans=10)
    assert runtime.seed == 7  # the session's, not the options'
    assert runtime.config.matcher.swarm.optimizer == "pso"
    assert runtime.config.runtime.rate_hz == 5.0
    assert runtime.config.runtime.schedule == "budgeted"
    assert not runtime.localizing


def test_a_localized_run_sizes_its_trajectory_for_the_scans_it_brings(session):
    runtime = open_runtime(RunOptions(localize=session), None, scans=12_345)
    assert runtime.localizing
    assert runtime.config.capacity.max_scans == 12_345
    assert runtime.config.matcher.swarm.optimizer == "pso"  # the session's own


def test_a_configuration_beside_a_session_is_refused_with_one_message(session):
    with pytest.raises(ValueError, match="takes the configuration saved in its session"):
        RunOptions(config=SlamConfig(), resume=session)
    with pytest.raises(ValueError, match="not both"):
        RunOptions(localize=session, resume=session)
    with pytest.raises(ValueError, match="keeps its session's swarm method"):
        RunOptions(resume=session, optimizer="fa")  # its swarm's saved state is PSO's


@pytest.mark.parametrize("command", [["replay", "log.clf"], ["lidar", "--port", "/dev/null"]])
@pytest.mark.parametrize("saved", ["--resume", "--localize"])
def test_replay_and_lidar_refuse_a_preset_beside_a_session_alike(command, saved, session, capsys):
    assert main([*command, "--preset", "rplidar-a1", saved, str(session)]) == 2
    assert SESSION_TAKES_ITS_CONFIGURATION in capsys.readouterr().err
