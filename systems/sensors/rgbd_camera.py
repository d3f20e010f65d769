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
    box of the map (slab test on the candidate x box pairs that the box's image rectangle and
    nearest corner leave possible; its own box is left out, since a point on a face is hidden by
    its own box only when that face turns away), nor when the outward
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


def _stable_order(keys: np.ndarray, bound: int) -> np.ndarray:
    """np.argsort(keys, kind="stable") of integer keys in [0, bound), sorted as the smallest
    unsigned type that holds them (16 bits or fewer: a radix sort)."""
    return np.argsort(keys.astype(np.min_scalar_type(bound)), kind="stable")


def _bounds(boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The lower and upper corners (M, 3) of boxes (M, >= 5: x0, y0, x1, y1, height; standing on
    z = 0)."""
    lo = np.zeros((len(boxes), 3))
    lo[:, :2] = boxes[:, :2]
    return lo, boxes[:, 2:5]  # (x1, y1, height: a view, no copy)


def _slab(c: np.ndarray, d: np.ndarray, lo: np.ndarray, hi: np.ndarray):
    """Rays c + t d (c (3,), d (..., 3)) against the boxes from corner lo to corner hi (..., 3,
    broadcast with d): entry and exit parameters (...); a ray meets a box where
    exit >= max(entry, 0)."""
    d = np.where(np.abs(d) < 1e-12, 1e-12, d)
    entry, exit_ = None, None
    for k in range(3):  # per axis: faster than a reduction over a short axis
        inv = 1.0 / d[..., k]
        t1, t2 = (lo[..., k] - c[k]) * inv, (hi[..., k] - c[k]) * inv
        near, far = np.minimum(t1, t2), np.maximum(t1, t2)
        entry = near if entry is None else np.maximum(entry, near)
        exit_ = far if exit_ is None else np.minimum(exit_, far)
    return entry, exit_


def occluded(c: np.ndarray, p: np.ndarray, boxes: np.ndarray, own: np.ndarray,
             pairs: np.ndarray = None) -> np.ndarray:
    """(N,) whether the segment from c (3,) to each point p (N, 3) crosses a box before reaching
    the point; a point's own box (`own` (N,), -1: none) is left out, and so are the point-box
    pairs that `pairs` (N, M) bool (default: all pairs) leaves out."""
    hidden = np.zeros(len(p), bool)
    if not len(p) or not len(boxes):
        return hidden
    # box by box (the camera's pairs are the transpose of (M, N) rows)
    j, i = np.nonzero(np.ones((len(boxes), len(p)), bool) if pairs is None else pairs.T)
    other = j != own[i]
    i, j = i[other], j[other]
    lo, hi = _bounds(boxes)
    entry, exit_ = _slab(c, p.take(i, axis=0) - c, lo.take(j, axis=0), hi.take(j, axis=0))
    hidden[i[(exit_ >= np.maximum(entry, 0.0)) & (entry < 1.0 - 1e-9)]] = True
    return hidden


class BoxCorners:
    """The 8 corners `p_W` (M, 8, 3) of boxes (M, >= 5: x0, y0, x1, y1, height; standing on
    z = 0), and the centre (M, 3) and radius (M,) of a sphere around each box's corners; a box
    whose centre is farther than -`cull` (M,) outside a plane is wholly outside it (the margin
    far above rounding)."""

    def __init__(self, boxes: np.ndarray):
        corners = np.stack(np.meshgrid([0, 2], [1, 3], [0, 1], indexing="ij"), -1).reshape(-1, 3)
        self.p_W = np.stack([boxes[:, corners[:, 0]], boxes[:, corners[:, 1]],
                             boxes[:, 4:5] * corners[:, 2]], axis=-1)
        self.centre = self.p_W.mean(axis=1)
        self.radius = np.linalg.norm(self.p_W - self.centre[:, None], axis=2).max(axis=1,
                                                                                   initial=0.0)
        self.cull = -self.radius - 1e-6


def ray_depth(c: np.ndarray, d: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """The parameter t (N,) of the first surface (ground z = 0 or a box) on each ray c + t d
    (inf: none). With d = R_WC [x, y, 1] it is the depth (z in C) seen at that pixel."""
    with np.errstate(divide="ignore"):
        t = np.where(d[:, 2] < 0, -c[2] / d[:, 2], np.inf)
    if len(boxes) and len(d):
        entry, exit_ = _slab(c, d[:, None], *_bounds(boxes))
        t_box = np.where(exit_ >= np.maximum(entry, 0.0), np.maximum(entry, 0.0), np.inf)
        t = np.minimum(t, t_box.min(axis=1))
    return t


def _facing_keys(p_WL: np.ndarray, n_WL: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For the back-face test of landmarks p_WL (N, 3) on faces with outward normals n_WL (N, 3)
    along the axes (the map's boxes are axis-aligned, the ground's normal is +z): codes (N,)
    and keys (N,) such that a face turns toward a camera at c where n (c - p) > 0, that is where
    [c, -c][code] > key. The same decision as the dot product, bit for bit: with n = s e_a
    (s = +-1) the dot product is exactly s (c_a - p_a), positive where s c_a > s p_a."""
    axis = np.argmax(np.abs(n_WL), axis=1)
    sign = n_WL[np.arange(len(n_WL)), axis]
    if not (np.all(np.abs(sign) == 1.0) and np.all(np.count_nonzero(n_WL, axis=1) == 1)):
        raise ValueError("landmark face normals must be +-x, +-y or +-z")
    return axis + 3 * (sign < 0), sign * p_WL[np.arange(len(p_WL)), axis]


@dc.dataclass(frozen=True)
class Tracks:
    """The camera's tracks: {landmark index: track id} of the last frame, and the next free track
    id. A value, never changed once made: Drake's copies of the state (copy.deepcopy, at every
    update of the camera) share it."""
    ids: dict = dc.field(default_factory=dict)
    next_id: int = 0

    def __deepcopy__(self, memo) -> "Tracks":
        return self


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
        self._boxes = self.landmarks.boxes[:, :5]
        self._focal, self._center = self._lens.K[[0, 1], [0, 1]], self._lens.K[:2, 2]
        # A map along a road holds 10^5 landmarks: each frame projects only those of the cells
        # that reach into the view frustum (`_boxes_in_view`).
        self._grid = LandmarkGrid(self.landmarks.p_WL, cell=params.max_range / 4)
        self._box_corners, self._cell_corners = BoxCorners(self._boxes), BoxCorners(
            self._grid.boxes)
        self._frustum = self._frustum_planes()
        # The landmarks in the grid's order (`LandmarkGrid.order`), so that a frame gathers those
        # of a few cells from close together; homogeneous coordinates (N, 4) for one product.
        m, order = self.landmarks, self._grid.order
        self._p_WL_h = np.column_stack([m.p_WL[order], np.ones(len(m.p_WL))])
        self._p_WL, self._box_of = m.p_WL[order], m.box[order]
        self._face_code, self._face_key = _facing_keys(self._p_WL, m.n_WL[order])
        self._poses = self.DeclareAbstractInputPort("body_poses", AbstractValue.Make(
            [RigidTransform()]))
        self._seed = self.DeclareVectorInputPort("noise_seed", 1)
        self._tracks = self.DeclareAbstractState(AbstractValue.Make(Tracks()))

    def _on_exposure(self, context, state):
        tracks = context.get_abstract_state(self._tracks).get_value()
        rng = np.random.default_rng(int(self._seed.Eval(context)[0] * 2 ** 31))
        frame, ids, next_id = self._observe(context, rng, tracks.ids, tracks.next_id)
        self._queue(context, state, frame)
        state.get_mutable_abstract_state(self._tracks).set_value(Tracks(ids, next_id))

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
        was_tracked = np.zeros(len(self._p_WL), bool)
        was_tracked[np.fromiter(tracks, int, len(tracks))] = True
        was_tracked = was_tracked[visible]
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
        keypoints = self.pixels(self._points_C(X_WC, self._grid.slot[selected])) \
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
        fresh = fresh[rng.permutation(len(fresh))]
        if not len(fresh):
            return fresh
        cells = (np.clip(uv[:, 0] * GRID[0] / self._lens.width, 0, GRID[0] - 1).astype(int)
                 * GRID[1] + np.clip(uv[:, 1] * GRID[1] / self._lens.height, 0,
                                     GRID[1] - 1).astype(int))  # of every row, in one pass
        count = np.bincount(cells[kept], minlength=GRID[0] * GRID[1])
        # Each new feature's rank: the features already in its cell (kept, then the new ones
        # before it in the shuffled order).
        cell = cells[fresh]
        order = _stable_order(cell, len(count))
        in_cell = np.bincount(cell, minlength=len(count))
        before = np.empty(len(fresh), int)
        before[order] = np.arange(len(fresh)) - (np.cumsum(in_cell) - in_cell)[cell[order]]
        rank = count[cell] + before
        return fresh[_stable_order(rank, len(uv))]

    def pixels(self, p_C: np.ndarray) -> np.ndarray:
        """Pixels (N, 2) of points p_C (N, 3) in C (z > 0): the undistorted lens's projection as
        cv2.projectPoints computes it, x (1 / z) f + c, bit for bit (tests/test_vio_units.py),
        without the call's overhead (about 5 % of a frame's CPU time)."""
        return p_C[:, :2] * (1.0 / p_C[:, 2:]) * self._focal + self._center

    def _points_C(self, X_WC: RigidTransform, at: np.ndarray) -> np.ndarray:
        """The landmarks at positions `at` of the grid's order in the camera frame C (N, 3)."""
        return (X_WC.inverse().GetAsMatrix34() @ self._p_WL_h.take(at, axis=0).T).T

    def _frustum_planes(self) -> tuple[np.ndarray, np.ndarray]:
        """The view frustum's planes in the camera frame C as inward unit normals n (6, 3) and
        offsets o (6,), a point q inside where n q + o > 0: in front (z > 0), within
        `max_range`, and inside the four image edges (those of `_boxes_in_view`)."""
        (fx, fy), (cx, cy) = self._focal, self._center
        w, h = self._lens.width, self._lens.height
        normals = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [fx, 0.0, cx], [-fx, 0.0, w - cx],
                            [0.0, fy, cy], [0.0, -fy, h - cy]])
        normals /= np.linalg.norm(normals, axis=1)[:, None]
        return normals, np.array([0.0, self._params.max_range, 0.0, 0.0, 0.0, 0.0])

    def _boxes_in_view(self, X_WC: RigidTransform,
                       boxes: BoxCorners) -> tuple[np.ndarray, np.ndarray]:
        """Rows of the boxes not wholly outside one plane of the view frustum (behind the camera,
        beyond `max_range`, or beyond one image edge), in increasing order, and their corners in
        the camera frame C (N, 8, 3)."""
        X_CW = X_WC.inverse()
        R_CW, p_CW = X_CW.rotation().matrix(), X_CW.translation()
        # Only the boxes whose spheres reach inside every plane of the frustum are tested corner
        # by corner (margins far above rounding: the others are wholly outside a plane, corner by
        # corner too); the slab 0 < z < max_range alone kept 60 % of a road map's cells.
        normals, offsets = self._frustum
        # the centres' distances (6, M) to the planes, as normals_W c_W + offsets_W
        distance = (normals @ R_CW) @ boxes.centre.T + (normals @ p_CW + offsets)[:, None]
        rows = np.flatnonzero(np.logical_and.reduce(distance > boxes.cull))
        p_C = boxes.p_W[rows] @ R_CW.T + p_CW
        x, y, z = p_C[..., 0], p_C[..., 1], p_C[..., 2]
        (fx, fy), (cx, cy) = self._focal, self._center
        w, h = self._lens.width, self._lens.height
        fx_x, fy_y = fx * x, fy * y
        # all corners outside a plane: the one nearest to it is (max < 0 is all < 0)
        outside = ((z.max(1) <= 0) | (z.min(1) >= self._params.max_range)
                   | ((fx_x + cx * z).max(1) < 0) | ((fx_x - (w - cx) * z).min(1) > 0)
                   | ((fy_y + cy * z).max(1) < 0) | ((fy_y - (h - cy) * z).min(1) > 0))
        return rows[~outside], p_C[~outside]

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
        c = X_WC.translation()
        at, uv, z = self._in_image(X_WC)
        # facing the camera: n (c - p) > 0, as `_facing_keys` compares it
        rows = np.flatnonzero(np.concatenate([c, -c]).take(self._face_code.take(at))
                              > self._face_key.take(at))
        # Only boxes that reach into the view frustum can hide a point in it.
        in_view, corners_C = self._boxes_in_view(X_WC, self._box_corners)
        box_row = np.full(len(self._boxes) + 1, -1)  # a box's row in in_view (-1, the last: none)
        box_row[in_view] = np.arange(len(in_view))
        rows = rows[~occluded(c, self._p_WL.take(at[rows], axis=0), self._boxes[in_view],
                              box_row[self._box_of[at[rows]]],
                              self._may_hide(corners_C, uv.take(rows, axis=0), z[rows]))]
        # Increasing order: each cell's landmarks are an increasing run, a stable sort merges them.
        index = self._grid.order[at[rows]]
        order = np.argsort(index, kind="stable")
        return index[order], uv.take(rows[order], axis=0), z[rows[order]]

    def _may_hide(self, p_C: np.ndarray, uv: np.ndarray, z: np.ndarray) -> np.ndarray:
        """(N, M) whether the M boxes with corners p_C (M, 8, 3) in the camera frame may hide the
        points at pixels uv (N, 2) and ranges z (N,), for `occluded` to test those pairs only: a
        box in front of the camera hides only points behind its nearest corner and inside the
        rectangle that its corners project into (with margins far above rounding: a hit found by
        `occluded` is kept)."""
        z_near = p_C[..., 2].min(axis=1)
        ahead = z_near > 1e-3  # the others may hide any point
        corners = p_C[ahead, :, :2] / p_C[ahead, :, 2:] * self._focal + self._center
        lo, hi = np.full((len(p_C), 2), -np.inf), np.full((len(p_C), 2), np.inf)
        lo[ahead], hi[ahead] = corners.min(axis=1) - 1.0, corners.max(axis=1) + 1.0
        z_near = np.where(ahead, z_near - 1e-6, -np.inf)
        u, v = uv[:, 0], uv[:, 1]
        # (M, N), box by box: long rows are faster
        return ((z_near[:, None] <= z) & (lo[:, :1] <= u) & (hi[:, :1] >= u) & (lo[:, 1:] <= v)
                & (hi[:, 1:] >= v)).T

    def _in_image(self, X_WC: RigidTransform) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The landmarks of the grid cells that reach into the view that are in front, within
        range and inside the image minus the border: their positions in the grid's order, their
        noise-free pixels (N, 2) and ranges (N,)."""
        p = self._params
        at = self._grid.slots(self._boxes_in_view(X_WC, self._cell_corners)[0])
        p_CL = self._points_C(X_WC, at)
        z = p_CL[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):  # behind the camera: left out
            uv = p_CL[:, :2] / z[:, None] * self._focal + self._center
        keep = np.flatnonzero((z > 0.1) & (z < p.max_range)
                              & self._lens.in_image(uv, p.border_margin))
        return at[keep], uv.take(keep, axis=0), z[keep]


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
