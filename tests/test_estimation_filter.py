"""The filter and the bank on their own contexts: heading and heading rate at large tilt
(M(3)-(5), M(12)-(15)) against yaw-from-Euler, rejected non-finite and out-of-order messages,
configuration errors."""
import numpy as np
import pytest
from pydrake.math import RollPitchYaw, RotationMatrix
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder, LeafSystem
from scipy.spatial.transform import Rotation

from alight.diagrams.onboard.estimation import load_bank_params
from alight.systems.boundary import FC_ATTITUDE, STATE_ESTIMATE
from alight.systems.estimation.bank import EstimatorBank
from alight.systems.estimation.heading import heading_rate, rotation_z, with_heading
from alight.systems.estimation.measurements import POSITION_FIX
from alight.systems.params import ConfigError
from alight.systems.rotations import heading

BANK = """
period: 0.01
sources: [{name: fix, kind: position_fix, timeout: 10.0}]
filters:
  - {name: only, frame_id: 3, gate: {gate}, fuse: [fix.position, fc.heading, fc.heading_rate]}
"""
TILT = RollPitchYaw(np.radians(50.0), np.radians(35.0), 0.0).ToRotationMatrix().matrix()
RATE = 0.6  # rad/s about e3


class Tumbling(LeafSystem):
    """fc_attitude of a vehicle tilted 58 deg, turning about e3 at RATE: R(t) = Rz(RATE t) TILT."""

    def __init__(self):
        super().__init__()
        self.DeclareVectorOutputPort("fc_attitude", FC_ATTITUDE.size, self._calc)

    def _calc(self, context, output):
        t = context.get_time()
        R = rotation_z(RATE * t) @ TILT
        w_B = R.T @ np.array([0.0, 0.0, RATE])
        output.SetFromVector(FC_ATTITUDE.pack(
            stamp=t, q_WB=RotationMatrix(R).ToQuaternion().wxyz(), w_B=w_B))


class Messages(LeafSystem):
    """A position_fix message per `schedule` row (t_publish, stamp, p): the latest published."""

    def __init__(self, schedule):
        super().__init__()
        self._schedule = schedule
        self.DeclareVectorOutputPort("fix", POSITION_FIX.size, self._calc)

    def _calc(self, context, output):
        rows = [r for r in self._schedule if r[0] <= context.get_time() + 1e-9]
        if not rows:
            output.SetFromVector(POSITION_FIX.pack(stamp=0, p=np.zeros(3), var_p=np.ones(3),
                                                   valid=0))
            return
        _, stamp, p = rows[-1]
        output.SetFromVector(POSITION_FIX.pack(stamp=stamp, p=p, var_p=[0.01] * 3, valid=1))


def _bank_diagram(schedule, gate="true"):
    builder = DiagramBuilder()
    dut = builder.AddSystem(EstimatorBank(load_bank_params(data=BANK.replace("{gate}", gate))))
    attitude = builder.AddSystem(Tumbling())
    messages = builder.AddSystem(Messages(schedule))
    builder.Connect(attitude.get_output_port(), dut.GetInputPort("fc_attitude"))
    builder.Connect(messages.get_output_port(), dut.GetInputPort("fix"))
    diagram = builder.Build()
    return diagram, dut


def test_heading_and_heading_rate_at_large_tilt_match_the_truth_unlike_yaw():
    assert np.degrees(np.arccos(TILT[2, 2])) > 55.0
    schedule = [(k * 0.1, k * 0.1, [1.0, 2.0, 3.0]) for k in range(40)]
    diagram, dut = _bank_diagram(schedule)
    simulator = Simulator(diagram)
    context = dut.GetMyContextFromRoot(simulator.get_mutable_context())
    errors = []
    for t in np.arange(2.0, 4.0, 0.1):
        simulator.AdvanceTo(t)
        estimate = dut.GetOutputPort("state_estimate").Eval(context)
        R_true = rotation_z(RATE * t) @ TILT
        eta_true = heading(R_true)                   # M(3)
        yaw = Rotation.from_matrix(R_true).as_euler("ZXY")[0]  # yaw of a z-x-y Euler sequence
        w_B = R_true.T @ [0.0, 0.0, RATE]
        errors.append([np.angle(np.exp(1j * (STATE_ESTIMATE.get(estimate, "heading") - eta_true))),
                       STATE_ESTIMATE.get(estimate, "heading_rate") - RATE,
                       np.angle(np.exp(1j * (yaw - eta_true))), w_B[2] - RATE])
    heading_error, rate_error, yaw_error, w3_error = np.abs(np.array(errors)).max(axis=0)
    print(f"heading error {np.degrees(heading_error):.2f} deg vs Euler yaw "
          f"{np.degrees(yaw_error):.1f} deg; heading rate error {rate_error:.4f} rad/s vs omega_3 {w3_error:.3f} rad/s")
    assert np.degrees(heading_error) < 1.0 and rate_error < 0.02
    assert np.degrees(yaw_error) > 10.0 and w3_error > 0.2   # what the filter does not use
    # M(15) on its own and M(12)-(14): the orientation keeps b3 and takes the heading
    assert heading_rate(TILT, TILT.T @ [0, 0, RATE]) == pytest.approx(RATE, abs=1e-12)
    R = with_heading(TILT, 1.0)
    assert heading(R) == pytest.approx(1.0) and R[2, 2] == pytest.approx(TILT[2, 2])


def test_nan_and_out_of_order_messages_are_rejected_counted_and_never_fused():
    good = [1.0, 2.0, 3.0]
    schedule = [(0.1, 0.1, good), (0.2, 0.2, good), (0.3, 0.3, [np.nan, 2.0, 3.0]),
                (0.4, 0.15, [50.0, 50.0, 50.0]), (0.5, 0.5, good), (0.6, np.nan, good),
                (0.7, 0.7, [np.inf, 0, 0]), (0.8, 0.8, good)]
    diagram, dut = _bank_diagram(schedule, gate="false")   # no gate: only the checks protect
    simulator = Simulator(diagram)
    context = dut.GetMyContextFromRoot(simulator.get_mutable_context())
    worst = 0.0
    for t in np.arange(0.05, 1.0, 0.01):
        simulator.AdvanceTo(t)
        estimate = dut.GetOutputPort("state_estimate").Eval(context)
        assert np.all(np.isfinite(estimate))
        if STATE_ESTIMATE.get(estimate, "valid") > 0.5:
            worst = max(worst, np.abs(STATE_ESTIMATE.get(estimate, "p_EB") - good).max())
    status = dut.status
    values = dut.GetOutputPort("bank_status").Eval(context)
    assert status.get(values, "rejected_nan") == 3     # nan p, nan stamp, inf p
    assert status.get(values, "rejected_order") == 1   # the stamp 0.15 after 0.2
    assert worst < 0.05


@pytest.mark.parametrize("fuse, message", [
    ("[nope.position]", "source 'nope'"), ("[fix.velocity]", "not 'velocity'"),
    ("[fix.position.xw]", "axes 'xw'"), ("[fc.heading]", "no translational quantity")])
def test_a_bad_bank_file_names_the_key(fuse, message):
    text = BANK.replace("{gate}", "true").replace(
        "[fix.position, fc.heading, fc.heading_rate]", fuse)
    with pytest.raises(ConfigError, match="filters\\[0\\].fuse") as error:
        load_bank_params(data=text)
    assert message in str(error.value)
