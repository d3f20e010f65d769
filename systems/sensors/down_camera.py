"""The downward camera (issue 5; L Sec. 3.1, 5.2): 20 Hz frames with exposure latency and stamps that
are not synchronized to the IMU, in two sources (DESIGN.md "Simulation fidelity"):

- `RenderedDownCamera`: a Drake `RgbdSensor` pinhole colour render of the scene, distorted through
  the lens model (`down_camera_lens.Lens`) by `cv2.remap`, converted to grey, with pixel noise;
- `GeometricDownCamera`: the landing pattern's keypoints projected through the same lens model, with
  5 px noise (L Sec. 5.2.2), field-of-view, view-angle and image-border checks, and dropouts.

Timing, common to both: exposures at `phase + k period` (not on the IMU's sample grid); a frame is
published `latency` after its exposure; its stamp is the exposure time plus `stamp_offset` (the
clock error of an unsynchronized camera, which the paper blames for part of its errors, L Sec. 5.2.2).
"""
import dataclasses as dc

import cv2
import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.systems.framework import LeafSystem
from pydrake.systems.sensors import ImageRgba8U
from scipy.stats import norm

from alight.systems.boundary import CameraFrame
from alight.systems.params import bounded, choice
from alight.systems.sensors.down_camera_lens import Lens


@dc.dataclass
class DownCameraParams:
    source: str = choice("none", "geometric", "rendered")
    width: int = bounded(1280, 32, 8192, "px")
    height: int = bounded(1024, 32, 8192, "px")
    focal_length: float = bounded(640.0, 10.0, 1e5, "px")
    distortion: list[float] = bounded([-0.2, 0.04, 2e-4, -1e-4, 0.0], -10.0, 10.0)
    rectified_scale: float = bounded(0.8, 0.1, 2.0)
    p_BC: list[float] = bounded([0.0, 0.0, -0.08], -2.0, 2.0, "m")
    rpy_BC: list[float] = bounded([180.0, 0.0, -90.0], -360.0, 360.0, "deg")
    period: float = bounded(0.05, 0.001, 10.0, "s")
    phase: float = bounded(0.0123, 0.0, 10.0, "s")
    latency: float = bounded(0.03, 0.0, 10.0, "s")
    stamp_offset: float = bounded(0.005, -1.0, 1.0, "s")
    render_scale: float = bounded(1.0, 0.1, 4.0)
    renderer_backend: str = choice("", "EGL", "GLX")
    image_noise_std: float = bounded(2.0, 0.0, 100.0, "grey levels")
    keypoint_noise_std: float = bounded(5.0, 0.0, 100.0, "px")
    frame_dropout: float = bounded(0.02, 0.0, 1.0)
    keypoint_dropout: float = bounded(0.05, 0.0, 1.0)
    border_margin: float = bounded(10.0, 0.0, 1000.0, "px")
    max_view_angle: float = bounded(80.0, 0.0, 90.0, "deg")

    def X_BC(self) -> RigidTransform:
        return RigidTransform(RollPitchYaw(np.radians(self.rpy_BC)), self.p_BC)

    def lens(self) -> Lens:
        return Lens.make(self.width, self.height, self.focal_length, self.distortion,
                         self.rectified_scale, self.X_BC().GetAsMatrix4())


