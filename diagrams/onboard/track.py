"""The closed controller loop of the M Sec. 8 experiments (`alight track`): mocap odometry (+ the
fault injector) -> controllers switched by a `TimedSwitch` (the control manager's stand-in) ->
vehicle."""
import dataclasses as dc

import numpy as np
from pydrake.common import RandomDistribution
from pydrake.systems.primitives import RandomSource, TrajectorySource
from pydrake.trajectories import PiecewisePolynomial

from alight.diagrams.onboard.controllers import ControllersConfig, make_controller
from alight.diagrams.onboard.mocap import add_mocap
from alight.diagrams.running.run_log import RunLoggers, add_run_logging
from alight.systems.boundary import CONTROLLER_STATUS, REFERENCE, STATE_ESTIMATE
from alight.systems.control import analytic_reference as ref
from alight.systems.control.arm_gate import ArmGate
from alight.systems.control.disturbance import DISTURBANCE_ESTIMATE
from alight.systems.control.timed_switch import TimedSwitch
from alight.systems.sensors.estimate_faults import EstimateFaultParams, EstimateFaults
from alight.systems.sensors.mocap import MocapParams


@dc.dataclass
class ControllerLoop:
    """Handles to the closed loop built by `add_controller_loop`."""
    vehicle: object
    controllers: dict
    switch: TimedSwitch
    state_estimate_port: object
    true_estimate_port: object
    reference_port: object


def add_arm_gate(builder, command_port, name: str, idle: float = 0.5):
    """An `ArmGate` on `command_port`: arm request from t = 0, thrust from `idle` s on (the
    flight controller arms only at low thrust; the force controllers ramp up on their own)."""
    gate = builder.AddNamedSystem(name, ArmGate())
    arm = builder.AddNamedSystem(f"{name}_request", TrajectorySource(
        PiecewisePolynomial.ZeroOrderHold([0.0, idle, idle + 1.0],
                                          np.array([[1.0, 1.0, 1.0], [0.0, 1.0, 1.0]]))))
    builder.Connect(command_port, gate.GetInputPort("fc_command"))
    builder.Connect(arm.get_output_port(), gate.GetInputPort("arm"))
    return gate.GetOutputPort("fc_command")


def add_faulty_mocap(builder, vehicle, period: float, faults: EstimateFaultParams | None,
                     mocap: MocapParams):
    """Mocap `mocap` of `vehicle` and, when `faults` is given and active, the fault injector
    after it: (the true mocap port, the port the controllers read)."""
    mocap_port = add_mocap(builder, vehicle.GetOutputPort("ground_truth"), mocap)
    if faults is None or not faults.active:
        return mocap_port, mocap_port
    injector = builder.AddNamedSystem("estimate_faults", EstimateFaults(faults))
    noise = builder.AddNamedSystem("estimate_fault_noise", RandomSource(
        RandomDistribution.kGaussian, 6, period))
    builder.Connect(noise.get_output_port(), injector.GetInputPort("noise"))
    builder.Connect(mocap_port, injector.GetInputPort("state_estimate"))
    return mocap_port, injector.GetOutputPort("state_estimate")


def add_controller_loop(builder, vehicle_diagram, controllers_config: ControllersConfig,
                        trajectory: ref.Trajectory, names: list[str], start_times: list[float],
                        faults: EstimateFaultParams | None, mocap: MocapParams) -> ControllerLoop:
    """Vehicle + mocap (+ fault injector when `faults` are given) + the named controllers
    (`make_controller`: the flight-stack controllers, or the landing paper's `linear_mpc` with
    `controllers_config.linear_mpc` and `.linear_model`), controller i active from
    start_times[i], following the analytic `trajectory`."""
    vehicle = builder.AddNamedSystem("vehicle", vehicle_diagram)
    mocap_port, estimate = add_faulty_mocap(builder, vehicle, controllers_config.period, faults,
                                            mocap)
    reference = builder.AddNamedSystem("reference", ref.AnalyticReference(
        trajectory, controllers_config.period))
    switch = builder.AddNamedSystem("switch", TimedSwitch(start_times, controllers_config.period))
    controllers = {}
    for i, name in enumerate(names):
        controller = builder.AddNamedSystem(f"controller_{i}_{name}",
                                            make_controller(name, controllers_config))
        builder.Connect(estimate, controller.GetInputPort("state_estimate"))
        builder.Connect(reference.GetOutputPort("reference"), controller.GetInputPort("reference"))
        builder.Connect(switch.GetOutputPort(f"active_{i}"), controller.GetInputPort("active"))
        builder.Connect(switch.GetOutputPort("fc_command"), controller.GetInputPort("last_command"))
        if controller.HasInputPort("fc_attitude"):
            builder.Connect(vehicle.GetOutputPort("fc_attitude"),
                            controller.GetInputPort("fc_attitude"))
        command = controller.GetOutputPort("fc_command")
        if name == "linear_mpc":
            command = add_arm_gate(builder, command, f"arm_gate_{i}")
        builder.Connect(command, switch.GetInputPort(f"fc_command_{i}"))
        controllers[f"{i}_{name}"] = controller
    builder.Connect(switch.GetOutputPort("fc_command"), vehicle.GetInputPort("fc_command"))
    return ControllerLoop(vehicle, controllers, switch, estimate, mocap_port,
                          reference.GetOutputPort("reference"))


def add_loop_logging(builder, loop: ControllerLoop, period: float) -> RunLoggers:
    """The vehicle's streams, the (faulty) estimate, the reference, and per controller its status,
    desired acceleration M(53) and disturbance estimate M(35)-(37)."""
    loggers = add_run_logging(builder, loop.vehicle, loop.switch.GetOutputPort("fc_command"))
    loggers.add(builder, "state_estimate", loop.state_estimate_port, STATE_ESTIMATE)
    loggers.add(builder, "reference", loop.reference_port, REFERENCE)
    for key, controller in loop.controllers.items():
        loggers.add(builder, f"status_{key}", controller.GetOutputPort("controller_status"),
                    CONTROLLER_STATUS, period)
        if controller.HasOutputPort("disturbance_estimate"):
            loggers.add(builder, f"disturbance_{key}",
                        controller.GetOutputPort("disturbance_estimate"), DISTURBANCE_ESTIMATE,
                        period)
    return loggers
