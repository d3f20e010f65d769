"""The downward camera (issue 5; L Sec. 3.1, 5.2): 20 Hz frames with exposure latency and stamps that
are not synchronized to the IMU, in two sources (DESIGN.md "Simulation fidelity"):

- `RenderedDownCamera`: a Drake `RgbdSensor` pinhole colour render of the scene, distorted through
  the lens model (`down_camera_lens.Lens`) by `cv2.remap`, converted to grey, with pixel noise;
- `GeometricDownCamera`: a sensor model of the image front end's output: the landing pattern's
  keypoints projected through the same lens model as unlabelled candidates, with the misses
  (motion blur, distance, the vehicle's legs), noise, outliers and false candidates of the
  rendered pipeline (calibrated: bench/sensing_calibration.py); `mode: labelled` keeps the
  idealized labelled keypoints.

Timing, common to both: exposures at `phase + k period` (not on the IMU's sample grid); a frame is
published `latency` after its exposure; its stamp is the exposure time plus `stamp_offset` (the
clock error of an unsynchronized camera, which the paper blames for part of its errors, L Sec. 5.2.2).
"""
import dataclasses as dc

import cv2
import numpy as np
from pydrake.common.eigen_geometry import AngleAxis
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix
from pydrake.multibody.math import SpatialVelocity
from pydrake.systems.framework import LeafSystem
from pydrake.systems.sensors import ImageRgba8U

from alight.systems.boundary import CameraFrame
from alight.systems.params import bounded, choice
from alight.systems.rotations import norm
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
    # geometric source (GeometricDownCamera; calibration: docs/target.md)
    mode: str = choice("candidates", "labelled")
    keypoint_noise_std: float = bounded(0.3, 0.0, 100.0, "px")
    frame_dropout: float = bounded(0.02, 0.0, 1.0)
    keypoint_dropout: float = bounded(0.01, 0.0, 1.0)
    border_margin: float = bounded(10.0, 0.0, 1000.0, "px")
    max_view_angle: float = bounded(80.0, 0.0, 90.0, "deg")
    exposure: float = bounded(0.005, 0.0, 0.1, "s")
    blur_halving: float = bounded(28.0, 0.0, 1e4, "px")
    blur_width: float = bounded(3.0, 0.1, 1e4, "px")
    blur_noise: float = bounded(0.08, 0.0, 10.0, "px/px")
    size_halving: float = bounded(36.0, 0.0, 1e4, "px")
    size_width: float = bounded(5.0, 0.1, 1e4, "px")
    outlier_probability: float = bounded(0.02, 0.0, 1.0)
    outlier_radius: float = bounded(25.0, 0.0, 1000.0, "px")
    false_pattern_rate: float = bounded(0.3, 0.0, 100.0, "per frame")
    false_body_rate: float = bounded(1.0, 0.0, 100.0, "per frame")

    def X_BC(self) -> RigidTransform:
        return RigidTransform(RollPitchYaw(np.radians(self.rpy_BC)), self.p_BC)

    def lens(self) -> Lens:
        return Lens.make(self.width, self.height, self.focal_length, self.distortion,
                         self.rectified_scale, self.X_BC().GetAsMatrix4())


