"""Landing on the estimator bank (M Sec. 3.1.1 input, 3.1.2 rangefinder): ground contact, the
clipped rangefinder, the active controller's own M(53) as the bank's input, and the managed stack
flown on the bank from take-off to a disarmed landing."""
import numpy as np
import pytest
from pydrake.math import RotationMatrix
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder, LeafSystem

from alight.diagrams.onboard.estimation import BankOdometry, load_bank_params
from alight.diagrams.onboard.mpc_loop import load_linear_model
from alight.diagrams.running.mission import Mission
from alight.systems.boundary import FC_ATTITUDE, FC_STATUS, STATE_ESTIMATE
from alight.systems.control.controller import level_command
from alight.systems.control.force_controller import VehicleModel
from alight.systems.estimation.bank import EstimatorBank
from alight.systems.estimation.command_acceleration import CommandAcceleration
from alight.systems.estimation.heading import rotation_z
from alight.systems.estimation.measurements import RANGE
from alight.systems.managers.control_manager import ControlManager, ManagerMode
from alight.systems.params import ConfigError
from alight.systems.thrust_curve import GRAVITY

REST = 0.22   # m: the F550's body origin above the ground on its legs
BANK = """
period: 0.01
sources: [{name: rangefinder, kind: range, timeout: 0.3, gate_action: {action}}]
filters: [{name: height, frame_id: 1, fuse: [rangefinder.height, fc.heading]}]
ground: {source: {ground}, height: 0.3}
"""


class Level(LeafSystem):
    """fc_attitude of a level vehicle at heading `eta`."""

    def __init__(self, eta=0.0):
        super().__init__()
        q = RotationMatrix(rotation_z(eta)).ToQuaternion().wxyz()
        self.DeclareVectorOutputPort("fc_attitude", FC_ATTITUDE.size, lambda context, out: (
            out.SetFromVector(FC_ATTITUDE.pack(stamp=context.get_time(), q_WB=q, w_B=0.0))))


class Ranges(LeafSystem):
    """A 2 cm rangefinder reading `height(t)` at 50 Hz (seeded noise per sample)."""

    def __init__(self, height):
        super().__init__()
        self._height = height
        self.DeclareVectorOutputPort("range", RANGE.size, self._calc)

    def _calc(self, context, output):
        k = int(context.get_time() / 0.02 + 1e-9)
        noise = np.random.default_rng(k).standard_normal() * 0.02
        output.SetFromVector(RANGE.pack(stamp=k * 0.02, range=self._height(k * 0.02) + noise,
                                        var=0.02 ** 2, valid=1.0))


def _rest_on_the_ground(ground: str, action: str, u_z, seconds: float = 5.0,
                        height=lambda t: REST):
    """The bank fed a rangefinder reading `height(t)` and a vertical input `u_z` (or `u_z(t)`;
    downward: what the landing controller's command implies while it still pushes down): the
    filter's height and vertical velocity every 50 ms from 0.5 s, and on_ground at the end."""
    params = load_bank_params(data=BANK.replace("{ground}", ground).replace("{action}", action))
    builder = DiagramBuilder()
    dut = builder.AddSystem(EstimatorBank(params))
    builder.Connect(builder.AddSystem(Level()).get_output_port(), dut.GetInputPort("fc_attitude"))
    builder.Connect(builder.AddSystem(Ranges(height)).get_output_port(),
                    dut.GetInputPort("rangefinder"))
    diagram = builder.Build()
    simulator = Simulator(diagram)
    context = dut.GetMyContextFromRoot(simulator.get_mutable_context())
    z, v = [], []
    for t in np.arange(0.0, seconds, 0.05):
        dut.GetInputPort("desired_acceleration").FixValue(
            context, [0.0, 0.0, u_z(t) if callable(u_z) else u_z])
        simulator.AdvanceTo(t + 0.05)
        status = dut.GetOutputPort("bank_status").Eval(context)   # the filter's own z
        z.append(dut.status.get(status, "height_p")[2])
        v.append(dut.status.get(status, "height_v")[2])
    return np.array(z), np.array(v), dut.status.get(status, "on_ground")


