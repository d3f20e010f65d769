"""The flight-controller emulation: tracking, mixing, command checks, failsafe, arming."""
import numpy as np
import pytest
from pydrake.common.eigen_geometry import Quaternion
from pydrake.math import RollPitchYaw
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder, LeafSystem

from alight.diagrams.onboard.pilot import pilot_model
from alight.diagrams.running.flights import fly_profile
from alight.diagrams.running.run_log import add_run_logging, read_run, write_run_folder
from alight.diagrams.world.sim_vehicle import make_sim_vehicle
from alight.diagrams.running.simulation import simulate
from alight.systems.autopilot.commander import Commander, CommanderParams
from alight.systems.autopilot.mixer import allocation_matrix, mix
from alight.systems.boundary import (FC_ATTITUDE, FC_COMMAND, FC_STATUS, GROUND_TRUTH, ActiveMode,
                                     CommandMode, Refusal)
from alight.systems.control.scripted_pilot import ScriptedPilot
from alight.systems.plant.hexacopter import Airframe
from alight.systems.thrust_curve import ThrustCurve
from conftest import TAKEOFF, TAKEOFF_END, profile, tilt_deg

F550 = Airframe(p_BR=0.275 * np.array([[np.cos(a), np.sin(a), 0.0] for a in
                                        np.radians([30, 90, 150, 210, 270, 330])]),
                yaw_moment=0.016 * np.array([1, -1, 1, -1, 1, -1]), max_thrust=9.0, idle=0.1,
                inertia=np.array([0.042, 0.042, 0.075]), mass=2.5)


def roll_deg(q):
    return np.degrees([RollPitchYaw(Quaternion(x / np.linalg.norm(x))).roll_angle() for x in q])


@pytest.fixture(scope="module")
def step_run(vehicle_config, tmp_path_factory):
    """Take off, a 10 degree roll step, level again, then a 30 deg/s yaw-rate command."""
    return fly_profile(vehicle_config, profile(TAKEOFF + """
        {duration: 2.0, roll: 10.0}
        {duration: 2.0, roll: 0.0}
        {duration: 2.0, mode: rates, body_rates: [0, 0, 30]}
        """), run_dir=tmp_path_factory.mktemp("runs") / "step")


def test_attitude_step_rise_time_and_overshoot(step_run):
    truth = step_run["ground_truth"]
    t = truth["time"].to_numpy()
    window = (t >= TAKEOFF_END) & (t < TAKEOFF_END + 2.0)
    roll = roll_deg(step_run.field("ground_truth", "q_WB").to_numpy()[window])
    tau = t[window] - TAKEOFF_END
    start = roll[0]
    rise = tau[np.argmax(roll > start + 0.9 * (10 - start))] \
        - tau[np.argmax(roll > start + 0.1 * (10 - start))]
    overshoot = (roll.max() - 10.0) / (10.0 - start)
    assert 0.05 < rise < 0.3, f"rise time {rise:.3f} s"        # PX4-tuned F550: about 0.2 s
    assert overshoot < 0.2, f"overshoot {100 * overshoot:.1f} %"
    assert abs(np.mean(roll[-20:]) - 10.0) < 1.0  # FC attitude estimate error is ~0.3 deg


def test_rates_mode_tracks_commanded_yaw_rate(step_run):
    truth = step_run["ground_truth"]
    t = truth["time"].to_numpy()
    window = (t > TAKEOFF_END + 4.5) & (t < TAKEOFF_END + 6.0)
    yaw_rate = np.degrees(step_run.field("ground_truth", "w_WB_B").to_numpy()[window, 2])
    assert np.mean(yaw_rate) == pytest.approx(30.0, rel=0.1)
    status = step_run["fc_status"]
    assert (status["mode"][status["time"] > TAKEOFF_END + 4.5] == ActiveMode.RATES_THRUST).all()


def test_mixer_delivers_feasible_demands_exactly():
    A = allocation_matrix(F550)
    pinv = np.linalg.pinv(A)
    demand = np.array([25.0, 0.3, -0.2, 0.05])
    solution = mix(demand[0], demand[1:], pinv, F550.min_thrust, F550.max_thrust)
    np.testing.assert_allclose(A @ solution.rotor_thrust, demand, atol=1e-9)
    assert solution.roll_pitch_scale == 1.0 and solution.yaw_scale == 1.0


def test_mixer_gives_up_yaw_before_roll_pitch():
    A = allocation_matrix(F550)
    pinv = np.linalg.pinv(A)
    torque = np.array([1.5, 0.0, 2.0])  # yaw far beyond the rotors' reaction moments
    solution = mix(25.0, torque, pinv, F550.min_thrust, F550.max_thrust)
    achieved = A @ solution.rotor_thrust
    assert achieved[1] == pytest.approx(1.5, rel=1e-6)  # roll kept in full
    assert 0.0 <= solution.yaw_scale < 1.0 and achieved[3] < 2.0
    assert np.all(solution.rotor_thrust >= F550.min_thrust - 1e-9)
    assert np.all(solution.rotor_thrust <= F550.max_thrust + 1e-9)


