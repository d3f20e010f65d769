"""SO(3) force tracking M(17)-(31), the disturbance integrators M(35)-(37) and the MPC's QP
M(40)-(51), each on its own (no simulation)."""
import dataclasses as dc

import numpy as np
import pytest

from alight.systems.control import disturbance
from alight.systems.control.disturbance import DISTURBANCE, DisturbanceGains, DisturbanceLimits
from alight.systems.control.mpc_force import MpcForceParams, MpcForceQp, prediction
from alight.systems.control.so3 import (So3Params, body_rate_command, desired_orientation,
                                        heading_rate, jerk_feedforward, rotation_error,
                                        yaw_rate_for_heading_rate)
from alight.systems.rotations import heading
from alight.systems.thrust_curve import GRAVITY


def tilted_force(tilt_deg: float, azimuth_deg: float, magnitude: float = 30.0) -> np.ndarray:
    tilt, azimuth = np.radians(tilt_deg), np.radians(azimuth_deg)
    return magnitude * np.array([np.sin(tilt) * np.cos(azimuth), np.sin(tilt) * np.sin(azimuth),
                                 np.cos(tilt)])


@pytest.mark.parametrize("azimuth", [30.0, 45.0, 60.0, 120.0])
def test_heading_compliant_orientation_keeps_heading_at_30_degrees_tilt(azimuth):
    """M(21)-(23) give exactly the commanded heading; M(18)-(19) miss it by degrees when the
    force tilts away from the heading direction (M Sec. 5.1)."""
    f_d = tilted_force(30.0, azimuth)
    eta_d = 0.0
    R_new = desired_orientation(f_d, eta_d, heading_compliant=True)
    R_old = desired_orientation(f_d, eta_d, heading_compliant=False)
    for R in (R_new, R_old):
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
        np.testing.assert_allclose(R[:, 2], f_d / np.linalg.norm(f_d), atol=1e-12)
    assert abs(np.degrees(heading(R_new) - eta_d)) < 1e-9
    error_old = abs(np.degrees(heading(R_old) - eta_d))
    # At 30 deg tilt toward 45 deg azimuth M(18)-(19) is 4.1 deg off heading.
    assert error_old > 1.5, error_old


def test_rotation_error_and_rate_command_turn_toward_desired():
    R_d = desired_orientation(tilted_force(20.0, 10.0), 0.3)
    np.testing.assert_allclose(rotation_error(R_d, R_d), 0.0, atol=1e-12)
    params = So3Params()
    R = desired_orientation(tilted_force(0.0, 0.0), 0.3)  # level, same heading
    omega = body_rate_command(R, R_d, params, np.zeros(3), 0.0)
    # Integrating the commanded rates briefly reduces the attitude error.
    from scipy.linalg import expm
    hat = lambda w: np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
    R_next = R @ expm(hat(omega) * 0.02)
    assert np.linalg.norm(rotation_error(R_d, R_next)) < np.linalg.norm(rotation_error(R_d, R))
    assert np.all(np.abs(omega) <= np.asarray(params.max_rate) + 1e-12)


def test_jerk_feedforward_matches_finite_differences_of_desired_orientation():
    """M(26): along a reference with jerk, omega_j is the rate at which R_d's b3 turns."""
    m_e = 2.5
    t = np.linspace(0.0, 1.0, 1001)
    dt = t[1] - t[0]
    # a(t) = [2 sin(3t), cos(2t), 0.5 t]; jerk = derivative.
    acc = np.column_stack([2 * np.sin(3 * t), np.cos(2 * t), 0.5 * t])
    jerk = np.column_stack([6 * np.cos(3 * t), -2 * np.sin(2 * t), 0.5 * np.ones_like(t)])
    i = 500
    f = lambda k: m_e * (acc[k] + GRAVITY * np.array([0, 0, 1.0]))
    R_d = desired_orientation(f(i), 0.2)
    b3_dot = (f(i + 1) / np.linalg.norm(f(i + 1)) - f(i - 1) / np.linalg.norm(f(i - 1))) / (2 * dt)
    omega_j = jerk_feedforward(np.linalg.norm(f(i)), m_e, R_d, jerk[i])
    # d b3/dt = R_d (omega x e3).
    np.testing.assert_allclose(R_d @ np.cross(omega_j, [0, 0, 1.0]), b3_dot, atol=1e-4)


