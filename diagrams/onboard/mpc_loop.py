"""The landing paper's linear MPC closing the loop on any vehicle's boundary ports (L Sec. 6.1-6.2):
odometry (e.g. mocap, `mocap_odometry`) -> linear MPC -> failsafe switch -> arm gate ->
`fc_command` (`add_mpc_control`), and its logging.

The failsafe switch (systems/managers/failsafe_switch.py) is the control manager's fallback for
this stack without a manager: with the estimate lost, the MPC failing, a command that is not
usable or a control error beyond the reference's steps, the feedforward failsafe controller
(M Sec. 5.10) lands the vehicle from the last issued command and disarms it."""
import dataclasses as dc

from alight.diagrams.onboard.mocap import add_mocap
from alight.diagrams.running.run_log import RunLoggers, add_run_logging
from alight.models import model_path
from alight.systems.boundary import CONTROLLER_STATUS, REFERENCE, STATE_ESTIMATE
from alight.systems.control.arm_gate import ArmGate
from alight.systems.control.failsafe import FailsafeController
from alight.systems.control.force_controller import VehicleModel
from alight.systems.control.linear_model import LinearModelParams
from alight.systems.control.linear_mpc import MPC_DISTURBANCE, LinearMpc, LinearMpcParams
from alight.systems.managers.control_manager import MANAGER_STATUS
from alight.systems.managers.failsafe_switch import FailsafeSwitch, FailsafeSwitchParams
from alight.systems.params import load_params
from alight.systems.sensors.mocap import MocapParams


def load_linear_model(filename: str = "linear_model.yaml") -> LinearModelParams:
    return load_params(LinearModelParams, model_path(filename))


def load_linear_mpc(filename: str = "linear_mpc.yaml") -> LinearMpcParams:
    return load_params(LinearMpcParams, model_path(filename))


def load_failsafe_switch(filename: str = "failsafe_switch.yaml") -> FailsafeSwitchParams:
    return load_params(FailsafeSwitchParams, model_path(filename))


@dc.dataclass
class MpcLoop:
    """Handles to the parts of a closed MPC loop built by `add_mpc_loop`."""
    vehicle: object
    mpc: LinearMpc
    state_estimate_port: object
    command_port: object
    mpc_period: float
    switch: FailsafeSwitch
    failsafe: FailsafeController


def mocap_odometry(params: MocapParams):
    """The odometry source of simulation: mocap (true pose + noise + latency)."""
    return lambda builder, vehicle: add_mocap(builder, vehicle.GetOutputPort("ground_truth"),
                                              params)


def add_mpc_control(builder, vehicle, reference_port, arm_port, mpc_params: LinearMpcParams,
                    model: LinearModelParams, odometry, fallback: FailsafeSwitchParams,
                    estimate_filter=None, command_filter=None) -> MpcLoop:
    """Onboard: odometry + linear MPC, the failsafe switch `fallback` to the failsafe controller
    and the arm gate, following `reference_port` and commanding `vehicle` through its boundary
    ports only (the simulated or the MAVLink vehicle). `arm_port` [arm, thrust enable] is the
    mission's request (the switch watches while both are 1; a disarm is obeyed in any mode).
    `odometry(builder, vehicle) -> STATE_ESTIMATE port` builds the state estimate
    (`mocap_odometry(params)`, simulation only; VIO, the estimator bank and the MAVLink side's
    channel mocap plug in here); an odometry with `connect_command(builder, port)` is also given
    the issued command; `estimate_filter(builder, port) -> port` may alter the estimate and
    `command_filter(builder, port) -> port` the MPC's command (fault injection in tests)."""
    estimate = odometry(builder, vehicle)
    if estimate_filter is not None:
        estimate = estimate_filter(builder, estimate)
    mpc = builder.AddNamedSystem("linear_mpc", LinearMpc(model, mpc_params))
    failsafe = builder.AddNamedSystem("failsafe", FailsafeController(
        VehicleModel(mass=model.mass, a_t=model.thrust_a, b_t=model.thrust_b), fallback.failsafe,
        fallback.period))
    switch = builder.AddNamedSystem("failsafe_switch", FailsafeSwitch(fallback))
    gate = builder.AddNamedSystem("arm_gate", ArmGate(command_disarms=True))
    issued = gate.GetOutputPort("fc_command")
    mpc_command = mpc.GetOutputPort("fc_command")
    if command_filter is not None:
        mpc_command = command_filter(builder, mpc_command)
    for name, controller, command in (("controller", mpc, mpc_command),
                                      ("failsafe", failsafe, failsafe.GetOutputPort("fc_command"))):
        builder.Connect(estimate, controller.GetInputPort("state_estimate"))
        builder.Connect(reference_port, controller.GetInputPort("reference"))
        builder.Connect(switch.GetOutputPort(f"{name}.active"), controller.GetInputPort("active"))
        builder.Connect(issued, controller.GetInputPort("last_command"))
        builder.Connect(command, switch.GetInputPort(f"{name}.fc_command"))
    builder.Connect(mpc.GetOutputPort("controller_status"),
                    switch.GetInputPort("controller.controller_status"))
    builder.Connect(vehicle.GetOutputPort("fc_attitude"), mpc.GetInputPort("fc_attitude"))
    builder.Connect(estimate, switch.GetInputPort("state_estimate"))
    builder.Connect(reference_port, switch.GetInputPort("reference"))
    builder.Connect(arm_port, switch.GetInputPort("arm"))
    builder.Connect(vehicle.GetOutputPort("fc_status"), switch.GetInputPort("fc_status"))
    builder.Connect(switch.GetOutputPort("fc_command"), gate.GetInputPort("fc_command"))
    builder.Connect(switch.GetOutputPort("arm"), gate.GetInputPort("arm"))
    builder.Connect(issued, vehicle.GetInputPort("fc_command"))
    if hasattr(odometry, "connect_command"):  # e.g. the estimator bank's acceleration input
        odometry.connect_command(builder, issued)
    return MpcLoop(vehicle, mpc, estimate, issued, mpc_params.period, switch, failsafe)


def add_mpc_logging(builder, loop: MpcLoop, reference_port) -> RunLoggers:
    """The vehicle's streams plus the estimate, the reference, the controller status, the failsafe
    switch's status (`manager_status`, as the control manager's) and the failsafe's status."""
    loggers = add_run_logging(builder, loop.vehicle, loop.command_port)
    loggers.add(builder, "state_estimate", loop.state_estimate_port, STATE_ESTIMATE)
    loggers.add(builder, "reference", reference_port, REFERENCE)
    loggers.add(builder, "controller_status", loop.mpc.GetOutputPort("controller_status"),
                CONTROLLER_STATUS, period=loop.mpc_period)
    loggers.add(builder, "manager_status", loop.switch.GetOutputPort("manager_status"),
                MANAGER_STATUS, period=loop.failsafe.period)
    loggers.add(builder, "status_failsafe", loop.failsafe.GetOutputPort("controller_status"),
                CONTROLLER_STATUS, period=loop.failsafe.period)
    loggers.add(builder, "mpc_disturbance", loop.mpc.GetOutputPort("disturbance"),
                MPC_DISTURBANCE, period=loop.mpc_period)
    return loggers
