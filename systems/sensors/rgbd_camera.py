"""The forward RGB-D camera of the VIO (issue 8, L Sec. 3.1 and 5.1): an Intel RealSense-class
camera (30 Hz, 640x480 colour, depth from an infrared stereo pair with a 10 cm baseline), mounted
looking forward and pitched down, hardware-synchronized with its IMU (the vehicle's `imu` port).

Depth noise grows with range as stereo depth does: sigma_z = z^2 sigma_d / (f b) (disparity noise
sigma_d [px], focal length f [px], baseline b [m]); depth is missing outside [depth_min, depth_max]
and in holes. Two sources (DESIGN.md "Simulation fidelity"), timed like the down camera
(`down_camera.TimedCamera`: exposure, latency, stamp):

- `RenderedRgbdCamera`: Drake `RgbdSensor` colour and depth of the textured scene, with pixel noise,
  range-dependent depth noise and blob-shaped holes;
- `GeometricRgbdCamera`: the landmark map (`rgbd_camera_map`) projected into the pinhole image with
  pixel noise, per-keypoint depth with the same noise model and holes, a feature budget and track
  losses. Track ids behave like a KLT tracker's: a landmark that was not observed in the previous
  frame (out of view, dropped, lost) comes back under a new id, so the estimator never gets free
  re-identification.

The pinhole has no distortion (the RealSense colour stream is published rectified).
"""
import dataclasses as dc

import cv2
import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.systems.sensors import ImageDepth32F, ImageRgba8U

from alight.systems.boundary import CameraFrame
from alight.systems.params import bounded, choice
from alight.systems.sensors.down_camera import TimedCamera
from alight.systems.sensors.down_camera_lens import Lens
from alight.systems.sensors.rgbd_camera_map import LandmarkMapParams, make_landmark_map


@dc.dataclass
class RgbdCameraParams:
    source: str = choice("none", "geometric", "rendered")
    width: int = bounded(640, 32, 4096, "px")
    height: int = bounded(480, 32, 4096, "px")
    focal_length: float = bounded(460.0, 10.0, 1e5, "px")        # 70 deg horizontal field
    p_BC: list[float] = bounded([0.12, 0.0, 0.02], -2.0, 2.0, "m")
    rpy_BC: list[float] = bounded([-115.0, 0.0, -90.0], -360.0, 360.0, "deg")  # forward, 25 deg down
    baseline: float = bounded(0.1, 0.01, 1.0, "m")               # infrared pair, L Sec. 5.1
    disparity_noise_std: float = bounded(0.15, 0.0, 10.0, "px")
    depth_min: float = bounded(0.3, 0.0, 10.0, "m")
    depth_max: float = bounded(10.0, 0.5, 100.0, "m")
    hole_probability: float = bounded(0.05, 0.0, 1.0)            # per keypoint / per 8x8 block
    period: float = bounded(1 / 30, 0.001, 10.0, "s")
    phase: float = bounded(0.0071, 0.0, 10.0, "s")
    latency: float = bounded(0.02, 0.0, 10.0, "s")
    stamp_offset: float = bounded(0.0, -1.0, 1.0, "s")           # synchronized with its IMU
    # geometric source
    landmarks: LandmarkMapParams = dc.field(default_factory=LandmarkMapParams)
    keypoint_noise_std: float = bounded(0.7, 0.0, 100.0, "px")
    max_features: int = bounded(150, 1, 10000)
    max_range: float = bounded(40.0, 0.5, 1000.0, "m")           # farther points are not detected
    track_loss: float = bounded(0.02, 0.0, 1.0)                  # per track and frame
    frame_dropout: float = bounded(0.0, 0.0, 1.0)
    border_margin: float = bounded(8.0, 0.0, 1000.0, "px")
    # rendered source
    renderer_backend: str = choice("", "EGL", "GLX")
    image_noise_std: float = bounded(2.0, 0.0, 100.0, "grey levels")

    def X_BC(self) -> RigidTransform:
        return RigidTransform(RollPitchYaw(np.radians(self.rpy_BC)), self.p_BC)

    def lens(self) -> Lens:
        return Lens.make(self.width, self.height, self.focal_length, np.zeros(5), 1.0,
                         self.X_BC().GetAsMatrix4())

    def calibration(self) -> dict:
        """The lens calibration plus the depth sensor's: baseline and depth noise model."""
        return {**self.lens().calibration(), "model": "pinhole", "baseline": self.baseline,
                "disparity_noise_std": self.disparity_noise_std, "depth_min": self.depth_min,
                "depth_max": self.depth_max}


