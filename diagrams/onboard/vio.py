"""Builds the visual-inertial odometry into a diagram (issue 8, L Sec. 5.1): `add_vio` wires the
`VisualInertialOdometry` system to the vehicle's `imu` and `rgbd` ports; `vio_odometry` is the
odometry builder for `mpc_loop.add_mpc_control` / `fly_waypoints` (the VIO closes the loop instead of mocap);
`VioRun` does the same and also logs the VIO's streams (open loop: mocap still flies, the VIO runs
beside it)."""


import dataclasses as dc

from alight.diagrams.onboard.mpc_loop import mocap_odometry
from alight.models import model_path
from alight.systems.boundary import STATE_ESTIMATE
from alight.systems.params import load_params
from alight.systems.sensors.camera_faults import CameraBlackout
from alight.systems.sensors.mocap import MocapParams
from alight.systems.sensors.rgbd_camera import RgbdCameraParams
from alight.systems.vio.estimator import VioParams
from alight.systems.vio.odometry import VIO_ODOMETRY, VisualInertialOdometry


def load_vio_params(filename: str = "vio.yaml") -> VioParams:
    return load_params(VioParams, model_path(filename))


def load_rgbd_camera_params(filename: str = "rgbd_camera.yaml") -> RgbdCameraParams:
    return load_params(RgbdCameraParams, model_path(filename))


def add_vio(builder, vehicle, params: VioParams, name: str = "vio",
            blackouts=None) -> VisualInertialOdometry:
    """The VIO on the vehicle's `imu` and `rgbd` ports; `blackouts` [(start, end), ...] [s] blank
    the camera in those windows (a sensor fault, simulation only)."""
    vio = builder.AddNamedSystem(name, VisualInertialOdometry(params))
    builder.Connect(vehicle.GetOutputPort("imu"), vio.GetInputPort("imu"))
    rgbd = vehicle.GetOutputPort("rgbd")
    if blackouts:
        blackout = builder.AddNamedSystem(f"{name}_camera_blackout", CameraBlackout(blackouts))
        builder.Connect(rgbd, blackout.GetInputPort("image"))
        rgbd = blackout.GetOutputPort("image")
    builder.Connect(rgbd, vio.GetInputPort("rgbd"))
    return vio


def vio_odometry(params: VioParams):
    """The odometry builder `(builder, vehicle) -> STATE_ESTIMATE port` of the VIO."""
    return lambda builder, vehicle: add_vio(builder, vehicle, params).GetOutputPort(
        "state_estimate")


class VioRun:
    """An odometry builder that adds the VIO and remembers it, and a `log(builder, loggers)` that
    records its `odometry` and `state_estimate` streams. `closed_loop=False`: mocap (`mocap`)
    flies."""

    def __init__(self, params: VioParams, closed_loop: bool = True, blackouts=None,
                 mocap: MocapParams | None = None):
        if not closed_loop and mocap is None:
            raise ValueError("VioRun(closed_loop=False) flies on mocap: give its MocapParams")
        self.params = params
        self.closed_loop = closed_loop
        self.blackouts = blackouts
        self.mocap = mocap
        self.vio = None

    def __call__(self, builder, vehicle):
        self.vio = add_vio(builder, vehicle, self.params, blackouts=self.blackouts)
        if self.closed_loop:
            return self.vio.GetOutputPort("state_estimate")
        return mocap_odometry(self.mocap)(builder, vehicle)

    def log(self, builder, loggers) -> None:
        loggers.add(builder, "vio_odometry", self.vio.GetOutputPort("odometry"), VIO_ODOMETRY,
                    period=self.params.period)
        loggers.add(builder, "vio_estimate", self.vio.GetOutputPort("state_estimate"),
                    STATE_ESTIMATE, period=self.params.period)


def vio_from_start(params: VioParams, start_xy) -> VioRun:
    """`VioRun` of `params` whose estimator frame E starts at the take-off point `start_xy`
    (x, y in W [m], a surveyed start; the height at rest stays `params`')."""
    return VioRun(dc.replace(params, initial_position=[*start_xy, params.initial_position[2]]))
