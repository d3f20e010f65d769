"""The managed flight stack (M Sec. 7.2-7.6) flown through the mission API on the simulated
vehicle: UAV manager routines and refusals, controller switching, an estimator frame switch
during a trajectory, a failsafe on estimate loss."""
import shutil

import numpy as np
import pandas as pd
import pytest
from pydrake.systems.primitives import ConstantVectorSource

from alight.diagrams.analysis.flight import managed_flight_failures
from alight.diagrams.cli import main
from alight.diagrams.running.run_log import RunLog
from alight.diagrams.running.mission import Mission, MissionError
from alight.systems.estimation.frames import FrameSwitch
from alight.systems.managers.control_manager import FailsafeCause, ManagerMode
from alight.systems.sensors.estimate_faults import EstimateFaultParams, EstimateFaults

pytestmark = pytest.mark.mission


def frame_switch(at, p_OldNew, yaw):
    q = [np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)]

    def add(builder, estimate):
        switch = builder.AddNamedSystem("frame_switch", FrameSwitch(at, p_OldNew, q))
        builder.Connect(estimate, switch.get_input_port())
        return switch.get_output_port()
    return add


def true_position(run, t=None):
    truth = run["ground_truth"]
    p = run.field("ground_truth", "p_WB").to_numpy()
    return p if t is None else p[np.searchsorted(truth["time"].to_numpy(), t)]


def test_takeoff_goto_switch_land_home_with_refusals(tmp_path):
    mission = Mission.simulated(seed=1, run_dir=tmp_path, strict=False)
    with mission:
        assert mission.goto([1.0, 0.0, 2.0]).refusal == "not_flying"
        takeoff = mission.takeoff(2.0)
        assert takeoff.done and takeoff.duration < 8.0
        assert mission.takeoff(2.0).refusal == "not_idle"
        refused = mission.goto([80.0, 0.0, 2.0])
        assert refused.refusal == "outside_area" and not refused.done
        assert mission.switch_controller("pid").refusal == "unknown_name"
        assert mission.goto([3.0, 1.0, 2.5], heading=0.5).done
        mission.wait(2.0)
        assert np.linalg.norm(mission.estimate()[1:4] - [3.0, 1.0, 2.5]) < 0.12
        assert mission.switch_controller("mpc").done
        assert mission.goto([0.0, 2.0, 2.0]).done
        assert mission.land_home().done
    with pytest.raises(MissionError, match="refused"):
        strict = Mission.simulated(seed=1, run_dir=tmp_path / "strict")
        strict.goto([1.0, 0.0, 2.0])
    run = mission.run_log
    p = true_position(run)
    assert p[-1, 2] < 0.3                                      # on the ground ...
    assert np.linalg.norm(p[-1, :2] - p[0, :2]) < 0.3          # ... at home
    assert run["fc_status"]["armed"].iloc[-1] == 0.0           # disarmed
    status = run["manager_status"]
    assert status["mode"].max() <= ManagerMode.DISARMED and \
        not np.any(status["mode"].isin([ManagerMode.ELAND, ManagerMode.FAILSAFE]))
    assert set(status["active"].unique()) >= {0.0, 1.0}        # se3 and mpc both flew


def test_estimator_frame_switch_during_a_trajectory_keeps_the_true_path(tmp_path):
    """The estimate jumps into a new frame (5 m and 30 deg away) mid-trajectory: trackers,
    controllers, the control manager and the UAV manager re-express their states (M Sec. 3.5);
    the vehicle's true path matches the same flight without the switch."""
    paths = []
    for switch in (False, True):
        stack = {"estimate_filter": frame_switch(8.0, [4.0, -3.0, 0.5], np.radians(30))} \
            if switch else {}
        mission = Mission.simulated(seed=2, run_dir=tmp_path / str(switch), **stack)
        with mission:
            mission.takeoff(2.0)
            assert mission.fly_through([[4.0, 0.0, 2.0], [4.0, 4.0, 3.0]]).done
            assert mission.time > 9.0                      # the switch came mid-trajectory
        run = mission.run_log
        estimate = run.field("state_estimate", "p_EB").to_numpy()
        jump = np.linalg.norm(np.diff(estimate, axis=0), axis=1).max()
        assert run["state_estimate"]["frame_counter"].max() == float(switch)
        assert (jump > 2.0) == switch                      # 2.5 m here
        paths.append(true_position(run))
        times = run["ground_truth"]["time"].to_numpy()
    n = min(len(paths[0]), len(paths[1]))
    deviation = np.linalg.norm(paths[1][:n] - paths[0][:n], axis=1)
    # Exactly the same flight through the switch (measured: 0.0007 m at 8.3 s) ...
    assert deviation[times[:n] < 8.3].max() < 0.01
    # ... then the MPC tracker's per-axis shares of the horizontal limits (M Sec. 4.1) differ
    # in the 30 deg rotated frame, and the plans part slowly (measured 0.14 m at the end).
    assert deviation.max() < 0.2
    assert np.linalg.norm(paths[1][-1] - [4.0, 4.0, 3.0]) < 0.35


