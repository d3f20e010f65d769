"""The fault campaign's short version (issue 21; bench/faults.py is the whole one): a few
representative faults injected through the scenario into seeded flights of the direct stacks,
each judged from ground truth and contacts (diagrams/analysis/faults.py) with no unsafe outcome
and the outcome the stack should reach; and the judge itself flags what is unsafe.
About 50 CPU s in all (each waypoint flight 4-6 s, the landing about 15 s)."""
import pytest

from alight.diagrams.analysis.faults import (FAILSAFE_LANDING, FLYAWAY, LANDED, UNSAFE,
                                             judge_fault_run)
from alight.diagrams.running.runner import run
from alight.diagrams.scenario import load_scenario
from alight.systems.managers.control_manager import FailsafeCause

FAULT_TIME = 4.5   # s: the waypoint flight at 2 m on its first leg


def fly(scenario: str, overrides: list[str], tmp_path):
    log = run(load_scenario(scenario, overrides=overrides), run_dir=tmp_path / "run",
              duration=120.0)
    return log, judge_fault_run(log)


def _cause(log) -> FailsafeCause:
    return FailsafeCause(int(log["manager_status"]["failsafe_cause"].max()))


@pytest.mark.mission
@pytest.mark.parametrize("overrides, outcome, cause", [
    # A broken MPC: never forwarded, the failsafe lands.
    ([f"faults.command: {{kind: nan, start: {FAULT_TIME}, duration: 1.0}}"], FAILSAFE_LANDING,
     FailsafeCause.BAD_CONTROLLER),
    ([f"faults.command: {{kind: out_of_range, start: {FAULT_TIME}, duration: 1.0}}"],
     FAILSAFE_LANDING, FailsafeCause.BAD_CONTROLLER),
    # The estimate lost for longer than the descent: back on the ground, the failsafe disarms
    # (it stayed armed at 95 % of hover thrust before the campaign found it).
    ([f"faults.estimate: {{loss: true, loss_time: {FAULT_TIME}, loss_duration: 10.0}}"],
     FAILSAFE_LANDING, FailsafeCause.BAD_ESTIMATE),
    # The command link lost 2 s: the flight controller's own failsafe descent; the switch takes
    # over and the mission can no longer disarm (a landing disarmed 1.1 m up before 6b356f5).
    ([f"vehicle.link_losses: [[{FAULT_TIME}, {FAULT_TIME + 2.0}]]"], FAILSAFE_LANDING,
     FailsafeCause.FLIGHT_CONTROLLER),
    # A rotor at 70 % thrust: the flight controller's mixer flies on, the plan is flown.
    ([f"vehicle.motor_fault: {{loss: 0.3, rotor: 0, time: {FAULT_TIME}}}"], LANDED,
     FailsafeCause.NONE),
], ids=["nan_commands", "out_of_range_commands", "estimate_lost_10s", "link_lost_2s",
        "motor_30pc"])
def test_waypoint_flight_fault_is_safe(overrides, outcome, cause, tmp_path):
    log, judged = fly("waypoints", overrides, tmp_path)
    assert judged.outcome == outcome, judged
    assert _cause(log) == cause
    assert judged.distance < 3.0            # m from the plan: the failsafe drifts little
    assert judged.touchdown_speed < 1.5     # m/s down (the limit is 3)


@pytest.mark.mission
def test_landing_with_the_estimate_lost_for_2_s_lands_on_the_failsafe(tmp_path):
    """On the way to the car (15 s: in the air after the take-off at about 12 s): the direct
    landing stack falls back for good and lands beside the car's path."""
    log, judged = fly("field", ["faults.estimate: {loss: true, loss_time: 15.0, "
                                "loss_duration: 2.0}"], tmp_path)
    assert judged.outcome == FAILSAFE_LANDING, judged
    assert _cause(log) == FailsafeCause.BAD_ESTIMATE
    assert judged.touchdown_speed < 2.0 and judged.distance < FLYAWAY


@pytest.mark.mission
def test_the_judge_flags_a_touchdown_over_the_legs_limit(tmp_path):
    """The nominal waypoint flight (about 35 N on a leg at touchdown) judged against a 20 N
    leg: unsafe."""
    _, judged = fly("waypoints", ["vehicle.airframe.max_leg_force: 20.0"], tmp_path)
    assert judged.outcome == UNSAFE and judged.reason.startswith("hard impact"), judged