@pytest.mark.parametrize("tilt", [0.0, 25.0, 45.0])
def test_heading_rate_feedforward_and_parasitic_compensation(tilt):
    """M(27)-(31) realize the reference heading rate, and the M Sec. 5.3 compensation cancels the
    heading rate that the tilt correction would add: the resulting heading rate M(15) is the
    reference's (the heading feedback k_R[2] is off here to isolate the feedforward)."""
    R = desired_orientation(tilted_force(tilt, 70.0), 0.4)
    eta_rate = 0.8
    w3 = yaw_rate_for_heading_rate(R, eta_rate)
    assert heading_rate(R, np.array([0.0, 0.0, w3])) == pytest.approx(eta_rate, rel=1e-9)
    R_d = desired_orientation(tilted_force(tilt + 10.0, 100.0), 0.4)
    params = So3Params(k_R=[6.0, 6.0, 0.0], max_rate=[6.0, 6.0, 6.0])
    omega = body_rate_command(R, R_d, params, np.zeros(3), eta_rate)
    assert heading_rate(R, omega) == pytest.approx(eta_rate, abs=1e-9)
    if tilt > 0.0:  # without the compensation the tilt correction turns the heading
        uncompensated = omega.copy()
        uncompensated[2] = w3
        assert abs(heading_rate(R, uncompensated) - eta_rate) > 0.05


def test_disturbance_integrators_rotate_with_heading_and_clamp():
    gains, limits = DisturbanceGains(world=[1.0, 1.0], body=[2.0, 2.0], mass=0.5), \
        DisturbanceLimits(world=1.0, body=10.0, mass=0.3)
    state = np.zeros(DISTURBANCE.size)
    eta = np.pi / 2
    for _ in range(100):   # 1 s of a 0.5 m error along +x, 0.2 m below the reference
        state = disturbance.integrate(state, np.array([0.5, 0.0, -0.2]), eta, 0.01, gains, limits)
    d_w, d_b = disturbance.forces(state, eta)
    np.testing.assert_allclose(d_w, [0.5, 0.0, 0.0], atol=1e-9)
    # Body sum: the error in the heading frame is along -y_H; rotated back it is along +x in W.
    np.testing.assert_allclose(d_b, [1.0, 0.0, 0.0], atol=1e-9)
    assert disturbance.estimated_mass(2.5, state) == pytest.approx(2.6)  # sagging: heavier
    for _ in range(1000):  # anti-windup
        state = disturbance.integrate(state, np.array([0.5, 0.0, -0.2]), eta, 0.01, gains, limits)
    assert disturbance.forces(state, eta)[0][0] == pytest.approx(1.0)
    assert disturbance.estimated_mass(2.5, state) == pytest.approx(2.8)


def test_mpc_prediction_matches_simulated_model():
    dt, n = 0.05, 6
    Phi, Gamma = prediction(dt, n)
    x0, u = np.array([1.0, -0.5, 0.3]), np.linspace(-1, 1, n)
    x = x0.copy()
    A = np.array([[1.0, dt, dt * dt / 2], [0.0, 1.0, dt], [0.0, 0.0, 0.0]])
    for i in range(n):
        x = A @ x + np.array([0, 0, 1.0]) * u[i]
        np.testing.assert_allclose((Phi @ x0 + Gamma @ u)[3 * i:3 * i + 3], x, atol=1e-12)