def test_mixer_scales_roll_pitch_keeping_direction_and_shifts_thrust():
    A = allocation_matrix(F550)
    pinv = np.linalg.pinv(A)
    torque = np.array([6.0, -4.0, 0.0])  # more than the rotors can give
    solution = mix(50.0, torque, pinv, F550.min_thrust, F550.max_thrust)
    achieved = A @ solution.rotor_thrust
    assert solution.roll_pitch_scale < 1.0
    assert achieved[1] / achieved[2] == pytest.approx(6.0 / -4.0, rel=1e-6)  # same direction
    assert achieved[1] > 0 and achieved[2] < 0
    assert solution.collective_shift < 0  # thrust given up for attitude
    assert np.all(solution.rotor_thrust <= F550.max_thrust + 1e-9)


# --- Commander on its own context -------------------------------------------------------------

def _commander():
    params = CommanderParams()
    dut = Commander(params, ThrustCurve.from_rotors(6, 9.0, 0.1), period=0.004)
    context = dut.CreateDefaultContext()
    dut.GetInputPort("fc_attitude").FixValue(context, FC_ATTITUDE.pack(
        stamp=0.0, q_WB=[1, 0, 0, 0], w_B=np.zeros(3)))
    dut.GetInputPort("vertical_velocity").FixValue(context, [0.0])
    return dut, context, Simulator(dut, context)


def _command(stamp, thrust=0.1, arm=1.0, mode=CommandMode.ATTITUDE_THRUST, q=(1, 0, 0, 0),
             w=(0, 0, 0)):
    return FC_COMMAND.pack(stamp=stamp, mode=mode, q_WD=q, w_D=w, thrust=thrust, arm=arm)


def _status(dut, context):
    return dut.GetOutputPort("fc_status").Eval(context)


@pytest.mark.parametrize("bad, reason", [
    (dict(thrust=np.nan), Refusal.NOT_FINITE),
    (dict(q=(np.inf, 0, 0, 0)), Refusal.NOT_FINITE),
    (dict(mode=7), Refusal.BAD_MODE),
    (dict(thrust=1.3), Refusal.THRUST_RANGE),
    (dict(q=(2.0, 0, 0, 0)), Refusal.QUATERNION_NORM),
    (dict(w=(0, 0, 40.0)), Refusal.BODY_RATE_RANGE),
    (dict(arm=0.5), Refusal.ARM_FLAG),
])
def test_bad_command_is_refused_and_previous_holds(bad, reason):
    dut, context, simulator = _commander()
    dut.GetInputPort("fc_command").FixValue(context, _command(0.0, thrust=0.1))
    simulator.AdvanceTo(0.1)
    assert _status(dut, context)[FC_STATUS.slice("armed")] == 1.0
    dut.GetInputPort("fc_command").FixValue(context, _command(0.1, **{"thrust": 0.1, **bad}))
    simulator.AdvanceTo(0.2)
    status = _status(dut, context)
    assert FC_STATUS.get(status, "refused") == 1  # counted once per message, not per tick
    assert FC_STATUS.get(status, "last_refusal") == reason
    setpoint = dut.GetOutputPort("setpoint").Eval(context)
    assert np.all(np.isfinite(setpoint))
    assert setpoint[5 + 3] == pytest.approx(0.1)  # the previous thrust holds
    assert FC_STATUS.get(status, "armed") == 1.0


def test_stale_command_enters_failsafe_descent_with_level_attitude():
    dut, context, simulator = _commander()
    tilted = RollPitchYaw(0.3, 0.0, 1.0).ToQuaternion().wxyz()
    dut.GetInputPort("fc_command").FixValue(context, _command(0.0, thrust=0.05))
    simulator.AdvanceTo(0.05)
    dut.GetInputPort("fc_command").FixValue(context, _command(0.05, thrust=0.7, q=tilted))
    simulator.AdvanceTo(0.5)
    assert FC_STATUS.get(_status(dut, context), "mode") == ActiveMode.ATTITUDE_THRUST
    simulator.AdvanceTo(0.6)  # 0.55 s after the last command
    status = _status(dut, context)
    assert FC_STATUS.get(status, "mode") == ActiveMode.FAILSAFE_DESCENT
    assert FC_STATUS.get(status, "link_alive") == 0.0
    setpoint = dut.GetOutputPort("setpoint").Eval(context)
    rpy = RollPitchYaw(Quaternion(setpoint[1:5]))
    assert abs(rpy.roll_angle()) < 1e-9 and abs(rpy.pitch_angle()) < 1e-9
    # At rest vertically the loop asks for less than hover thrust: the vehicle descends.
    assert setpoint[8] < CommanderParams().hover_thrust


def _feed(dut, context, simulator, until, **command):
    """Sends a fresh command (stamped now) every 20 ms until `until`."""
    while context.get_time() < until - 1e-9:
        dut.GetInputPort("fc_command").FixValue(context, _command(context.get_time(), **command))
        simulator.AdvanceTo(min(until, context.get_time() + 0.02))