class TimedCamera(LeafSystem):
    """Exposure and publication timing shared by the camera sources. Subclasses implement
    `_expose(context) -> CameraFrame | None` (None: the frame is lost).

    Output `down_image`  CameraFrame, the latest published frame (invalid before the first); the
                         forward RGB-D camera names it `rgbd` (`output_name`)
    """

    def __init__(self, params: DownCameraParams, output_name: str = "down_image"):
        super().__init__()
        self._params = params
        self._pending = self.DeclareAbstractState(AbstractValue.Make([]))
        self._frame = self.DeclareAbstractState(AbstractValue.Make(CameraFrame()))
        self.DeclarePeriodicUnrestrictedUpdateEvent(params.period, params.phase, self._on_exposure)
        self.DeclarePeriodicUnrestrictedUpdateEvent(params.period, params.phase + params.latency,
                                                    self._on_release)
        self.DeclareStateOutputPort(output_name, self._frame)

    def _on_exposure(self, context, state):
        self._queue(context, state, self._expose(context))

    def _queue(self, context, state, frame: CameraFrame | None) -> None:
        """Schedules `frame` (None: lost) for publication `latency` after this exposure."""
        pending = list(context.get_abstract_state(self._pending).get_value())
        if frame is not None:
            pending.append((context.get_time() + self._params.latency, frame))
        state.get_mutable_abstract_state(self._pending).set_value(pending)

    def _on_release(self, context, state):
        t = context.get_time() + 1e-9
        pending = context.get_abstract_state(self._pending).get_value()
        released = [frame for release, frame in pending if release <= t]
        if released:
            state.get_mutable_abstract_state(self._frame).set_value(released[-1])
        state.get_mutable_abstract_state(self._pending).set_value(
            [(release, frame) for release, frame in pending if release > t])

    def _stamp(self, context) -> float:
        return context.get_time() + self._params.stamp_offset

    def _expose(self, context) -> CameraFrame | None:
        raise NotImplementedError


# Drake's VTK renders put the image content half a pixel up and left of where CameraInfo's
# pinhole (pixel centres at integer coordinates) projects it (measured: pattern corners at -0.49 px
# in u and v, tests/test_target_camera.py; cf. RobotLocomotion/drake PR 10190). The lens model
# samples the render accordingly.
RENDER_PIXEL_OFFSET = -0.5


def render_intrinsics(params: DownCameraParams) -> tuple[int, int, float, float, float]:
    """Width, height, focal length, cx, cy of a pinhole render that covers the lens's field."""
    lens = params.lens()
    w, h = lens.width - 1, lens.height - 1
    border = np.concatenate([np.stack([np.linspace(0, w, 64), np.full(64, v)], 1) for v in (0, h)]
                            + [np.stack([np.full(64, u), np.linspace(0, h, 64)], 1) for u in (0, w)])
    xy = np.abs(lens.normalized(border)).max(axis=0)
    f = params.focal_length * params.render_scale
    width, height = (2 * np.ceil(f * xy) + 3).astype(int)
    return int(width), int(height), f, (width - 1) / 2, (height - 1) / 2