@pytest.mark.parametrize("solver", ["daqp", "clarabel", "osqp"])
def test_mpc_qp_respects_speed_acceleration_and_jerk_bounds_after_a_5_m_error(solver):
    """M(46)-(51): a 5 m position error (an estimator jump) gives a plan within 2 m/s, 2 m/s^2
    and 5 m/s^3 that heads back toward the reference."""
    p = MpcForceParams(solver=solver)
    qp = MpcForceQp(p, control_period=0.01)
    x0 = qp.initial_state(np.array([5.0, 0.0, 0.0]), np.zeros(3), np.zeros(3))
    ok, u, _ = qp.solve(x0, np.zeros(3))
    assert ok
    assert u[0, 0] < 0.0                             # accelerates back toward the reference
    assert np.all(np.abs(u) <= 2.0 + 1e-4)
    assert np.all(np.abs(np.diff(u, axis=1)) <= 5.0 * p.model_period + 1e-4)
    assert abs(u[0, 0]) <= 5.0 * 0.01 + 1e-4         # first step slew against u_prev = 0
    states = (qp.Phi @ x0[0] + qp.Gamma @ u[0]).reshape(-1, 3)
    assert np.all(np.abs(states[:, 1]) <= 2.0 + 1e-3)  # soft speed bound held
    np.testing.assert_allclose(u[1:], 0.0, atol=1e-4)   # y, z: no error, no action


def test_mpc_qp_on_daqp_lands_on_the_optimum_that_clarabel_reaches_at_tight_tolerance():
    """The default back end (warm-started DAQP) solves the same program: over errors of 0-5 m and
    0-3 m/s, each tick warm-started from the last, its inputs are within 1e-3 m/s^2 of
    Clarabel's at 1e-9 tolerance (measured 3.5e-4; Clarabel at its default 1e-5: 1.9e-2)."""
    rng = np.random.default_rng(3)
    daqp_qp = MpcForceQp(MpcForceParams(solver="daqp"), control_period=0.01)
    exact = MpcForceQp(MpcForceParams(solver="clarabel", solver_tolerance=1e-9), 0.01)
    u_prev = np.zeros(3)
    for k in range(60):
        e_p = rng.normal(size=3) * 5.0 * (k % 20) / 19.0
        x0 = exact.initial_state(e_p, rng.uniform(-3, 3, 3), u_prev)
        (ok, u, _), (ok_exact, u_exact, _) = daqp_qp.solve(x0, u_prev), exact.solve(x0, u_prev)
        assert ok and ok_exact
        np.testing.assert_allclose(u, u_exact, atol=1e-3)
        u_prev = u_exact[:, 0]


def test_disturbance_integrators_ignore_errors_larger_than_max_error():
    """An estimator jump must not wind the integrators up."""
    gains, limits = DisturbanceGains(), DisturbanceLimits(max_error=1.0)
    state = disturbance.integrate(np.zeros(DISTURBANCE.size), np.array([5.0, 0.0, -3.0]), 0.0,
                                  0.01, gains, limits)
    np.testing.assert_array_equal(state, 0.0)


def test_advance_reference_follows_the_circle_to_within_a_micrometre():
    """A chi handed over one 10 ms tick late is moved to the tick time along its own v, a, j
    (the force controllers do this with the reference's stamp)."""
    from alight.systems.boundary import REFERENCE
    from alight.systems.control.analytic_reference import AnalyticReference, Circle, Trajectory
    from alight.systems.control.force_controller import advance_reference
    chi = AnalyticReference(Trajectory([Circle(np.zeros(3), 5.0, 7.0, 2.0, 1.0, True)])).chi
    advanced = advance_reference(chi(3.0), 0.01)
    np.testing.assert_allclose(REFERENCE.get(advanced, "p"), REFERENCE.get(chi(3.01), "p"),
                               atol=1e-6)
    np.testing.assert_allclose(REFERENCE.get(advanced, "v"), REFERENCE.get(chi(3.01), "v"),
                               atol=1e-4)
    assert REFERENCE.get(advanced, "heading") == pytest.approx(
        REFERENCE.get(chi(3.01), "heading"), abs=1e-9)
    assert REFERENCE.get(advanced, "stamp") == pytest.approx(3.01)


