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
  re-identification. A model of the front end's output, not of the scene's points (issue 20):
  - occlusion: a landmark is not observed when the segment from the camera centre to it crosses a
    box of the map (slab test, visible candidates x boxes; its own box is left out, since a point
    on a face is hidden by its own box only when that face turns away), nor when the outward
    normal of its face points away from the camera (back face; the ground's normal is +z);
  - outlier matches: each tracked keypoint jumps with probability `outlier_probability` to a
    wrong pixel (`outlier_error` px away, uniform, in a uniform direction) keeping its track id,
    as a KLT tracker sliding onto another corner does, with the depth of the surface seen at that
    wrong pixel (ray cast on the ground and the boxes, NaN for the sky). The track ends there
    (the landmark comes back under a new id), as the front end's consistency check ends such a
    track on rendered images; a tracker staying on the wrong corner is not modelled.
  All draws come from the frame's `noise_seed` (same scenario and seed: same streams).

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
from alight.systems.sensors.rgbd_camera_map import (LandmarkGrid, LandmarkMap,
                                                    LandmarkMapParams, make_landmark_map)


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
    outlier_probability: float = bounded(0.01, 0.0, 1.0)         # per tracked keypoint and frame
    outlier_error: list[float] = bounded([5.0, 40.0], 0.0, 1000.0, "px")  # jump length range
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
    finite = np.isfinite(z)                # a rendered sky is at infinity
    z = np.where(finite, z, 0.0)
    noisy = z + rng.standard_normal(z.shape) * depth_noise_std(
        z, params.focal_length, params.baseline, params.disparity_noise_std)
    missing = holes | ~finite | (z < params.depth_min) | (z > params.depth_max)
    return np.where(missing, np.nan, noisy)


GRID = (8, 6)  # feature bucketing cells (columns, rows)


def _slab(c: np.ndarray, d: np.ndarray, boxes: np.ndarray):
    """Ray c + t d (c (3,), d (N, 3)) against boxes (M, >= 5: x0, y0, x1, y1, height; standing on
    z = 0): entry and exit parameters (N, M); the ray meets a box where exit >= max(entry, 0)."""
    lo = np.column_stack([boxes[:, :2], np.zeros(len(boxes))])
    hi = np.column_stack([boxes[:, 2:4], boxes[:, 4]])
    d = np.where(np.abs(d) < 1e-12, 1e-12, d)
    entry, exit_ = None, None
    for k in range(3):  # per axis on (N, M) arrays: faster than a reduction over a short axis
        inv = 1.0 / d[:, k:k + 1]
        t1, t2 = (lo[:, k] - c[k]) * inv, (hi[:, k] - c[k]) * inv
        near, far = np.minimum(t1, t2), np.maximum(t1, t2)
        entry = near if entry is None else np.maximum(entry, near)
        exit_ = far if exit_ is None else np.minimum(exit_, far)
    return entry, exit_


def occluded(c: np.ndarray, p: np.ndarray, boxes: np.ndarray, own: np.ndarray) -> np.ndarray:
    """(N,) whether the segment from c (3,) to each point p (N, 3) crosses a box before reaching
    the point; a point's own box (`own` (N,), -1: none) is left out."""
    if not len(p) or not len(boxes):
        return np.zeros(len(p), bool)
    entry, exit_ = _slab(c, p - c, boxes)
    hit = (exit_ >= np.maximum(entry, 0.0)) & (entry < 1.0 - 1e-9)
    mine = own >= 0
    hit[np.flatnonzero(mine), own[mine]] = False
    return hit.any(axis=1)


def ray_depth(c: np.ndarray, d: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """The parameter t (N,) of the first surface (ground z = 0 or a box) on each ray c + t d
    (inf: none). With d = R_WC [x, y, 1] it is the depth (z in C) seen at that pixel."""
    with np.errstate(divide="ignore"):
        t = np.where(d[:, 2] < 0, -c[2] / d[:, 2], np.inf)
    if len(boxes) and len(d):
        entry, exit_ = _slab(c, d, boxes)
        t_box = np.where(exit_ >= np.maximum(entry, 0.0), np.maximum(entry, 0.0), np.inf)
        t = np.minimum(t, t_box.min(axis=1))
    return t


class GeometricRgbdCamera(TimedCamera):
    """Input  `body_poses`  the plant's body poses (the vehicle's is used)
    Input  `noise_seed`  (1) uniform in [0, 1), resampled every period: seeds this frame's noise
    Output `rgbd`        CameraFrame without image: keypoints (N, 2) [px], keypoint_ids (N,) track
                         ids, depth (N,) per keypoint [m, NaN: no depth], calibration
    """

    def __init__(self, params: RgbdCameraParams, body_index, landmarks: LandmarkMap = None):
        super().__init__(params, output_name="rgbd")
        self._lens = params.lens()
        self._calibration = params.calibration()
        self._X_BC = params.X_BC()
        self._body = int(body_index)
        self.landmarks = landmarks if landmarks is not None else make_landmark_map(
            params.landmarks)
        # Homogeneous landmark coordinates (4, N), for one product per frame.
        self._p_WL_h = np.vstack([self.landmarks.p_WL.T, np.ones(len(self.landmarks.p_WL))])
        self._boxes = self.landmarks.boxes[:, :5]
        self._focal, self._center = self._lens.K[[0, 1], [0, 1]], self._lens.K[:2, 2]
        # A map along a road holds 10^5 landmarks: each frame projects only those of the cells
        # that reach into the view frustum (`_boxes_in_view`).
        self._grid = LandmarkGrid(self.landmarks.p_WL, cell=params.max_range / 4)
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
        X_WC = self._poses.Eval(context)[self._body] @ self._X_BC
        frame, tracks, next_id, _ = self.observe(X_WC, self._stamp(context), rng, tracks, next_id)
        return frame, tracks, next_id

    def observe(self, X_WC: RigidTransform, stamp: float, rng, tracks: dict, next_id: int):
        """One frame from the camera pose X_WC: (frame or None, the new {landmark: track id},
        the next free track id, which keypoints are outliers (N,) bool)."""
        p = self._params
        if rng.random() < p.frame_dropout:
            return None, {}, next_id, np.zeros(0, bool)
        visible, uv, z = self._visible(X_WC)
        # Rows of `visible` (its uv, z): tracked in the last frame or not.
        was_tracked = np.isin(visible, np.fromiter(tracks, int, len(tracks)))
        tracked = np.flatnonzero(was_tracked)
        # One draw per tracked landmark, in order (as many draws as one call each).
        kept = tracked[rng.random(len(tracked)) >= p.track_loss]
        fresh = self._spread(np.flatnonzero(~was_tracked), kept, uv, rng)
        rows = np.concatenate([kept, fresh])[:p.max_features]
        selected = visible[rows]
        new_tracks = {i: tracks[i] for i in visible[kept].tolist()}
        for i in selected[len(kept):].tolist():
            new_tracks[i], next_id = next_id, next_id + 1
        n = len(selected)
        ids = np.array([new_tracks[i] for i in selected.tolist()], np.int64)
        keypoints = self._lens.project(self._points_C(X_WC, selected)) \
            + p.keypoint_noise_std * rng.standard_normal((n, 2)) if n else np.zeros((0, 2))
        # Outlier matches: a tracked keypoint (not a fresh detection) slides to a wrong pixel.
        jump = (rng.random(n) < p.outlier_probability) & (np.arange(n) < len(kept))
        length = rng.uniform(*p.outlier_error, n)
        angle = rng.uniform(0.0, 2 * np.pi, n)
        z_true = z[rows]
        if jump.any():
            moved = keypoints[jump] + length[jump, None] * np.column_stack(
                [np.cos(angle[jump]), np.sin(angle[jump])])
            moved = np.clip(moved, 0.0, [self._lens.width - 1.0, self._lens.height - 1.0])
            keypoints[jump] = moved
            R_WC = X_WC.rotation().matrix()
            rays = np.column_stack([(moved - self._center) / self._focal,
                                    np.ones(len(moved))]) @ R_WC.T
            z_true = z_true.copy()
            seen = ray_depth(X_WC.translation(), rays, self._boxes)
            z_true[jump] = np.where(np.isfinite(seen), seen, np.nan)  # NaN: the sky
            for i in selected[jump]:  # the track ends on the wrong corner
                del new_tracks[int(i)]
        depth = _noisy_depth(rng, z_true, p, rng.random(n) < p.hole_probability)
        frame = CameraFrame(stamp=stamp, calibration=self._calibration, keypoints=keypoints,
                            keypoint_ids=ids, depth=depth)
        return frame, new_tracks, next_id, jump

    def _spread(self, fresh: np.ndarray, kept: np.ndarray, uv: np.ndarray, rng) -> np.ndarray:
        """The `fresh` rows of `uv` (noise-free pixels) ordered as a detector with a bucketing
        grid picks new features: evenly over the image (GRID cells, the emptiest first, the
        `kept` tracks counted), not where landmarks crowd (near the horizon)."""
        def cells(rows):
            return (np.clip(uv[rows, 0] * GRID[0] / self._lens.width, 0, GRID[0] - 1)
                    .astype(int) * GRID[1] + np.clip(uv[rows, 1] * GRID[1] / self._lens.height,
                                                     0, GRID[1] - 1).astype(int))
        fresh = fresh[rng.permutation(len(fresh))]
        if not len(fresh):
            return fresh
        count = np.bincount(cells(kept), minlength=GRID[0] * GRID[1])
        # Each new feature's rank: the features already in its cell (kept, then the new ones
        # before it in the shuffled order).
        cell = cells(fresh)
        order = np.argsort(cell, kind="stable")
        first = np.searchsorted(cell[order], cell[order])
        before = np.empty(len(fresh), int)
        before[order] = np.arange(len(fresh)) - first
        rank = count[cell] + before
        return fresh[np.argsort(rank, kind="stable")]

    def _points_C(self, X_WC: RigidTransform, indices=None) -> np.ndarray:
        """Landmarks (all, or those of `indices`) in the camera frame C."""
        p_WL_h = self._p_WL_h if indices is None else self._p_WL_h[:, indices]
        return (X_WC.inverse().GetAsMatrix34() @ p_WL_h).T

    def _boxes_in_view(self, X_WC: RigidTransform, boxes: np.ndarray = None) -> np.ndarray:
        """Rows of the boxes (default: the map's) not wholly outside one plane of the view frustum
        (behind the camera, beyond `max_range`, or beyond one image edge), in increasing order."""
        b = self._boxes if boxes is None else boxes
        if not len(b):
            return np.zeros(0, int)
        corners = np.stack(np.meshgrid([0, 2], [1, 3], [0, 1], indexing="ij"), -1).reshape(-1, 3)
        p_W = np.stack([b[:, corners[:, 0]], b[:, corners[:, 1]],
                        b[:, 4:5] * corners[:, 2]], axis=-1)            # (M, 8, 3)
        X_CW = X_WC.inverse()
        p_C = p_W @ X_CW.rotation().matrix().T + X_CW.translation()
        x, y, z = p_C[..., 0], p_C[..., 1], p_C[..., 2]
        (fx, fy), (cx, cy) = self._focal, self._center
        w, h = self._lens.width, self._lens.height
        outside = ((z <= 0).all(1) | (z >= self._params.max_range).all(1)
                   | (fx * x + cx * z < 0).all(1)
                   | (fx * x - (w - cx) * z > 0).all(1)
                   | (fy * y + cy * z < 0).all(1) | (fy * y - (h - cy) * z > 0).all(1))
        return np.flatnonzero(~outside)

    def visible(self, X_WC: RigidTransform) -> tuple[list[int], np.ndarray, np.ndarray]:
        """`_visible` with the indices as a list."""
        visible, uv, z = self._visible(X_WC)
        return visible.tolist(), uv, z

    def _visible(self, X_WC: RigidTransform) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Indices of the landmarks a detector would find (in front, within range, inside the
        image minus the border, on a face turned toward the camera, not hidden by a box), in
        increasing order, with their noise-free pixels (N, 2) and ranges (z in C) (N,) in the
        same order. Only the landmarks of the grid cells that reach into the view are projected
        (a map along a road holds 10^5 of them)."""
        p = self._params
        c = X_WC.translation()
        near = self._grid.members(self._boxes_in_view(X_WC, self._grid.boxes))
        p_CL = self._points_C(X_WC, near)
        z = p_CL[:, 2]
        ahead = (z > 0.1) & (z < p.max_range)
        near, p_CL, z = near[ahead], p_CL[ahead], z[ahead]
        uv = p_CL[:, :2] / z[:, None] * self._focal + self._center
        keep = self._lens.in_image(uv, p.border_margin)
        order = np.argsort(near[keep])
        candidates, uv, z = near[keep][order], uv[keep][order], z[keep][order]
        m = self.landmarks
        p_WL = m.p_WL[candidates]
        front = np.einsum("ij,ij->i", m.n_WL[candidates], c - p_WL) > 0
        candidates, p_WL, uv, z = candidates[front], p_WL[front], uv[front], z[front]
        # Only boxes that reach into the view frustum can hide a point in it.
        in_view = self._boxes_in_view(X_WC)
        own = np.full(len(candidates), -1)
        mine = np.isin(m.box[candidates], in_view)
        own[mine] = np.searchsorted(in_view, m.box[candidates][mine])
        seen = ~occluded(c, p_WL, self._boxes[in_view], own)
        return candidates[seen], uv[seen], z[seen]


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