# The stand-in's input on the ground: the MPC force controller still holding 0.8 of the weight
# (its 1.8 m/s^2 bound) is -2 m/s^2; at 0.5 of the hover thrust -3.3 m/s^2; the clip holds to
# -7.4 (0.25 of the weight, where the stand-in gives zero).
@pytest.mark.parametrize("u_z", [-2.0, -3.3, -7.4])
def test_on_the_ground_the_bank_does_not_integrate_the_descent_the_ground_prevents(u_z):
    z, v, on_ground = _rest_on_the_ground("rangefinder", "clip", u_z)
    print(f"u_z {u_z}: height error max {np.abs(z - REST).max():.3f} m, |v_z| max "
          f"{np.abs(v).max():.3f} m/s")
    assert on_ground == 1.0
    assert np.abs(z - REST).max() < 0.04        # 2 cm rangefinder
    assert abs(v[20:].mean()) < 0.03 and np.abs(v).max() < 0.25   # unbiased: noise only


def test_without_ground_contact_the_gate_shuts_the_rangefinder_out_and_the_estimate_falls():
    """The measured failure (docs/flight_stack.md, Known limits, before): the prediction runs
    away, every rangefinder reading then fails the gate and is rejected."""
    z, _, on_ground = _rest_on_the_ground("''", "reject", -5.0)
    print(f"no ground contact, rejecting: {z[-1] - REST:.1f} m after 5 s")
    assert on_ground == 0.0 and z[-1] < REST - 5.0
    z, v, _ = _rest_on_the_ground("''", "clip", -5.0)   # clipped: bounded, but biased
    print(f"no ground contact, clipping: height error max {np.abs(z - REST).max():.3f} m, "
          f"v_z mean {v[20:].mean():.2f} m/s")
    assert np.abs(z - REST).max() < 0.15 and v[20:].mean() < -0.3


def test_ground_contact_ends_when_the_vehicle_lifts_off():
    """Spool-up on the ground (the input says -2 m/s^2), then a 1 m/s^2 climb from 1 s."""
    z, v, on_ground = _rest_on_the_ground(
        "rangefinder", "clip", lambda t: -2.0 if t < 1.0 else 1.0, 3.0,
        height=lambda t: REST + max(0.0, t - 1.0) ** 2 / 2)
    t = np.arange(1, len(z) + 1) * 0.05
    print(f"climb: height error at 3 s {z[-1] - REST - 2.0:.3f} m, v_z {v[-1]:.2f} m/s")
    assert on_ground == 0.0
    assert np.abs(z[t <= 1.0] - REST).max() < 0.04
    assert abs(z[-1] - (REST + 2.0)) < 0.05 and abs(v[-1] - 2.0) < 0.15


def test_a_ground_source_that_is_no_rangefinder_names_the_key():
    text = BANK.replace("{action}", "reject").replace("{ground}", "nope")
    with pytest.raises(ConfigError, match="ground.source"):
        load_bank_params(data=text)
    with pytest.raises(ConfigError, match="gate_action"):
        load_bank_params(data=BANK.replace("{action}", "ignore").replace("{ground}", "''"))


def _command_acceleration(a_E, heading_E, eta_o, landed=0.0):
    dut = CommandAcceleration(2.5, VehicleModel().curve)
    context = dut.CreateDefaultContext()
    thrust = float(VehicleModel().curve.thrust(2.5 * GRAVITY * 1.2))   # stand-in: +0.2 g
    dut.GetInputPort("fc_command").FixValue(context, level_command(0.0, 0.0, thrust, 1.0))
    dut.GetInputPort("fc_status").FixValue(context, FC_STATUS.pack(
        stamp=0.0, armed=1.0, mode=0.0, link_alive=1.0, last_command_stamp=0.0, refused=0.0,
        last_refusal=0.0, landed=landed))
    dut.GetInputPort("controller_acceleration").FixValue(context, a_E)
    dut.GetInputPort("state_estimate").FixValue(context, STATE_ESTIMATE.vector(heading=heading_E))
    dut.GetInputPort("fc_attitude").FixValue(context, FC_ATTITUDE.pack(
        stamp=0.0, q_WB=RotationMatrix(rotation_z(eta_o)).ToQuaternion().wxyz(), w_B=0.0))
    return dut.GetOutputPort("desired_acceleration").Eval(context)