def test_controller_tilts_by_the_flight_controller_attitude_with_the_estimate_heading():
    """With `fc_attitude` connected the orientation is the flight controller's tilt turned to the
    estimate's heading (M footnote 18, M(12)-(14)); a non-finite message falls back to the
    estimate's own orientation. Seen through the roll rate that levels a hovering vehicle."""
    from alight.diagrams.onboard.controllers import (DisturbanceSources,
                                                     load_controllers_config, make_controller)
    from alight.systems.boundary import (FC_ATTITUDE, FC_COMMAND, REFERENCE, STATE_ESTIMATE,
                                         CommandMode)
    from alight.systems.rotations import heading_quaternion, quaternion_product
    dut = make_controller("se3", load_controllers_config())
    context = dut.CreateDefaultContext()
    eta = 0.7
    dut.GetInputPort("state_estimate").FixValue(context, STATE_ESTIMATE.vector(
        p_EB=[0, 0, 2.0], q_EB=heading_quaternion(eta), heading=eta))
    dut.GetInputPort("reference").FixValue(context, REFERENCE.pack(
        stamp=0.0, p=[0, 0, 2.0], v=np.zeros(3), a=np.zeros(3), j=np.zeros(3), heading=eta,
        heading_rate=0.0))
    dut.GetInputPort("active").FixValue(context, [1.0])
    dut.GetInputPort("last_command").FixValue(context, FC_COMMAND.pack(
        stamp=0.0, mode=CommandMode.RATES_THRUST, q_WD=[1, 0, 0, 0], w_D=np.zeros(3),
        thrust=0.64, arm=1.0))
    # The flight controller's frame differs in heading by 2 rad; its body is rolled 10 deg.
    roll = np.radians(10.0)
    q_fc = quaternion_product(heading_quaternion(eta - 2.0),
                              np.array([np.cos(roll / 2), np.sin(roll / 2), 0.0, 0.0]))

    def roll_rate(fc_attitude):
        dut.GetInputPort("fc_attitude").FixValue(context, fc_attitude)
        context.SetDiscreteState(dut.EvalUniquePeriodicDiscreteUpdate(context))
        return FC_COMMAND.get(dut.GetOutputPort("fc_command").Eval(context), "w_D")

    tilted = FC_ATTITUDE.pack(stamp=0.0, q_WB=q_fc, w_B=np.zeros(3))
    w_D = roll_rate(tilted)
    assert w_D[0] == pytest.approx(-6.0 * np.sin(roll), rel=0.05)   # -k_R e_R, M(25)
    assert abs(w_D[1]) < 0.02 and abs(w_D[2]) < 0.02   # no yaw: the heading is the estimate's
    w_D = roll_rate(np.full(FC_ATTITUDE.size, np.nan))
    np.testing.assert_allclose(w_D, 0.0, atol=1e-6)


def _active_at(dut, p_ref, thrust: float):
    """A context of the force controller `dut`, active on a hover reference at `p_ref`, taking
    over from a level rates command at `thrust`."""
    from alight.systems.boundary import FC_COMMAND, REFERENCE, CommandMode
    context = dut.CreateDefaultContext()
    dut.GetInputPort("reference").FixValue(context, REFERENCE.pack(
        stamp=0.0, p=p_ref, v=0.0, a=0.0, j=0.0, heading=0.0, heading_rate=0.0))
    dut.GetInputPort("active").FixValue(context, [1.0])
    dut.GetInputPort("last_command").FixValue(context, FC_COMMAND.pack(
        stamp=0.0, mode=CommandMode.RATES_THRUST, q_WD=[1, 0, 0, 0], w_D=np.zeros(3),
        thrust=thrust, arm=1.0))
    return context