class RenderedDownCamera(TimedCamera):
    """Input  `color_image`  ImageRgba8U, the pinhole render (`render_intrinsics`) at the camera pose
    Input  `noise_seed`   (1) uniform in [0, 1), resampled every period: seeds the pixel noise
    Output `down_image`   CameraFrame: grey uint8 image of the distorted lens, calibration
    """

    def __init__(self, params: DownCameraParams):
        super().__init__(params)
        self._lens = params.lens()
        self._calibration = self._lens.calibration()
        _, _, f, cx, cy = render_intrinsics(params)
        u, v = np.meshgrid(np.arange(self._lens.width, dtype=np.float64),
                           np.arange(self._lens.height, dtype=np.float64))
        xy = self._lens.normalized(np.stack([u.ravel(), v.ravel()], 1))
        map_x = (f * xy[:, 0] + cx + RENDER_PIXEL_OFFSET).reshape(u.shape).astype(np.float32)
        map_y = (f * xy[:, 1] + cy + RENDER_PIXEL_OFFSET).reshape(u.shape).astype(np.float32)
        self._maps = cv2.convertMaps(map_x, map_y, cv2.CV_16SC2)
        self._color = self.DeclareAbstractInputPort("color_image", AbstractValue.Make(ImageRgba8U()))
        self._seed = self.DeclareVectorInputPort("noise_seed", 1)

    def distort(self, rgba: np.ndarray, seed: int = 0) -> np.ndarray:
        """The grey distorted image of a pinhole render (also used by the test rigs)."""
        grey = cv2.cvtColor(np.ascontiguousarray(rgba), cv2.COLOR_RGBA2GRAY)
        image = cv2.remap(grey, *self._maps, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        if self._params.image_noise_std > 0:
            noise = np.random.default_rng(seed).normal(0, self._params.image_noise_std, image.shape)
            image = np.clip(image + noise, 0, 255).astype(np.uint8)
        return image

    def _expose(self, context) -> CameraFrame:
        rgba = self._color.Eval(context).data
        seed = int(self._seed.Eval(context)[0] * 2 ** 31)
        return CameraFrame(stamp=self._stamp(context), image=self.distort(rgba, seed),
                           calibration=self._calibration)


class GeometricDownCamera(TimedCamera):
    """Input  `body_poses`  the plant's body poses (the vehicle's and the target platform's)
    Input  `noise`       (2 n + n + 1) unit white Gaussian noise, resampled every period: pixel
                         noise, keypoint dropouts, frame dropout (n keypoints)
    Output `down_image`  CameraFrame without image: keypoints (distorted pixels), keypoint_ids,
                         calibration
    """

    def __init__(self, params: DownCameraParams, p_TK: np.ndarray, body_index, platform_index):
        super().__init__(params)
        self._lens = params.lens()
        self._calibration = self._lens.calibration()
        self._p_TK = np.asarray(p_TK, float)
        self._X_BC = params.X_BC()
        self._body = int(body_index)
        self._platform = int(platform_index)
        n = len(self._p_TK)
        self._poses = self.DeclareAbstractInputPort("body_poses", AbstractValue.Make(
            [RigidTransform()]))
        self._noise = self.DeclareVectorInputPort("noise", 3 * n + 1)
        corners = np.array([[0, 0], [self._lens.width - 1, self._lens.height - 1]], float)
        self._max_radius = 1.02 * np.linalg.norm(self._lens.normalized(corners), axis=1).max()

    def noise_size(self) -> int:
        return 3 * len(self._p_TK) + 1

    def _expose(self, context) -> CameraFrame | None:
        p = self._params
        noise = self._noise.Eval(context)
        n = len(self._p_TK)
        if norm.cdf(noise[-1]) < p.frame_dropout:
            return None
        poses = self._poses.Eval(context)
        X_WC = poses[self._body] @ self._X_BC
        X_TC = poses[self._platform].inverse() @ X_WC
        uv, visible = self.observe(X_TC)
        visible &= norm.cdf(noise[2 * n:3 * n]) >= p.keypoint_dropout
        uv = uv + p.keypoint_noise_std * noise[:2 * n].reshape(n, 2)
        ids = np.flatnonzero(visible)
        return CameraFrame(stamp=self._stamp(context), calibration=self._calibration,
                           keypoints=uv[ids], keypoint_ids=ids)

    def observe(self, X_TC: RigidTransform) -> tuple[np.ndarray, np.ndarray]:
        """Noise-free distorted pixels of every keypoint and whether each can be seen: in front of
        the camera, within the lens's field and the image (minus the border margin), and the
        pattern seen from above within `max_view_angle` of its normal."""
        p = self._params
        p_TC = X_TC.translation()
        p_CK = (X_TC.inverse().GetAsMatrix34() @ np.vstack([self._p_TK.T, np.ones(len(self._p_TK))])).T
        in_front = p_CK[:, 2] > 0.05
        radius = np.linalg.norm(p_CK[:, :2], axis=1) / np.maximum(p_CK[:, 2], 1e-9)
        in_field = in_front & (radius < self._max_radius)
        uv = np.full((len(p_CK), 2), np.nan)
        if in_field.any():
            uv[in_field] = self._lens.project(p_CK[in_field])
        rays = p_TC - self._p_TK
        cos_view = rays[:, 2] / np.linalg.norm(rays, axis=1)
        facing = cos_view > np.cos(np.radians(p.max_view_angle))
        visible = in_field & facing & self._lens.in_image(np.nan_to_num(uv, nan=-1e9),
                                                          p.border_margin)
        return uv, visible