class TimedCamera(LeafSystem):
    """Exposure and publication timing shared by the camera sources. Subclasses implement
    `_expose(context) -> CameraFrame | None` (None: the frame is lost).

    Output `down_image`  CameraFrame, the latest frame published by the output's time: each frame
                         `latency` after its exposure (invalid before the first); the forward
                         RGB-D camera names it `rgbd` (`output_name`)

    One periodic event per frame, the exposure; a frame's publication is not an event of its own
    (an event off the plant's 2 ms grid is a simulator step: 50 per simulated second for the two
    cameras' arrivals): the output takes the newest pending frame whose arrival time has come, as
    an arrival event would have published it, and the next exposure moves it to the state.
    """

    def __init__(self, params: DownCameraParams, output_name: str = "down_image"):
        super().__init__()
        self._params = params
        self._pending = self.DeclareAbstractState(AbstractValue.Make([]))
        self._frame = self.DeclareAbstractState(AbstractValue.Make(CameraFrame()))
        self.DeclarePeriodicUnrestrictedUpdateEvent(params.period, params.phase, self._on_exposure)
        self.DeclareAbstractOutputPort(
            output_name, lambda: AbstractValue.Make(CameraFrame()), self._calc_frame,
            {self.abstract_state_ticket(self._pending), self.abstract_state_ticket(self._frame),
             self.time_ticket()})

    def _calc_frame(self, context, output):
        pending = context.get_abstract_state(self._pending).get_value()
        frame = _published(pending, context.get_time())
        output.set_value(frame if frame is not None
                         else context.get_abstract_state(self._frame).get_value())

    def _on_exposure(self, context, state):
        self._queue(context, state, self._expose(context))

    def _queue(self, context, state, frame: CameraFrame | None) -> None:
        """Publishes the frames whose arrival time has come, and schedules `frame` (None: lost)
        for publication `latency` after this exposure."""
        t = context.get_time()
        pending = context.get_abstract_state(self._pending).get_value()
        published = _published(pending, t)
        if published is not None:
            state.get_mutable_abstract_state(self._frame).set_value(published)
        pending = [(release, f) for release, f in pending if release > t + _ARRIVAL_TOLERANCE]
        if frame is not None:
            pending.append((t + self._params.latency, frame))
        state.get_mutable_abstract_state(self._pending).set_value(pending)

    def _stamp(self, context) -> float:
        return context.get_time() + self._params.stamp_offset

    def _expose(self, context) -> CameraFrame | None:
        raise NotImplementedError


_ARRIVAL_TOLERANCE = 1e-9  # s: a frame due at the output's time (rounding of t + latency) is out


