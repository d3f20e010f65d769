"""Level touchdown (alight.systems.control.touchdown_level): why and what.

Why: the windy landing `alight land --target-speed 3 --wind 15 --gusts 0.8 --seed 1` touched
down tilted 11.7 deg (the MPC holding the vehicle against 7 m/s of air over the car), 1.91 m/s
down and 0.56 m/s sideways relative to the platform, and tipped over once disarmed. Dropped
disarmed from that state (the drop below, on a still platform in the same relative air), the
vehicle tips over; levelled, with everything else the same, it stays upright.
What: in Landing Phase 2, under `height` above the target, the command is level at its heading.
"""
import numpy as np
import pytest
from pydrake.math import RollPitchYaw
from pydrake.systems.analysis import Simulator

from alight.diagrams.analysis.landing import MAX_TILT, score_landing
from alight.diagrams.running.runner import run as run_scenario
from alight.diagrams.scenario import load_scenario, vehicle_config
from alight.systems.boundary import FC_COMMAND, STATE_ESTIMATE, TARGET_ESTIMATE, CommandMode
from alight.systems.control.touchdown_level import TouchdownLevel, TouchdownLevelParams
from alight.systems.mission.landing import MISSION_STATUS, Mode
from alight.systems.rotations import heading, rotation_matrix, tilt_deg
from drops import drop

# The flown touchdown (seed 1 above, 0.02 m above the first leg contact), in the car's frame
# (x forward): the air over the car, the velocity relative to it, the tilt into that air.
AIR = np.array([5.5, -3.6, 0.0])            # m/s, 6.6 m/s
V_TOUCHDOWN = np.array([0.03, -0.56, -1.91])  # m/s
TILT = np.radians(11.7)                       # rad, about the horizontal axis across the air
HEIGHT = 0.24                                 # m, CoM above the platform (legs 0.22 m below it)


def touchdown(tilt: float) -> np.ndarray:
    """The disarmed vehicle let go at the flown touchdown state tilted by `tilt` [rad] into the
    air; its tilt [deg] at every plant step for 1.5 s."""
    direction = np.degrees(np.arctan2(AIR[1], AIR[0]))
    config = vehicle_config(load_scenario("field", overrides=[
        "target_motion.speed: 0.0", f"vehicle.wind.mean_speed: {np.linalg.norm(AIR)}",
        f"vehicle.wind.direction: {direction}", "vehicle.wind.gust_std: 0.0"]))
    # Tilted into the air: the thrust axis leans upwind (pitch about the axis across it).
    upwind = np.arctan2(AIR[1], AIR[0]) + np.pi
    x, y = config.target.initial_position
    _, truth = drop(config, 0.0, duration=1.5, rpy=(0.0, tilt, upwind),
                    p_WB=[x, y, config.target.platform_height + HEIGHT], v_WB=V_TOUCHDOWN)
    return tilt_deg(truth["q_WB"])


def test_a_touchdown_tilted_into_the_air_tips_over_and_a_level_one_stays_upright():
    tilted, level = touchdown(TILT), touchdown(0.0)
    print(f"max tilt: tilted {tilted.max():.1f} deg, level {level.max():.1f} deg")
    assert tilted.max() > 90.0             # over on its side or back
    assert level.max() < MAX_TILT / 4      # measured 2-3 deg
    assert level[-1] < 1.0                 # resting on its four legs


def levelled(mode: Mode, height: float, valid: float = 1.0, level_height: float = 1.0,
             command_mode: CommandMode = CommandMode.ATTITUDE_THRUST):
    dut = TouchdownLevel(TouchdownLevelParams(height=level_height), period=0.01)
    context = dut.CreateDefaultContext()
    q_WD = RollPitchYaw(0.1, -0.2, 0.7).ToQuaternion().wxyz()
    dut.GetInputPort("fc_command").FixValue(context, FC_COMMAND.vector(
        stamp=3.0, mode=command_mode, q_WD=q_WD, w_D=[0.1, 0.2, 0.3], thrust=0.6, arm=1.0))
    dut.GetInputPort("mission_status").FixValue(context, MISSION_STATUS.vector(mode=mode))
    dut.GetInputPort("state_estimate").FixValue(context, STATE_ESTIMATE.vector(
        p_EB=[5.0, 2.0, 1.0 + height]))
    dut.GetInputPort("target_estimate").FixValue(context, TARGET_ESTIMATE.vector(
        p_WT=[5.2, 2.1, 1.0], valid=valid))
    unlevelled = dut.GetOutputPort("fc_command").Eval(context).copy()
    Simulator(dut, context).AdvanceTo(0.005)    # the decision of the tick at t = 0
    assert np.array_equal(unlevelled, FC_COMMAND.vector(
        stamp=3.0, mode=command_mode, q_WD=RollPitchYaw(0.1, -0.2, 0.7).ToQuaternion().wxyz(),
        w_D=[0.1, 0.2, 0.3], thrust=0.6, arm=1.0))    # nothing is levelled before a decision
    return dut.GetOutputPort("fc_command").Eval(context)


