"""The landing paper's linear MPC closing the loop on any vehicle's boundary ports (L Sec. 6.1-6.2):
odometry (e.g. mocap, `mocap_odometry`) -> linear MPC -> arm gate -> `fc_command`
(`add_mpc_control`), and its logging."""
import dataclasses as dc

from pydrake.systems.primitives import ConstantVectorSource

from alight.diagrams.onboard.mocap import add_mocap
from alight.diagrams.running.run_log import RunLoggers, add_run_logging
from alight.models import model_path
from alight.systems.boundary import CONTROLLER_STATUS, REFERENCE, STATE_ESTIMATE
from alight.systems.control.arm_gate import ArmGate
from alight.systems.control.linear_model import LinearModelParams
from alight.systems.control.linear_mpc import MPC_DISTURBANCE, LinearMpc, LinearMpcParams
from alight.systems.params import load_params
from alight.systems.sensors.mocap import MocapParams


def load_linear_model(filename: str = "linear_model.yaml") -> LinearModelParams:
    return load_params(LinearModelParams, model_path(filename))


def load_linear_mpc(filename: str = "linear_mpc.yaml") -> LinearMpcParams:
    return load_params(LinearMpcParams, model_path(filename))


@dc.dataclass
class MpcLoop:
    """Handles to the parts of a closed MPC loop built by `add_mpc_loop`."""
    vehicle: object
    mpc: LinearMpc
    state_estimate_port: object
    command_port: object
    mpc_period: float


def mocap_odometry(params: MocapParams):
    """The odometry source of simulation: mocap (true pose + noise + latency)."""
    return lambda builder, vehicle: add_mocap(builder, vehicle.GetOutputPort("ground_truth"),
                                              params)


def add_mpc_control(builder, vehicle, reference_port, arm_port, mpc_params: LinearMpcParams,
                    model: LinearModelParams, odometry, estimate_filter=None) -> MpcLoop:
    """Onboard: odometry + linear MPC (+ arm gate) following `reference_port` and commanding
    `vehicle` through its boundary ports only (the simulated or the MAVLink vehicle).
    `odometry(builder, vehicle) -> STATE_ESTIMATE port` builds the state estimate
    (`mocap_odometry(params)`, simulation only; VIO, the estimator bank and the MAVLink side's
    channel mocap plug in here); an odometry with `connect_command(builder, port)` is also given
    the issued command; `estimate_filter(builder, port) -> port` may alter the estimate (fault
    injection in tests)."""
    estimate = odometry(builder, vehicle)
    if estimate_filter is not None:
        estimate = estimate_filter(builder, estimate)
    mpc = builder.AddNamedSystem("linear_mpc", LinearMpc(model, mpc_params))
    gate = builder.AddNamedSystem("arm_gate", ArmGate())
    active = builder.AddNamedSystem("mpc_active", ConstantVectorSource([1.0]))
    builder.Connect(estimate, mpc.GetInputPort("state_estimate"))
    builder.Connect(reference_port, mpc.GetInputPort("reference"))
    builder.Connect(active.get_output_port(), mpc.GetInputPort("active"))
    builder.Connect(vehicle.GetOutputPort("fc_attitude"), mpc.GetInputPort("fc_attitude"))
    builder.Connect(mpc.GetOutputPort("fc_command"), gate.GetInputPort("fc_command"))
    builder.Connect(arm_port, gate.GetInputPort("arm"))
    builder.Connect(gate.GetOutputPort("fc_command"), vehicle.GetInputPort("fc_command"))
    builder.Connect(gate.GetOutputPort("fc_command"), mpc.GetInputPort("last_command"))
    if hasattr(odometry, "connect_command"):  # e.g. the estimator bank's acceleration input
        odometry.connect_command(builder, gate.GetOutputPort("fc_command"))
    return MpcLoop(vehicle, mpc, estimate, gate.GetOutputPort("fc_command"), mpc_params.period)


def add_mpc_logging(builder, loop: MpcLoop, reference_port) -> RunLoggers:
    """The vehicle's streams plus the estimate, the reference and the controller status."""
    loggers = add_run_logging(builder, loop.vehicle, loop.command_port)
    loggers.add(builder, "state_estimate", loop.state_estimate_port, STATE_ESTIMATE)
    loggers.add(builder, "reference", reference_port, REFERENCE)
    loggers.add(builder, "controller_status", loop.mpc.GetOutputPort("controller_status"),
                CONTROLLER_STATUS, period=loop.mpc_period)
    loggers.add(builder, "mpc_disturbance", loop.mpc.GetOutputPort("disturbance"),
                MPC_DISTURBANCE, period=loop.mpc_period)
    return loggers