def _published(pending: list, t: float) -> CameraFrame | None:
    """The newest of the `pending` (arrival time, frame) pairs that has arrived by `t`."""
    arrived = [frame for release, frame in pending if release <= t + _ARRIVAL_TOLERANCE]
    return arrived[-1] if arrived else None


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
    """A sensor model of the image front end's output (DESIGN.md "Simulation fidelity").

    `mode: candidates` (the default): what the detector and the keypoint tracker would find in the
    frame, as unlabelled, shuffled keypoint candidates (distorted pixels, `keypoint_ids` None), so
    that the estimator's own association, symmetry resolution and outlier rejection run on them:
    - the pattern's keypoints within the field, the image (minus `border_margin`) and
      `max_view_angle`, and not behind one of the vehicle's own legs (`legs`: capsules in B, from
      the airframe's SDF); the pattern is found in a frame with probability
      `sigma((blur_halving - b) / blur_width) sigma((s - size_halving) / size_width)` (sigma the
      logistic function), b the motion blur [px] of the pattern's centre over `exposure` (the
      vehicle's and the platform's velocities), s the white square's side [px]; each keypoint is
      then missed with `keypoint_dropout`;
    - pixel noise of standard deviation `keypoint_noise_std + blur_noise b`, and with
      `outlier_probability` a keypoint displaced by up to `outlier_radius`;
    - false candidates: a Poisson number `false_pattern_rate` per frame on the platform (look-alike
      junctions of the ring and the cross) and `false_body_rate` on the car body's outline
      (`outline_T`, its top rectangle in T), both where the camera sees them.
    The rates and noise are calibrated against the rendered pipeline (bench/sensing_calibration.py,
    docs/target.md).

    `mode: labelled` (an idealization): the observed keypoints with their ids, Gaussian noise, the
    same visibility and misses, no false candidates or outliers.

    Input  `body_poses`               the plant's body poses (vehicle's, platform's)
    Input  `body_spatial_velocities`  the plant's body spatial velocities (motion blur)
    Input  `noise_seed`               (1) uniform in [0, 1), resampled every period
    Output `down_image`               CameraFrame without image: keypoints, calibration
    """

    def __init__(self, params: DownCameraParams, p_TK: np.ndarray, body_index, platform_index,
                 legs: tuple = (), outline_T: np.ndarray | None = None):
        super().__init__(params)
        self._lens = params.lens()
        self._calibration = self._lens.calibration()
        self._p_TK = np.asarray(p_TK, float)
        self._X_BC = params.X_BC()
        self._body = int(body_index)
        self._platform = int(platform_index)
        # the legs' capsules (L, 3), (L, 3), (L,) and the pattern's homogeneous keypoints (4, N)
        self._leg_a = np.array([a for a, _, _ in legs], float).reshape(-1, 3)
        self._leg_b = np.array([b for _, b, _ in legs], float).reshape(-1, 3)
        self._leg_radius = np.array([r for _, _, r in legs], float)
        self._p_TK_h = _homogeneous(self._p_TK)
        self._cos_max_view = np.cos(np.radians(params.max_view_angle))
        self._outline_T = None if outline_T is None else np.asarray(outline_T, float)
        if self._outline_T is not None:  # the perimeter's edges and their arc-length intervals
            self._outline_edges = np.roll(self._outline_T, -1, axis=0) - self._outline_T
            self._outline_lengths = np.linalg.norm(self._outline_edges, axis=1)
            self._outline_ends = np.cumsum(self._outline_lengths)
            self._outline_starts = np.concatenate([[0], self._outline_ends])
        self._poses = self.DeclareAbstractInputPort("body_poses", AbstractValue.Make(
            [RigidTransform()]))
        self._velocities = self.DeclareAbstractInputPort(
            "body_spatial_velocities", AbstractValue.Make([SpatialVelocity()]))
        self._seed = self.DeclareVectorInputPort("noise_seed", 1)
        corners = np.array([[0, 0], [self._lens.width - 1, self._lens.height - 1]], float)
        self._max_radius = 1.02 * np.linalg.norm(self._lens.normalized(corners), axis=1).max()

    def _expose(self, context) -> CameraFrame | None:
        poses = self._poses.Eval(context)
        velocities = self._velocities.Eval(context)
        rng = np.random.default_rng(int(self._seed.Eval(context)[0] * 2 ** 31))
        if rng.random() < self._params.frame_dropout:
            return None
        X_WC = poses[self._body] @ self._X_BC
        X_TC = poses[self._platform].inverse() @ X_WC
        X_TC_before = _moved(poses[self._platform], velocities[self._platform],
                             -self._params.exposure).inverse() @ \
            _moved(poses[self._body], velocities[self._body], -self._params.exposure) @ self._X_BC
        if self._params.mode == "labelled":
            return self._labelled(context, X_TC, rng)
        uv, _ = self.candidates(X_TC, X_TC_before, rng)
        return CameraFrame(stamp=self._stamp(context), calibration=self._calibration,
                           keypoints=uv)

    def _labelled(self, context, X_TC, rng) -> CameraFrame | None:
        p = self._params
        uv, visible = self.observe(X_TC)
        visible &= rng.random(len(uv)) >= p.keypoint_dropout
        ids = np.flatnonzero(visible)
        uv = uv[ids] + p.keypoint_noise_std * rng.standard_normal((len(ids), 2))
        return CameraFrame(stamp=self._stamp(context), calibration=self._calibration,
                           keypoints=uv, keypoint_ids=ids)

    def candidates(self, X_TC: RigidTransform, X_TC_before: RigidTransform,
                   rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """The frame's shuffled candidates (N, 2) in distorted pixels and what each one is (the
        pattern keypoint's id, or -1 for a false candidate: for tests and the calibration, never
        sent). `X_TC_before`: the camera `exposure` earlier (motion blur)."""
        p = self._params
        uv, visible = self.observe(X_TC)
        blur = self.blur(X_TC, X_TC_before)
        if rng.random() >= self.detection_probability(X_TC, blur):
            visible[:] = False
        visible &= rng.random(len(uv)) >= p.keypoint_dropout
        ids = np.flatnonzero(visible)
        noise_std = p.keypoint_noise_std + p.blur_noise * blur
        uv = uv[ids] + noise_std * rng.standard_normal((len(ids), 2))
        outliers = rng.random(len(ids)) < p.outlier_probability
        uv[outliers] += _uniform_in_disc(rng, outliers.sum(), p.outlier_radius)
        false_uv = np.vstack([self._false_candidates(X_TC, rng, p.false_pattern_rate,
                                                     self._on_platform),
                              self._false_candidates(X_TC, rng, p.false_body_rate,
                                                     self._on_outline)])
        uv = np.vstack([uv, false_uv])
        truth = np.concatenate([ids, np.full(len(false_uv), -1)])
        order = rng.permutation(len(uv))
        return uv[order], truth[order]

    def blur(self, X_TC: RigidTransform, X_TC_before: RigidTransform) -> float:
        """Motion blur [px]: the image motion of the pattern's centre over the exposure (inf when
        it is behind the camera)."""
        p_CT = [X.inverse().translation() for X in (X_TC, X_TC_before)]
        if min(q[2] for q in p_CT) <= 0.05:
            return float("inf")
        uv = self._lens.project(np.array(p_CT))  # one call, point by point the same pixels
        return float(np.linalg.norm(uv[0] - uv[1]))

    def detection_probability(self, X_TC: RigidTransform, blur: float) -> float:
        """Probability that the front end finds the pattern in a frame that arrives, from the
        motion blur [px] and the white square's side in pixels."""
        p = self._params
        if not np.isfinite(blur):
            return 0.0
        side = self._lens.K[0, 0] * 2 * np.abs(self._p_TK[0, 0]) / X_TC.inverse().translation()[2]
        return float(_logistic((p.blur_halving - blur) / p.blur_width)
                     * _logistic((side - p.size_halving) / p.size_width))

    def _false_candidates(self, X_TC, rng, rate: float, sample) -> np.ndarray:
        n = rng.poisson(rate)
        if n == 0:
            return np.zeros((0, 2))
        p_TF = sample(rng, n)
        if p_TF is None:
            return np.zeros((0, 2))
        uv, visible = self._visible(X_TC, p_TF)
        return uv[visible]

    def _on_platform(self, rng, n: int) -> np.ndarray:
        """Look-alikes on the pattern: uniform over the white square."""
        a = np.abs(self._p_TK[0, 0])
        return np.column_stack([rng.uniform(-a, a, (n, 2)), np.zeros(n)])

    def _on_outline(self, rng, n: int) -> np.ndarray | None:
        """Edges and corners of the car's body: uniform along its top rectangle's perimeter."""
        if self._outline_T is None:
            return None
        lengths, edges = self._outline_lengths, self._outline_edges
        s = rng.uniform(0, lengths.sum(), n)
        k = np.searchsorted(self._outline_ends, s, side="right").clip(0, 3)
        fraction = (s - self._outline_starts[k]) / lengths[k]
        return self._outline_T[k] + fraction[:, None] * edges[k]

    def observe(self, X_TC: RigidTransform) -> tuple[np.ndarray, np.ndarray]:
        """Noise-free distorted pixels of every pattern keypoint and whether each can be seen (see
        `_visible`)."""
        return self._visible(X_TC, self._p_TK, self._p_TK_h)

    def _visible(self, X_TC: RigidTransform, p_TK: np.ndarray,
                 p_TK_h: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Distorted pixels of points on the platform (T) and whether each can be seen: in front of
        the camera, within the lens's field and the image (minus the border margin), the pattern
        seen from above within `max_view_angle` of its normal, and no leg on the ray. `p_TK_h`:
        the points' homogeneous coordinates, when known."""
        p_TC = X_TC.translation()
        p_TK_h = _homogeneous(p_TK) if p_TK_h is None else p_TK_h
        p_CK = (X_TC.inverse().GetAsMatrix34() @ p_TK_h).T
        in_front = p_CK[:, 2] > 0.05
        radius = np.linalg.norm(p_CK[:, :2], axis=1) / np.maximum(p_CK[:, 2], 1e-9)
        in_field = in_front & (radius < self._max_radius)
        uv = np.full((len(p_CK), 2), np.nan)
        if not in_field.any():
            return uv, in_field
        uv[in_field] = self._lens.project(p_CK[in_field])
        rays = p_TC - p_TK
        cos_view = rays[:, 2] / np.linalg.norm(rays, axis=1)
        facing = cos_view > self._cos_max_view
        # (nan pixels, outside the field, compare false: not in the image)
        visible = in_field & facing & self._lens.in_image(uv, self._params.border_margin)
        if len(self._leg_radius) and visible.any():
            visible &= ~self.occluded(self._X_BC.multiply(p_CK.T).T)
        return uv, visible

    def occluded(self, p_BK: np.ndarray) -> np.ndarray:
        """Whether the ray from the camera to each point (in B) passes one of the legs."""
        distances = _segment_distances(self._X_BC.translation(), p_BK, self._leg_a, self._leg_b)
        return np.any(distances < self._leg_radius[:, None], axis=0)


def _moved(X_WA: RigidTransform, V_WA: SpatialVelocity, dt: float) -> RigidTransform:
    """The pose `dt` later at constant spatial velocity (first order in the rotation vector)."""
    w = V_WA.rotational()
    rate = norm(w)
    axis = w / rate if rate > 0 else np.array([0.0, 0.0, 1.0])
    R = RotationMatrix(AngleAxis(float(rate * dt), axis)) @ X_WA.rotation()
    return RigidTransform(R, X_WA.translation() + V_WA.translational() * dt)


def _logistic(x: float) -> float:
    return 1.0 / (1.0 + np.exp(-np.clip(x, -50.0, 50.0)))


def _uniform_in_disc(rng, n: int, radius: float) -> np.ndarray:
    angle = rng.uniform(0, 2 * np.pi, n)
    r = radius * np.sqrt(rng.uniform(0, 1, n))
    return np.column_stack([r * np.cos(angle), r * np.sin(angle)])


def _homogeneous(p: np.ndarray) -> np.ndarray:
    """(4, N) homogeneous coordinates of points (N, 3)."""
    return np.vstack([p.T, np.ones(len(p))])


def _segment_distances(p: np.ndarray, q: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distances (M, N) between the segments p-q[i] (N) and a[j]-b[j] (M) (closest points,
    clamped). The dot products are taken segment by segment (the same sums as for one)."""
    d1 = q - p
    d2 = b - a
    r = p - a
    aa = np.einsum("ij,ij->i", d1, d1)
    ee = np.array([d @ d for d in d2])[:, None]
    f = np.array([r_j @ d for r_j, d in zip(r, d2)])[:, None]
    c = np.array([d1 @ r_j for r_j in r]).reshape(len(a), len(q))
    bb = np.array([d1 @ d for d in d2]).reshape(len(a), len(q))
    denominator = aa * ee - bb ** 2
    s = np.where(denominator > 1e-12, np.clip((bb * f - c * ee) / np.where(
        denominator > 1e-12, denominator, 1.0), 0, 1), 0.0)
    t = np.clip((bb * s + f) / ee, 0, 1)
    s = np.clip((bb * t - c) / aa, 0, 1)
    return np.linalg.norm(p + s[..., None] * d1 - (a[:, None] + t[..., None] * d2[:, None]),
                          axis=2)