@pytest.mark.parametrize("mode", [Mode.LANDING_P2, Mode.LANDED])
def test_under_the_height_in_phase_2_the_command_is_level_at_its_heading(mode):
    command = levelled(mode, height=0.9)
    q_WD = FC_COMMAND.get(command, "q_WD")
    assert tilt_deg(q_WD) == pytest.approx(0.0, abs=1e-9)
    assert heading(rotation_matrix(q_WD)) == pytest.approx(
        heading(RollPitchYaw(0.1, -0.2, 0.7).ToRotationMatrix().matrix()), abs=1e-12)
    assert np.all(FC_COMMAND.get(command, "w_D") == 0.0)
    for field in ("stamp", "mode", "thrust", "arm"):
        assert FC_COMMAND.get(command, field) == FC_COMMAND.get(levelled(Mode.FOLLOW, 0.9), field)


def test_a_rates_command_is_levelled_as_an_attitude_command():
    """The force controllers (M Sec. 5) send RATES_THRUST: levelled only in its rates (zero) it
    held the tilt it had (20 deg at a windy managed se3 touchdown, which tipped over); it goes
    out as a level ATTITUDE_THRUST command."""
    command = levelled(Mode.LANDING_P2, height=0.9, command_mode=CommandMode.RATES_THRUST)
    assert FC_COMMAND.get(command, "mode") == CommandMode.ATTITUDE_THRUST
    assert tilt_deg(FC_COMMAND.get(command, "q_WD")) == pytest.approx(0.0, abs=1e-9)
    assert np.all(FC_COMMAND.get(command, "w_D") == 0.0)
    assert FC_COMMAND.get(command, "thrust") == 0.6 and FC_COMMAND.get(command, "arm") == 1.0


@pytest.mark.parametrize("mode, height, valid, level_height", [
    (Mode.LANDING_P2, 1.1, 1.0, 1.0),   # above the height
    (Mode.LANDING_P1, 0.9, 1.0, 1.0),   # Phase 1 can still abort: the MPC keeps its attitude
    (Mode.FOLLOW, 0.5, 1.0, 1.0),
    (Mode.LANDING_P2, 0.5, 0.0, 1.0),   # no target estimate: no height above it
    (Mode.LANDING_P2, -0.1, 1.0, 0.0),  # height 0: off, even under the target's estimate
])
def test_otherwise_the_command_passes_unchanged(mode, height, valid, level_height):
    command = levelled(mode, height, valid, level_height)
    assert tilt_deg(FC_COMMAND.get(command, "q_WD")) > 10.0
    assert np.all(FC_COMMAND.get(command, "w_D") == [0.1, 0.2, 0.3])


@pytest.mark.mission
def test_the_windy_landing_that_tipped_over_lands_level(tmp_path):
    """The run the cause was found on (3 m/s, 15 km/h wind, 0.8 m/s gusts, seed 1): landed,
    touching down level (measured 0.5 deg; it was 11.7 deg and tipped over)."""
    scenario = load_scenario("field", overrides=[
        "target_motion.speed: 3.0", f"vehicle.wind.mean_speed: {15 / 3.6}",
        "vehicle.wind.gust_std: 0.8", "random_seed: 1"])
    run = run_scenario(scenario, run_dir=tmp_path / "run", command="land")
    impact = scenario.scoring.impact
    score = score_landing(run, impact.vertical_speed, impact.horizontal_speed)
    assert score.success, score.row()
    truth = run["ground_truth"]
    touchdown = np.flatnonzero(truth["legs_platform_force"].to_numpy() > 0.0)[0]
    q_WB = truth[[f"q_WB_{i}" for i in range(4)]].to_numpy()[touchdown]
    assert tilt_deg(q_WB)[0] < 3.0
    assert score.peak_leg_force < 150.0   # measured 134 N (was 140 N on one leg, tilted)