def depth_noise_std(z, focal_length: float, baseline: float, disparity_noise_std: float):
    """Stereo depth noise [m] at range z [m]: sigma_z = z^2 sigma_d / (f b)."""
    return np.square(z) * disparity_noise_std / (focal_length * baseline)


def _noisy_depth(rng, z: np.ndarray, params: RgbdCameraParams, holes: np.ndarray) -> np.ndarray:
    """Depth with the range-dependent noise, NaN where out of range or in a hole."""
    noisy = z + rng.standard_normal(z.shape) * depth_noise_std(
        z, params.focal_length, params.baseline, params.disparity_noise_std)
    missing = holes | ~np.isfinite(z) | (z < params.depth_min) | (z > params.depth_max)
    return np.where(missing, np.nan, noisy)


GRID = (8, 6)  # feature bucketing cells (columns, rows)


class GeometricRgbdCamera(TimedCamera):
    """Input  `body_poses`  the plant's body poses (the vehicle's is used)
    Input  `noise_seed`  (1) uniform in [0, 1), resampled every period: seeds this frame's noise
    Output `rgbd`        CameraFrame without image: keypoints (N, 2) [px], keypoint_ids (N,) track
                         ids, depth (N,) per keypoint [m, NaN: no depth], calibration
    """

    def __init__(self, params: RgbdCameraParams, body_index):
        super().__init__(params, output_name="rgbd")
        self._lens = params.lens()
        self._calibration = params.calibration()
        self._X_BC = params.X_BC()
        self._body = int(body_index)
        self.landmarks = make_landmark_map(params.landmarks)
        # Homogeneous landmark coordinates (4, N), for one product per frame.
        self._p_WL_h = np.vstack([self.landmarks.p_WL.T, np.ones(len(self.landmarks.p_WL))])
        self._focal, self._center = self._lens.K[[0, 1], [0, 1]], self._lens.K[:2, 2]
        self._poses = self.DeclareAbstractInputPort("body_poses", AbstractValue.Make(
            [RigidTransform()]))
        self._seed = self.DeclareVectorInputPort("noise_seed", 1)
        # {landmark index: track id} of the last frame, and the next free track id
        self._tracks = self.DeclareAbstractState(AbstractValue.Make(({}, 0)))

    def _on_exposure(self, context, state):
        tracks, next_id = context.get_abstract_state(self._tracks).get_value()
        rng = np.random.default_rng(int(self._seed.Eval(context)[0] * 2 ** 31))
        frame, tracks, next_id = self._observe(context, rng, tracks, next_id)
        self._queue(context, state, frame)
        state.get_mutable_abstract_state(self._tracks).set_value((tracks, next_id))

    def _observe(self, context, rng, tracks: dict, next_id: int):
        p = self._params
        if rng.random() < p.frame_dropout:
            return None, {}, next_id
        X_WC = self._poses.Eval(context)[self._body] @ self._X_BC
        visible, uv, z = self.visible(X_WC)
        tracked = [i for i in visible if i in tracks]
        # One draw per tracked landmark, in order (as many draws as one call each).
        kept = [i for i, u in zip(tracked, rng.random(len(tracked))) if u >= p.track_loss]
        fresh = self._spread([i for i in visible if i not in tracks], kept, uv, rng)
        selected = np.array((kept + fresh)[:p.max_features], dtype=int)
        new_tracks = {i: tracks[i] for i in kept}
        for i in selected[len(kept):]:
            new_tracks[int(i)], next_id = next_id, next_id + 1
        n = len(selected)
        keypoints = self._lens.project(self._points_C(X_WC, selected)) \
            + p.keypoint_noise_std * rng.standard_normal((n, 2)) if n else np.zeros((0, 2))
        depth = _noisy_depth(rng, z[selected], p, rng.random(n) < p.hole_probability)
        frame = CameraFrame(stamp=self._stamp(context), calibration=self._calibration,
                            keypoints=keypoints,
                            keypoint_ids=np.array([new_tracks[int(i)] for i in selected], np.int64),
                            depth=depth)
        return frame, new_tracks, next_id

    def _spread(self, fresh: list[int], kept: list[int], uv: np.ndarray, rng) -> list[int]:
        """New features ordered as a detector with a bucketing grid picks them: evenly over the
        image (GRID cells, the emptiest first), not where landmarks crowd (near the horizon)."""
        cells = lambda ids: (np.clip(uv[ids, 0] * GRID[0] / self._lens.width, 0, GRID[0] - 1)
                             .astype(int) * GRID[1] + np.clip(uv[ids, 1] * GRID[1]
                                                              / self._lens.height, 0,
                                                              GRID[1] - 1).astype(int))
        fresh = np.asarray(fresh, dtype=int)[rng.permutation(len(fresh))]
        if not len(fresh):
            return []
        count = np.bincount(cells(kept), minlength=GRID[0] * GRID[1]) if kept else \
            np.zeros(GRID[0] * GRID[1], int)
        # Each new feature's rank: the features already in its cell (kept, then the new ones
        # before it in the shuffled order).
        cell = cells(fresh)
        order = np.argsort(cell, kind="stable")
        first = np.searchsorted(cell[order], cell[order])
        before = np.empty(len(fresh), int)
        before[order] = np.arange(len(fresh)) - first
        rank = count[cell] + before
        return fresh[np.argsort(rank, kind="stable")].tolist()

    def _points_C(self, X_WC: RigidTransform, indices=None) -> np.ndarray:
        """Landmarks (all, or those of `indices`) in the camera frame C."""
        p_WL_h = self._p_WL_h if indices is None else self._p_WL_h[:, indices]
        return (X_WC.inverse().GetAsMatrix34() @ p_WL_h).T

    def visible(self, X_WC: RigidTransform) -> tuple[list[int], np.ndarray, np.ndarray]:
        """Indices of the landmarks a detector would find (in front, within range, inside the
        image minus the border), the noise-free pixels (meaningless behind the camera) and ranges
        (z in C) of all landmarks."""
        p = self._params
        p_CL = self._points_C(X_WC)
        z = p_CL[:, 2]
        ahead = (z > 0.1) & (z < p.max_range)
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = p_CL[:, :2] / z[:, None] * self._focal + self._center
        visible = ahead & self._lens.in_image(uv, p.border_margin)
        return np.flatnonzero(visible).tolist(), uv, z


