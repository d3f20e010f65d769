"""Fault injection on an onboard stack's inputs (simulation only, issue 21's fault campaign): the
scenario's `faults` (diagrams/scenario.py `Faults`) put a bad localization system after the
odometry (`faulty_odometry`: estimate loss, jump, noise; systems/sensors/estimate_faults.py) and
a broken controller after the linear MPC (`command_filter`: NaN or out-of-range commands;
systems/sensors/command_faults.py). The motor fault is the vehicle's own
(`vehicle.motor_fault`), the camera's the scenario's `camera_blackouts`."""
from pydrake.common import RandomDistribution
from pydrake.systems.primitives import RandomSource

from alight.systems.sensors.command_faults import CommandFaultParams, CommandFaults
from alight.systems.sensors.estimate_faults import EstimateFaultParams, EstimateFaults

NOISE_PERIOD = 0.01   # s: the estimator noise is drawn at the bank's 100 Hz


def add_estimate_faults(builder, estimate, params: EstimateFaultParams,
                        noise_period: float = NOISE_PERIOD):
    """`EstimateFaults(params)` (with its seeded Gaussian noise source) after the STATE_ESTIMATE
    port `estimate`; returns the faulty estimate's port."""
    injector = builder.AddNamedSystem("estimate_faults", EstimateFaults(params))
    noise = builder.AddNamedSystem("estimate_fault_noise", RandomSource(
        RandomDistribution.kGaussian, 6, noise_period))
    builder.Connect(noise.get_output_port(), injector.GetInputPort("noise"))
    builder.Connect(estimate, injector.GetInputPort("state_estimate"))
    return injector.GetOutputPort("state_estimate")


class FaultyOdometry:
    """An odometry hook `(builder, vehicle) -> STATE_ESTIMATE port` with the estimate faults
    `params` after `odometry`'s port; anything else (`log`, `connect_command`) is `odometry`'s."""

    def __init__(self, odometry, params: EstimateFaultParams):
        self._odometry, self._params = odometry, params

    def __call__(self, builder, vehicle):
        return add_estimate_faults(builder, self._odometry(builder, vehicle), self._params)

    def __getattr__(self, name):
        return getattr(self._odometry, name)


def faulty_odometry(odometry, params: EstimateFaultParams):
    """`odometry` itself without an active fault (the nominal diagram unchanged), else
    `FaultyOdometry`."""
    return FaultyOdometry(odometry, params) if odometry is not None and params.active \
        else odometry


def command_filter(params: CommandFaultParams):
    """A `command_filter(builder, port) -> port` of `add_mpc_control` putting `CommandFaults`
    after the controller's command; None without an active fault."""
    if not params.active:
        return None

    def add(builder, command):
        faults = builder.AddNamedSystem("command_faults", CommandFaults(params))
        builder.Connect(command, faults.get_input_port())
        return faults.get_output_port()
    return add
