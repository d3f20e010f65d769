"""Builds the estimator bank (M Sec. 3.5, 7.1) into a diagram: its sources (simulated sensor
models, or the mocap source) from the bank YAML, the bank, and the command-derived acceleration
input; `BankOdometry` is the `odometry` hook of `mpc_loop.add_mpc_control` (and the
runners' `add_mpc_loop` / `fly_waypoints`).

A source entry in the bank YAML names its kind and, for simulation, its sensor model's parameters
(`sensor:`, a file resolved at load, or inline); `SENSOR_MODELS` maps the kind to the model.
Adding a simulated source kind is one entry here plus its adapter in
`systems/estimation/measurements.py`.
"""
import dataclasses as dc

import numpy as np
from pydrake.systems.primitives import ConstantVectorSource

from alight.diagrams.onboard.mocap import add_mocap
from alight.systems.sensors.sampled import add_sampled_sensor
from alight.models import model_path
from alight.systems.boundary import STATE_ESTIMATE
from alight.systems.estimation.bank import SENSOR_PARAMS, BankParams, EstimatorBank, check_bank
from alight.systems.estimation.command_acceleration import CommandAcceleration
from alight.systems.estimation.frames import FrameAnchor
from alight.systems.control.linear_model import LinearModelParams
from alight.systems.params import ConfigError, load_params
from alight.systems.sensors.optic_flow import OpticFlow
from alight.systems.sensors.position_fix import PositionFix
from alight.systems.sensors.rangefinder import Rangefinder
from alight.systems.thrust_curve import ThrustCurve


def load_bank_params(filename: str = "estimator_bank.yaml", data: str | None = None) -> BankParams:
    """The bank YAML (a path or a file in models/), checked: a ConfigError names file and key."""
    path = model_path(filename) if data is None else None
    params = load_params(BankParams, path, data=data)
    check_bank(params, str(path) if path else "<yaml string>")
    return params


def _sampled(system):
    def build(builder, name, params, ground_truth_port):
        return add_sampled_sensor(builder, name, system(params), params.latency,
                                  ground_truth_port)
    return build


def _mocap(builder, name, params, ground_truth_port):
    return add_mocap(builder, ground_truth_port, params, name=name)


# The simulated sensor model of each source kind, built from its parameters (SENSOR_PARAMS).
SENSOR_MODELS = {"position_fix": _sampled(PositionFix), "velocity_fix": _sampled(OpticFlow),
                 "range": _sampled(Rangefinder), "odometry": _mocap}


@dc.dataclass
class Bank:
    """Handles to the parts `add_estimator_bank` built."""
    system: EstimatorBank
    state_estimate: object   # the bank's output port (active frame, switches visible)
    anchored: object         # the same estimate in the anchor frame (FrameAnchor)
    status: object
    sources: dict


def add_estimator_bank(builder, vehicle, params: BankParams, request: str | None = None,
                       sensors: dict | None = None, name: str = "estimator_bank") -> Bank:
    """The bank fed by simulated sources on `vehicle`'s ground truth and its `fc_attitude`.
    `request`: a filter name the arbiter is asked for (held for the whole run); `sensors`:
    {source name: sensor parameters} overriding the bank's `sensor:` entries (a source with
    neither flies its model's defaults, SourceParams)."""
    bank = builder.AddNamedSystem(name, EstimatorBank(params))
    builder.Connect(vehicle.GetOutputPort("fc_attitude"), bank.GetInputPort("fc_attitude"))
    truth = vehicle.GetOutputPort("ground_truth")
    ports = {}
    for source in params.sources:
        sensor = (sensors or {}).get(source.name, source.sensor)
        if sensor is None:
            sensor = SENSOR_PARAMS[source.kind]()
        ports[source.name] = SENSOR_MODELS[source.kind](builder, source.name, sensor, truth)
        builder.Connect(ports[source.name], bank.GetInputPort(source.name))
    if request is not None:
        if request not in bank.filter_names:
            raise ConfigError(f"estimator {request!r} is not a filter of the bank "
                              f"{bank.filter_names}")
        index = builder.AddNamedSystem(f"{name}_request", ConstantVectorSource(
            [float(bank.filter_names.index(request))]))
        builder.Connect(index.get_output_port(), bank.GetInputPort("request"))
    anchor = builder.AddNamedSystem(f"{name}_anchor", FrameAnchor(params.period))
    builder.Connect(bank.GetOutputPort("state_estimate"), anchor.GetInputPort("state_estimate"))
    return Bank(bank, bank.GetOutputPort("state_estimate"),
                anchor.GetOutputPort("state_estimate"), bank.GetOutputPort("bank_status"), ports)