class RenderedRgbdCamera(TimedCamera):
    """Input  `color_image`  ImageRgba8U from a Drake RgbdSensor with this camera's pinhole
    Input  `depth_image`  ImageDepth32F [m] from the same sensor
    Input  `noise_seed`   (1) uniform in [0, 1), resampled every period
    Output `rgbd`         CameraFrame: colour image (H, W, 3) uint8, depth (H, W) [m, NaN: none],
                          calibration
    """

    def __init__(self, params: RgbdCameraParams):
        super().__init__(params, output_name="rgbd")
        self._calibration = params.calibration()
        self._color = self.DeclareAbstractInputPort("color_image", AbstractValue.Make(ImageRgba8U()))
        self._depth = self.DeclareAbstractInputPort("depth_image",
                                                    AbstractValue.Make(ImageDepth32F()))
        self._seed = self.DeclareVectorInputPort("noise_seed", 1)

    def degrade(self, rgba: np.ndarray, depth: np.ndarray, seed: int = 0):
        """Pixel noise on the colour image; range noise and holes on the depth image."""
        p = self._params
        rng = np.random.default_rng(seed)
        image = np.ascontiguousarray(rgba[:, :, :3])
        if p.image_noise_std > 0:
            image = np.clip(image + rng.normal(0, p.image_noise_std, image.shape), 0,
                            255).astype(np.uint8)
        h, w = depth.shape[:2]
        blocks = rng.random(((h + 7) // 8, (w + 7) // 8)) < p.hole_probability
        holes = cv2.resize(blocks.astype(np.uint8), ((w + 7) // 8 * 8, (h + 7) // 8 * 8),
                           interpolation=cv2.INTER_NEAREST)[:h, :w].astype(bool)
        z = np.asarray(depth, np.float64).reshape(h, w)
        return image, _noisy_depth(rng, z, p, holes).astype(np.float32)

    def _expose(self, context) -> CameraFrame:
        seed = int(self._seed.Eval(context)[0] * 2 ** 31)
        image, depth = self.degrade(self._color.Eval(context).data,
                                    self._depth.Eval(context).data, seed)
        return CameraFrame(stamp=self._stamp(context), image=image, depth=depth,
                           calibration=self._calibration)