def test_state_estimate_loss_in_flight_triggers_the_failsafe_landing(tmp_path):
    def lose_estimate(builder, estimate):
        faults = builder.AddNamedSystem("faults", EstimateFaults(EstimateFaultParams(
            loss=True, loss_time=6.0)))
        quiet = builder.AddNamedSystem("no_noise", ConstantVectorSource(np.zeros(6)))
        builder.Connect(quiet.get_output_port(), faults.GetInputPort("noise"))
        builder.Connect(estimate, faults.GetInputPort("state_estimate"))
        return faults.GetOutputPort("state_estimate")
    mission = Mission.simulated(seed=3, run_dir=tmp_path, strict=False,
                                estimate_filter=lose_estimate)
    with mission:
        mission.takeoff(2.0)
        mission.wait(14.0)
    run = mission.run_log
    status = run["manager_status"]
    failsafe = status[status["mode"] == ManagerMode.FAILSAFE]
    assert len(failsafe) and failsafe["time"].iloc[0] == pytest.approx(6.0, abs=0.05)
    assert failsafe["failsafe_cause"].iloc[0] == FailsafeCause.BAD_ESTIMATE
    v = run.field("ground_truth", "v_WB").to_numpy()
    assert v[:, 2].min() > -3.0                      # a controlled descent (M Sec. 5.10)
    assert true_position(run)[-1, 2] < 0.3           # down


def test_fly_command_flies_waypoints_and_a_trajectory_file_and_refuses_bad_input(
        tmp_path, capsys):
    """`alight fly` on the managed stack: a generated trajectory through waypoints with the
    MPC controller and a scheduled switch to SE(3); a sampled trajectory file; bad inputs."""
    # On mocap: the corner figures below are the generated trajectory's (M Sec. 6) rounding of
    # the corner from the start state, recorded on mocap. On the default VIO (initialized at rest
    # first, the flight 0.5 s later) the generated goal itself passes 0.315 m from the corner
    # (0.175 m on mocap) and the vehicle 0.36 m; `alight fly` on the VIO is the next test's.
    assert main(["fly", "--waypoints", "2,0,2; 2,2,2", "--controller", "mpc",
                 "--switch-controller-at", "6:se3", "--estimator", "mocap",
                 "--run-dir", str(tmp_path / "run")]) == 0
    out = capsys.readouterr().out
    assert "landed and disarmed   True" in out and "refused" not in out
    assert out.rstrip().endswith("outcome               flew and landed")
    run = RunLog(tmp_path / "run")
    p = true_position(run)
    for waypoint in ([2.0, 0.0, 2.0], [2.0, 2.0, 2.0]):   # the corner: 0.08-0.17 m measured
        assert np.linalg.norm(p - waypoint, axis=1).min() < 0.25
    assert p[-1, 2] < 0.3 and run["fc_status"]["armed"].iloc[-1] < 0.5
    active = run["manager_status"].set_index("time")["active"]   # the trajectory: 3.9-7.9 s
    assert active.loc[4.5:5.9].eq(1.0).all() and active.loc[6.1:7.0].eq(0.0).all()  # mpc, se3

    samples = tmp_path / "line.csv"
    times = np.arange(0.0, 4.01, 0.1)
    samples.write_text("t,x,y,z\n" + "\n".join(f"{t:.1f},{0.5 * t:.3f},0,2.5" for t in times))
    assert main(["fly", "--trajectory", str(samples), "--run-dir", str(tmp_path / "line")]) == 0
    p = true_position(RunLog(tmp_path / "line"))
    assert np.linalg.norm(p - [2.0, 0.0, 2.5], axis=1).min() < 0.15
    capsys.readouterr()

    bad = tmp_path / "bad.csv"
    bad.write_text("t,x,y\n0,0,0\n")
    for argv, message in ((["--waypoints", "1,0; 2,2,nan"], "waypoints must"),
                          (["--trajectory", str(bad)], "columns x, y, z"),
                          (["--waypoints", "1,0,2", "--controller", "pid"], "--controller"),
                          (["--waypoints", "1,0,2", "--switch-controller-at", "x:mpc"],
                           "TIME:NAME"),
                          (["--waypoints", "1,0,2", "--trajectory", str(samples)],
                           "exactly one")):
        assert main(["fly", *argv]) == 2
        assert message in capsys.readouterr().err


def test_fly_command_fails_a_refused_routine_and_judges_landed_by_contact(tmp_path, capsys):
    """A trajectory above the safety area (20 m) is refused: the vehicle lands where it is, and
    `alight fly` exits 1. Landed is judged by the legs' ground contact at rest, not the armed
    flag: the same run folder with the legs off the ground at the end is not landed."""
    assert main(["fly", "--waypoints", "2,0,2; 2,2,30", "--run-dir", str(tmp_path / "run")]) == 1
    out = capsys.readouterr().out
    assert "trajectory    refused (outside_area)" in out
    assert "landed and disarmed   True" in out
    assert out.rstrip().endswith("outcome               FAILED: trajectory refused (outside_area)")
    run = RunLog(tmp_path / "run")
    assert {"vio_odometry", "vio_estimate"} <= set(run.streams)   # flown on the default VIO
    assert managed_flight_failures(run) == ["trajectory refused (outside_area)"]
    shutil.copytree(tmp_path / "run", tmp_path / "hanging")
    truth_file = tmp_path / "hanging" / "ground_truth.parquet"
    truth = pd.read_parquet(truth_file)
    last = truth["time"] > truth["time"].iloc[-1] - 0.2  # disarmed, and in the air
    truth.loc[last, "legs_ground_force"] = 0.0
    truth.to_parquet(truth_file)
    assert RunLog(tmp_path / "hanging")["fc_status"]["armed"].iloc[-1] == 0.0
    assert managed_flight_failures(RunLog(tmp_path / "hanging")) == [
        "trajectory refused (outside_area)", "not landed (not at rest on its legs on the ground)"]