class BankOdometry:
    """The `odometry` hook of `add_mpc_loop` and `add_managed_onboard`: adds the bank and returns
    its estimate in the anchor frame (`anchored`: for the linear MPC loop and the waypoint
    mission, which do not re-express on frame switches), or as the bank outputs it, switching
    frames (the managed stack re-expresses, M Sec. 3.5);
    `connect_command` feeds the bank its input M(53): the active controller's own where it has
    one (`controller_acceleration`, in the frame of `estimate`), else the command stand-in
    (thrust to acceleration by `model`'s mass and thrust curve);
    `log(builder, loggers)` records `bank_estimate` (active frame) and `bank_status`."""

    def __init__(self, params: BankParams, model: LinearModelParams, request: str | None = None,
                 sensors: dict | None = None, anchored: bool = True):
        self.params = params
        self.request, self.sensors, self.anchored = request, sensors, anchored
        self._mass, self._curve = model.mass, ThrustCurve(model.thrust_a, model.thrust_b)
        self.bank: Bank | None = None

    def __call__(self, builder, vehicle):
        self.bank = add_estimator_bank(builder, vehicle, self.params, self.request, self.sensors)
        self._vehicle = vehicle
        return self.bank.anchored if self.anchored else self.bank.state_estimate

    def connect_command(self, builder, command_port, controller_acceleration=None,
                        estimate=None) -> None:
        acceleration = builder.AddNamedSystem("command_acceleration",
                                              CommandAcceleration(self._mass, self._curve))
        builder.Connect(command_port, acceleration.GetInputPort("fc_command"))
        builder.Connect(self._vehicle.GetOutputPort("fc_status"),
                        acceleration.GetInputPort("fc_status"))
        if controller_acceleration is not None:
            builder.Connect(controller_acceleration,
                            acceleration.GetInputPort("controller_acceleration"))
            builder.Connect(estimate, acceleration.GetInputPort("state_estimate"))
            builder.Connect(self._vehicle.GetOutputPort("fc_attitude"),
                            acceleration.GetInputPort("fc_attitude"))
        builder.Connect(acceleration.GetOutputPort("desired_acceleration"),
                        self.bank.system.GetInputPort("desired_acceleration"))

    def log(self, builder, loggers) -> None:
        loggers.add(builder, "bank_estimate", self.bank.state_estimate, STATE_ESTIMATE)
        loggers.add(builder, "bank_status", self.bank.status, self.bank.system.status)


ESTIMATORS = ("mocap", "bank")   # besides the bank's filter names


def scenario_odometry(estimator: str, bank: BankParams, model: LinearModelParams,
                      where: str = "<scenario>", anchored: bool = True, others: tuple = (),
                      key: str = "estimator") -> "BankOdometry | None":
    """The `odometry` hook a scenario's `estimator:` entry names: None for `mocap` (the caller's
    mocap), `BankOdometry` on `bank` (and the vehicle `model`) for `bank` (its arbiter) or one of
    its filters (requested for the whole run); `anchored` for the landing mission's state machine, which keeps its
    waypoint and reference in E and does not re-express them on frame switches (the managed
    stack of `alight fly` does: anchored=False). Raises ConfigError naming `where` and the key
    for anything else (`others`: names the caller handles, for the message; `key`: the
    estimator's key in the caller's configuration)."""
    if estimator == "mocap":
        return None
    names = [f.name for f in bank.filters]
    if estimator != "bank" and estimator not in names:
        raise ConfigError(f"{where}: key '{key}' = {estimator!r} must be one of "
                          f"{[*ESTIMATORS, *others, *names]} (the last ones: the filters of "
                          f"the estimator bank)")
    return BankOdometry(bank, model, request=None if estimator == "bank" else estimator,
                        anchored=anchored)


def active_filter_names(run, params: BankParams) -> np.ndarray:
    """The active filter's name at every `bank_status` row of a run folder."""
    names = np.array([f.name for f in params.filters])
    return names[run["bank_status"]["active"].to_numpy().astype(int)]
