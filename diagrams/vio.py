"""Builds the visual-inertial odometry into a diagram (issue 8, L Sec. 5.1): `add_vio` wires the
`VisualInertialOdometry` system to the vehicle's `imu` and `rgbd` ports; `vio_odometry` is the
odometry builder for `fly.add_mpc_loop` / `fly_waypoints` (the VIO closes the loop instead of mocap);
`VioRun` does the same and also logs the VIO's streams (open loop: mocap still flies, the VIO runs
beside it)."""
from pathlib import Path

import numpy as np

from alight.diagrams.fly import mocap_odometry
from alight.models import model_path
from alight.systems.boundary import STATE_ESTIMATE
from alight.systems.params import load_params
from alight.systems.sensors.camera_faults import CameraBlackout
from alight.systems.sensors.rgbd_camera import RgbdCameraParams
from alight.systems.vio.estimator import VioParams
from alight.systems.vio.metrics import ate_rmse, rpe_per_metre, write_tum
from alight.systems.vio.odometry import VIO_ODOMETRY, VisualInertialOdometry


def load_vio_params(filename: str = "vio.yaml") -> VioParams:
    return load_params(VioParams, model_path(filename))


def load_rgbd_camera_params(filename: str = "rgbd_camera.yaml") -> RgbdCameraParams:
    return load_params(RgbdCameraParams, model_path(filename))


def add_vio(builder, vehicle, params: VioParams | None = None, name: str = "vio",
            blackouts=None) -> VisualInertialOdometry:
    """The VIO on the vehicle's `imu` and `rgbd` ports; `blackouts` [(start, end), ...] [s] blank
    the camera in those windows (a sensor fault, simulation only)."""
    vio = builder.AddNamedSystem(name, VisualInertialOdometry(params or load_vio_params()))
    builder.Connect(vehicle.GetOutputPort("imu"), vio.GetInputPort("imu"))
    rgbd = vehicle.GetOutputPort("rgbd")
    if blackouts:
        blackout = builder.AddNamedSystem(f"{name}_camera_blackout", CameraBlackout(blackouts))
        builder.Connect(rgbd, blackout.GetInputPort("image"))
        rgbd = blackout.GetOutputPort("image")
    builder.Connect(rgbd, vio.GetInputPort("rgbd"))
    return vio


def vio_odometry(params: VioParams | None = None):
    """The odometry builder `(builder, vehicle) -> STATE_ESTIMATE port` of the VIO."""
    return lambda builder, vehicle: add_vio(builder, vehicle, params).GetOutputPort(
        "state_estimate")


class VioRun:
    """An odometry builder that adds the VIO and remembers it, and a `log(builder, loggers)` that
    records its `odometry` and `state_estimate` streams. `closed_loop=False`: mocap flies."""

    def __init__(self, params: VioParams | None = None, closed_loop: bool = True,
                 blackouts=None):
        self.params = params or load_vio_params()
        self.closed_loop = closed_loop
        self.blackouts = blackouts
        self.vio = None

    def __call__(self, builder, vehicle):
        self.vio = add_vio(builder, vehicle, self.params, blackouts=self.blackouts)
        if self.closed_loop:
            return self.vio.GetOutputPort("state_estimate")
        return mocap_odometry()(builder, vehicle)

    def log(self, builder, loggers) -> None:
        loggers.add(builder, "vio_odometry", self.vio.GetOutputPort("odometry"), VIO_ODOMETRY,
                    period=self.params.period)
        loggers.add(builder, "vio_estimate", self.vio.GetOutputPort("state_estimate"),
                    STATE_ESTIMATE, period=self.params.period)


def fly_vio(config, waypoints, seed: int = 0, run_dir=None, closed_loop: bool = True,
            camera: RgbdCameraParams | None = None, params: VioParams | None = None,
            blackouts=None):
    """Flies `waypoints` (fly.fly_waypoints) with the VIO on the forward camera (`camera`, default
    models/rgbd_camera.yaml) in the loop, or beside mocap (`closed_loop=False`)."""
    from alight.diagrams.fly import fly_waypoints
    config.rgbd_camera = camera or load_rgbd_camera_params()
    if config.rgbd_camera.source == "none":
        raise ValueError("the VIO needs the forward RGB-D camera: rgbd_camera.source is none")
    vio = VioRun(params, closed_loop, blackouts)
    return fly_waypoints(config, np.asarray(waypoints, float), seed=seed, run_dir=run_dir,
                         odometry=vio, log=vio.log)


def evaluate_vio(run) -> dict:
    """ATE and RPE per metre (evo's definitions, `systems/vio/metrics`) of the valid VIO estimate
    against the ground truth, processing times; writes the TUM files into the run folder."""
    estimate = run["vio_estimate"]
    valid = estimate["valid"].to_numpy() > 0.5
    t = estimate["time"].to_numpy()[valid]
    p = run.field("vio_estimate", "p_EB").to_numpy()[valid]
    q = run.field("vio_estimate", "q_EB").to_numpy()[valid]
    truth = run["ground_truth"]
    p_true = np.column_stack([np.interp(t, truth["time"], truth[f"p_WB_{i}"]) for i in range(3)])
    q_true = run.field("ground_truth", "q_WB").to_numpy()[
        np.clip(np.searchsorted(truth["time"].to_numpy(), t), 0, len(truth) - 1)]
    write_tum(Path(run.path) / "vio_estimate.tum", t, p, q)
    write_tum(Path(run.path) / "ground_truth.tum", t, p_true, q_true)
    odometry = run["vio_odometry"]
    keyframes = odometry["keyframes"].diff().fillna(0) > 0
    travelled = float(np.linalg.norm(np.diff(p_true, axis=0), axis=1).sum())
    return {"valid_fraction": float(valid.mean()), "ate_rmse": ate_rmse(p, p_true),
            "rpe_per_m": rpe_per_metre(p, q, p_true, q_true, 1.0),
            "final_drift": float(np.linalg.norm(p[-1] - p_true[-1]) / max(travelled, 1e-9)),
            "travelled": travelled,
            "frontend_ms": float(odometry["frontend_time"][odometry["tracked"] > 0].mean() * 1e3),
            "backend_ms": float(odometry["backend_time"][keyframes].mean() * 1e3),
            "backend_max_ms": float(odometry["backend_time"][keyframes].max() * 1e3),
            "restarts": int(odometry["restarts"].max()), "run_folder": str(run.path)}