def test_arming_needs_low_thrust_and_a_fresh_request_after_auto_disarm():
    dut, context, simulator = _commander()
    _feed(dut, context, simulator, 0.2, thrust=0.6)
    assert FC_STATUS.get(_status(dut, context), "armed") == 0.0  # refuses to arm at 60 %
    _feed(dut, context, simulator, 0.4, thrust=0.0)
    assert FC_STATUS.get(_status(dut, context), "armed") == 1.0
    # On the ground with zero thrust: the land detector disarms after land_time ...
    _feed(dut, context, simulator, 2.1, thrust=0.0)
    assert FC_STATUS.get(_status(dut, context), "armed") == 1.0
    _feed(dut, context, simulator, 2.4, thrust=0.0)
    assert FC_STATUS.get(_status(dut, context), "armed") == 0.0
    assert FC_STATUS.get(_status(dut, context), "landed") == 1.0
    # ... and a held arm request does not re-arm; dropping and raising it does.
    _feed(dut, context, simulator, 3.0, thrust=0.0)
    assert FC_STATUS.get(_status(dut, context), "armed") == 0.0
    _feed(dut, context, simulator, 3.1, thrust=0.0, arm=0.0)
    _feed(dut, context, simulator, 3.2, thrust=0.0, arm=1.0)
    assert FC_STATUS.get(_status(dut, context), "armed") == 1.0
    assert FC_STATUS.get(_status(dut, context), "refused") == 0


# --- Full vehicle ----------------------------------------------------------------------------

class NanInjector(LeafSystem):
    """Passes fc_command through, but puts NaN in its thrust in [t0, t1)."""

    def __init__(self, t0, t1):
        super().__init__()
        self._t0, self._t1 = t0, t1
        self._in = self.DeclareVectorInputPort("in", FC_COMMAND.size)
        self.DeclareVectorOutputPort("out", FC_COMMAND.size, self._calc)

    def _calc(self, context, output):
        command = self._in.Eval(context).copy()
        if self._t0 <= context.get_time() < self._t1:
            command[FC_COMMAND.slice("thrust")] = np.nan
        output.SetFromVector(command)


def test_nan_commands_in_flight_are_refused_and_the_vehicle_keeps_flying(vehicle_config, tmp_path):
    flight = profile(TAKEOFF + "{duration: 3.0}")
    builder = DiagramBuilder()
    vehicle = builder.AddSystem(make_sim_vehicle(vehicle_config))
    pilot = builder.AddSystem(ScriptedPilot(flight, pilot_model(vehicle_config.airframe)))
    injector = builder.AddSystem(NanInjector(TAKEOFF_END + 0.5, TAKEOFF_END + 0.9))
    builder.Connect(pilot.get_output_port(), injector.get_input_port())
    builder.Connect(injector.get_output_port(), vehicle.GetInputPort("fc_command"))
    loggers = add_run_logging(builder, vehicle, injector.get_output_port())
    diagram = builder.Build()
    simulator = simulate(diagram, flight.duration, seed=3)
    run = read_run(write_run_folder(tmp_path / "run", loggers, simulator, {}))
    truth = run["ground_truth"].drop(columns="time").to_numpy().T
    status = run["fc_status"].drop(columns="time").to_numpy().T
    t = run["ground_truth"]["time"].to_numpy()
    assert np.all(np.isfinite(truth[GROUND_TRUTH.slice("motor_command")]))
    assert status[FC_STATUS.slice("refused")][0, -1] >= 19  # one per 20 ms message for 0.4 s
    assert status[FC_STATUS.slice("last_refusal")][0, -1] == Refusal.NOT_FINITE
    assert np.all(status[FC_STATUS.slice("armed")][0, t > 1.0] == 1.0)
    # Shorter than the stale timeout: no failsafe, the last valid (hover) command holds.
    assert np.all(status[FC_STATUS.slice("mode")] != ActiveMode.FAILSAFE_DESCENT)
    z = truth[GROUND_TRUTH.slice("p_WB")][2]
    during = (t > TAKEOFF_END) & (t < TAKEOFF_END + 2.5)
    assert np.ptp(z[during]) < 0.3


def test_command_loss_triggers_failsafe_descent_landing_and_disarm(vehicle_config, tmp_path):
    stop = TAKEOFF_END + 0.5
    run = fly_profile(vehicle_config, profile(TAKEOFF + "{duration: 1.0}"), seed=1,
                      run_dir=tmp_path / "loss", pilot_stops_at=stop, duration=stop + 8.0)
    status = run["fc_status"]
    failsafe = status["time"][status["mode"] == ActiveMode.FAILSAFE_DESCENT]
    assert len(failsafe) and stop + 0.45 <= failsafe.iloc[0] <= stop + 0.6
    truth = run["ground_truth"]
    after = truth["time"] > failsafe.iloc[0]
    vz = truth["v_WB_2"][after]
    assert vz.min() > -1.6  # a controlled descent at about the configured 1 m/s
    z = truth["p_WB_2"].to_numpy()
    assert z[-1] < z[0] + 0.02  # on the ground
    assert status["armed"].iloc[-1] == 0.0 and status["landed"].iloc[-1] == 1.0
    assert tilt_deg(run.field("ground_truth", "q_WB").to_numpy()[after.to_numpy()]).max() < 10