@pytest.mark.parametrize("name", ["se3", "mpc"])
def test_integrators_hold_while_the_tracker_reports_admittance(name):
    """M Sec. 4.2: a vehicle held down 0.5 m below its reference (the landoff tracker's
    admittance) is not heavier: with `tracker_status` ADMITTANCE_HOLD the mass estimate M(37)
    stays; with the tracker taking off it learns the sag (before the hold it wound the thrust to
    its limit on a tethered take-off, docs/benchmarks.md)."""
    from alight.diagrams.onboard.controllers import (DisturbanceSources,
                                                     load_controllers_config, make_controller)
    from alight.systems.boundary import ADMITTANCE_HOLD, STATE_ESTIMATE, TRACKER_STATUS
    from alight.systems.control.disturbance import DISTURBANCE_ESTIMATE
    from alight.systems.tracking.chi_tracker import ChiReason
    config = load_controllers_config()
    dut = make_controller(name, config)

    def mass_after(reason, ticks=200):
        context = _active_at(dut, [0, 0, 0.7], thrust=0.0)
        dut.GetInputPort("state_estimate").FixValue(context,
                                                    STATE_ESTIMATE.vector(p_EB=[0, 0, 0.2]))
        dut.GetInputPort("tracker_status").FixValue(context, TRACKER_STATUS.pack(
            valid=1.0, reason=reason, solver_status=0.0))
        for _ in range(ticks):
            context.SetTime(context.get_time() + dut.period)
            context.SetDiscreteState(dut.EvalUniquePeriodicDiscreteUpdate(context))
        return DISTURBANCE_ESTIMATE.get(dut.GetOutputPort("disturbance_estimate").Eval(context),
                                        "m_e")

    nominal = config.vehicle.mass
    assert ChiReason.ADMITTANCE == ADMITTANCE_HOLD
    assert mass_after(ChiReason.ADMITTANCE) == pytest.approx(nominal, abs=1e-9)
    assert mass_after(ChiReason.TAKING_OFF) > nominal + 0.05   # 0.5 m sag learnt as mass


@pytest.mark.parametrize("name", ["se3", "mpc"])
def test_the_measured_acceleration_gives_the_side_force_within_a_second(name):
    """Beyond M(35): a vehicle at its reference, rolled 10 deg and not accelerating, is held there
    by a side force (wind). With `disturbance_source: acceleration` the controller measures that
    force from the estimate's acceleration and keeps the tilt that balances it (its desired
    roll within 1 deg of 10 after 0.6 s); with the integrators alone (`integrators`, M) nothing
    moves them at zero position error and it commands the vehicle level, to be blown away
    before the position error teaches them."""
    from alight.diagrams.onboard.controllers import (DisturbanceSources,
                                                     load_controllers_config, make_controller)
    from alight.systems.boundary import FC_COMMAND, STATE_ESTIMATE
    from alight.systems.rotations import rotation_matrix

    def desired_roll(source):
        config = dc.replace(load_controllers_config(), disturbance_source=dc.replace(
            DisturbanceSources(), **{name: source}))
        dut = make_controller(name, config)
        context = _active_at(dut, [0, 0, 2.0], thrust=0.66)
        roll = np.radians(10.0)
        for _ in range(60):
            context.SetTime(context.get_time() + dut.period)
            dut.GetInputPort("state_estimate").FixValue(context, STATE_ESTIMATE.vector(
                stamp=context.get_time(), p_EB=[0, 0, 2.0], a_EB=np.zeros(3),
                q_EB=[np.cos(roll / 2), np.sin(roll / 2), 0.0, 0.0]))
            context.SetDiscreteState(dut.EvalUniquePeriodicDiscreteUpdate(context))
        R_WD = rotation_matrix(FC_COMMAND.get(dut.GetOutputPort("fc_command").Eval(context),
                                              "q_WD"))
        return np.degrees(np.arctan2(R_WD[2, 1], R_WD[2, 2]))

    assert desired_roll("acceleration") == pytest.approx(10.0, abs=1.0)
    assert abs(desired_roll("integrators")) < 1.0


def test_each_force_controller_resolves_its_own_disturbance_source():
    """models/controllers.yaml: the MPC controller measures the external force on VIO (`auto`),
    the SE(3) controller keeps M's integrators; on mocap both fly the integrators alone."""
    from alight.diagrams.onboard.controllers import (load_controllers_config,
                                                     resolve_force_disturbance)
    config = load_controllers_config()
    assert (config.disturbance_source.se3, config.disturbance_source.mpc) == \
        ("integrators", "auto")
    on_vio = resolve_force_disturbance(config, "vio").disturbance_source
    assert (on_vio.se3, on_vio.mpc) == ("integrators", "acceleration")
    on_mocap = resolve_force_disturbance(config, "mocap").disturbance_source
    assert (on_mocap.se3, on_mocap.mpc) == ("integrators", "integrators")