def test_the_bank_takes_the_active_controllers_m53_turned_into_the_attitude_frame():
    # E is turned 0.5 rad from the attitude frame: a_E along x_E is along Rz(-0.5) x_o
    a = _command_acceleration([1.0, 0.0, -0.4], heading_E=0.7, eta_o=0.2)
    np.testing.assert_allclose(a, rotation_z(-0.5) @ [1.0, 0.0, -0.4], atol=1e-12)
    stand_in = _command_acceleration([np.nan] * 3, heading_E=0.7, eta_o=0.2)
    np.testing.assert_allclose(stand_in, [0.0, 0.0, 0.2 * GRAVITY], atol=1e-9)   # no M(53)
    np.testing.assert_array_equal(_command_acceleration([1.0, 0.0, -0.4], 0.7, 0.2, landed=1.0),
                                  np.zeros(3))


def test_the_control_manager_forwards_the_active_controllers_desired_acceleration():
    names = ["se3", "mpc", "failsafe"]
    dut = ControlManager(controllers=names, initial_controller="se3",
                         failsafe_controller="failsafe", emergency_controller="se3",
                         vehicle=VehicleModel(), period=0.01)
    context = dut.CreateDefaultContext()
    dut.GetInputPort("se3.desired_acceleration").FixValue(context, [0.1, 0.2, -0.3])
    np.testing.assert_array_equal(dut.GetOutputPort("desired_acceleration").Eval(context),
                                  [0.1, 0.2, -0.3])
    state = context.get_mutable_discrete_state(0).get_mutable_value()
    state[0] = 1   # `active` (the first field): mpc, whose port is not connected here
    assert np.all(np.isnan(dut.GetOutputPort("desired_acceleration").Eval(context)))


@pytest.mark.mission
def test_the_managed_stack_lands_on_the_bank_and_disarms_with_the_estimate_on_the_ground(
        tmp_path):
    """Take off, go 2 m, land, on the bank's own frames (the arbiter switches to RTK on the
    way): disarmed on the ground, the height estimate within 0.15 m of the truth from touchdown
    to the end, no emergency landing or failsafe."""
    odometry = BankOdometry(load_bank_params(), load_linear_model(), anchored=False)
    mission = Mission.simulated(seed=0, run_dir=tmp_path, strict=False, odometry=odometry,
                                log=odometry.log)
    with mission:
        assert mission.takeoff(1.5).done
        assert mission.goto([1.5, 1.0, 1.5]).done
        landing = mission.land(timeout=20.0)
    run = mission.run_log
    truth, estimate = run["ground_truth"], run["bank_estimate"]
    p_true = run.field("ground_truth", "p_WB").to_numpy()
    touchdown = truth["time"][(truth["time"] > 5.0) & (truth["p_WB_2"] < REST + 0.03)].iloc[0]
    after = estimate["time"].to_numpy() >= touchdown
    z_true = np.interp(estimate["time"], truth["time"], truth["p_WB_2"])
    error = np.abs(estimate["p_EB_2"].to_numpy() - z_true)[after]
    modes = set(run["manager_status"]["mode"].astype(int))
    print(f"landing {landing.duration:.1f} s (touchdown {touchdown:.2f} s, run "
          f"{truth['time'].iloc[-1]:.1f} s); height error after touchdown max {error.max():.3f} m;"
          f" modes {sorted(modes)}; bank switches {run['bank_status']['switches'].iloc[-1]:.0f}")
    assert landing.done and run["fc_status"]["armed"].iloc[-1] == 0.0
    assert p_true[-1, 2] < REST + 0.05
    assert error.max() < 0.15
    assert not modes & {ManagerMode.ELAND, ManagerMode.FAILSAFE, ManagerMode.LANDED}
