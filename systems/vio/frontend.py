"""The VIO front end (L Sec. 5.1): keypoints with track ids and depth from an RGB-D frame, the
virtual stereo measurement of L(2), and keyframe selection.

- Rendered frames: Shi-Tomasi corners tracked frame to frame with pyramidal Lucas-Kanade (OpenCV),
  outliers rejected by RANSAC on the fundamental matrix, new corners detected away from the tracked
  ones to keep `max_features`, and only where the depth image has depth (a corner beyond the depth
  range cannot start a landmark: L(2) needs its depth; the horizon's corners, which are the
  strongest in a forward view, would otherwise take the whole budget); depth looked up per keypoint
  (median of the valid depths around it).
- Geometric frames already carry keypoints, track ids and per-keypoint depth; their tracks are
  checked against the previous frame (issue 20: the geometric camera injects outlier matches): a
  3D-2D RANSAC (`cv2.solvePnPRansac`) of the previous frame's keypoints with depth, back-projected,
  against this frame's pixels gives the camera's motion between the frames; a track whose
  reprojection error (with depth in the previous frame) or distance to its epipolar line (without)
  exceeds `outlier_threshold` is dropped from this frame (counted in `KltTracker.rejected`).
  Tracks new in this frame are not checked (a fresh detection is no match).

L(2): z_v = u_v(T_CvC u^-1(z, D)): the keypoint back-projected with its depth, moved into the
virtual camera (the RGB camera shifted by the infrared baseline along x_C) and projected again with
the same pinhole. For a rectified pinhole this is u_v = u - f b / z, v_v = v.
"""
import dataclasses as dc

import cv2
import numpy as np

from alight.systems.boundary import CameraFrame
from alight.systems.params import bounded


@dc.dataclass
class FrontendParams:
    max_features: int = bounded(150, 8, 5000)
    min_corner_distance: float = bounded(15.0, 1.0, 200.0, "px")
    corner_quality: float = bounded(0.01, 1e-4, 1.0)
    klt_window: int = bounded(21, 5, 101, "px")
    klt_levels: int = bounded(3, 0, 8)
    ransac_threshold: float = bounded(1.0, 0.1, 20.0, "px")
    outlier_threshold: float = bounded(3.0, 0.1, 50.0, "px")  # geometric frames' 3D-2D check
    depth_window: int = bounded(2, 0, 10, "px")            # half size of the depth lookup patch
    keyframe_period: float = bounded(0.1, 0.0, 5.0, "s")   # at most this long between keyframes
    keyframe_overlap: float = bounded(0.7, 0.0, 1.0)       # fewer known tracks: a keyframe now
    min_keyframe_gap: float = bounded(0.03, 0.0, 5.0, "s")


@dc.dataclass(frozen=True)
class Keypoints:
    """Track ids (N,), pixels (N, 2), depth (N,) [m, NaN: none]."""
    ids: np.ndarray
    uv: np.ndarray
    depth: np.ndarray

    @staticmethod
    def empty() -> "Keypoints":
        return Keypoints(np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros(0))

    def __len__(self) -> int:
        return len(self.ids)


def virtual_stereo(uv: np.ndarray, depth: np.ndarray, K: np.ndarray, baseline: float):
    """L(2): the virtual camera's u (N,) and the back-projected points p_C (N, 3); NaN where the
    depth is missing."""
    uv = np.asarray(uv, float).reshape(-1, 2)
    z = np.asarray(depth, float)
    xy = (uv - K[:2, 2]) / K[[0, 1], [0, 1]]
    p_C = np.column_stack([xy * z[:, None], z])
    p_Cv = p_C - [baseline, 0.0, 0.0]  # T_CvC: the virtual camera sits at +b along x_C
    u_virtual = K[0, 0] * p_Cv[:, 0] / p_Cv[:, 2] + K[0, 2]
    return u_virtual, p_C


def lookup_depth(depth_image: np.ndarray, uv: np.ndarray, half: int) -> np.ndarray:
    """Median of the valid depths in a (2 half + 1)^2 patch around each pixel (NaN if none).

    All patches at once: the patch's pixels gathered by index (those outside the image and the
    invalid depths as NaN), sorted with the NaNs last, the middle of the valid ones taken."""
    h, w = depth_image.shape
    pixel = np.rint(np.asarray(uv, float).reshape(-1, 2)).astype(int)
    if not len(pixel):
        return np.zeros(0)
    offsets = np.arange(-half, half + 1)
    u = pixel[:, 0, None, None] + offsets[None, None, :]
    v = pixel[:, 1, None, None] + offsets[None, :, None]
    inside = ((u >= 0) & (u < w) & (v >= 0) & (v < h)).reshape(len(pixel), -1)
    patch = depth_image[np.clip(v, 0, h - 1), np.clip(u, 0, w - 1)].reshape(len(pixel), -1)
    patch = np.where(inside & np.isfinite(patch) & (patch > 0), patch, np.nan)
    patch.sort(axis=1)
    count = np.count_nonzero(~np.isnan(patch), axis=1)
    rows = np.arange(len(pixel))
    middle = (patch[rows, (count - 1) // 2] + patch[rows, count // 2]) / 2  # NaN where count 0
    return middle.astype(float)


def _homogeneous(xy: np.ndarray) -> np.ndarray:
    """The (N, 2) points with a third coordinate 1 (N, 3)."""
    x = np.empty((len(xy), 3))
    x[:, :2] = xy
    x[:, 2] = 1.0
    return x


def _row_norms(x: np.ndarray) -> np.ndarray:
    """np.linalg.norm(x, axis=1) of a real (N, k) array, the same sums without its checks."""
    return np.sqrt(np.add.reduce(x * x, axis=1))


def _cross(t: np.ndarray, y: np.ndarray) -> np.ndarray:
    """np.cross(t, y) of a 3-vector and (N, 3) rows, the same products without its
    broadcasting machinery (most of its cost at a few dozen rows)."""
    out = np.empty_like(y)
    out[:, 0] = t[1] * y[:, 2] - t[2] * y[:, 1]
    out[:, 1] = t[2] * y[:, 0] - t[0] * y[:, 2]
    out[:, 2] = t[0] * y[:, 1] - t[1] * y[:, 0]
    return out


class KltTracker:
    """Corner tracking on the grey image of rendered frames (state: the previous image and its
    tracked corners with their ids)."""

    def __init__(self, params: FrontendParams):
        self._p = params
        self._previous = None
        self._uv = np.zeros((0, 2), np.float32)
        self._ids = np.zeros(0, np.int64)
        self._next_id = 0
        self._last_geometric = Keypoints.empty()
        self.rejected = 0  # geometric keypoints dropped by the 3D-2D check, in all

    def check(self, keypoints: Keypoints, K: np.ndarray) -> Keypoints:
        """Geometric keypoints without the tracks inconsistent with the previous frame's (3D-2D
        RANSAC on the motion between the frames, then per track: reprojection error with depth
        in the previous frame, epipolar distance without)."""
        previous, self._last_geometric = self._last_geometric, keypoints
        _, a, b = np.intersect1d(previous.ids, keypoints.ids, assume_unique=True,
                                 return_indices=True)
        depth_prev = previous.depth[a]
        has_depth = np.isfinite(depth_prev)
        if np.count_nonzero(has_depth) < 8:
            return keypoints
        no_depth = ~has_depth
        f, c = K[[0, 1], [0, 1]], K[:2, 2]
        x_prev = _homogeneous((previous.uv[a] - c) / f)
        p_prev = x_prev[has_depth] * depth_prev[has_depth, None]
        uv = keypoints.uv[b]
        uv_depth = uv[has_depth]
        ok, rvec, tvec, _ = cv2.solvePnPRansac(
            p_prev, uv_depth, K, None, iterationsCount=50,
            reprojectionError=self._p.outlier_threshold, confidence=0.99,
            flags=cv2.SOLVEPNP_EPNP)
        if not ok:
            return keypoints
        R, t = cv2.Rodrigues(rvec)[0], tvec.ravel()
        error = np.empty(len(a))
        q = p_prev @ R.T + t
        error[has_depth] = _row_norms(q[:, :2] / q[:, 2:] * f + c - uv_depth)
        # without depth: the distance to the epipolar line E x_prev (E = [t]x R), in pixels
        x_cur = _homogeneous((uv[no_depth] - c) / f)
        line = _cross(t, x_prev[no_depth] @ R.T)
        error[no_depth] = f.mean() * np.abs(np.einsum("ij,ij->i", x_cur, line)) / np.maximum(
            _row_norms(line[:, :2]), 1e-12)
        bad = b[error > self._p.outlier_threshold]
        if not len(bad):
            return keypoints
        self.rejected += len(bad)
        keep = np.ones(len(keypoints), bool)
        keep[bad] = False
        kept = Keypoints(keypoints.ids[keep], keypoints.uv[keep], keypoints.depth[keep])
        self._last_geometric = kept
        return kept

    def track(self, frame: CameraFrame) -> Keypoints:
        p = self._p
        image = frame.image if frame.image.ndim == 2 else cv2.cvtColor(frame.image,
                                                                        cv2.COLOR_RGB2GRAY)
        uv, ids = self._uv, self._ids
        if self._previous is not None and len(uv):
            moved, status, _ = cv2.calcOpticalFlowPyrLK(
                self._previous, image, uv.reshape(-1, 1, 2), None,
                winSize=(p.klt_window, p.klt_window), maxLevel=p.klt_levels)
            moved = moved.reshape(-1, 2)
            h, w = image.shape
            ok = (status.ravel() == 1) & (moved[:, 0] >= 0) & (moved[:, 0] < w) \
                & (moved[:, 1] >= 0) & (moved[:, 1] < h)
            if ok.sum() >= 8:
                _, inliers = cv2.findFundamentalMat(uv[ok], moved[ok], cv2.FM_RANSAC,
                                                    p.ransac_threshold, 0.99)
                if inliers is not None:
                    ok[np.flatnonzero(ok)[inliers.ravel() == 0]] = False
            uv, ids = moved[ok], ids[ok]
        else:
            uv, ids = np.zeros((0, 2), np.float32), np.zeros(0, np.int64)
        uv, ids = self._detect(image, frame.depth, uv, ids)
        self._previous, self._uv, self._ids = image, uv, ids
        depth = lookup_depth(frame.depth, uv, p.depth_window) if frame.depth is not None \
            else np.full(len(uv), np.nan)
        return Keypoints(ids.copy(), uv.astype(float), depth)

    def _detect(self, image, depth, uv, ids):
        p = self._p
        wanted = p.max_features - len(uv)
        if wanted <= p.max_features // 4:
            return uv, ids
        mask = np.full(image.shape, 255, np.uint8)
        if depth is not None:
            mask[~(np.isfinite(depth) & (depth > 0))] = 0
        for u, v in np.rint(uv).astype(int):
            cv2.circle(mask, (int(u), int(v)), int(p.min_corner_distance), 0, -1)
        corners = cv2.goodFeaturesToTrack(image, wanted, p.corner_quality, p.min_corner_distance,
                                          mask=mask)
        if corners is None:
            return uv, ids
        corners = corners.reshape(-1, 2).astype(np.float32)
        new_ids = np.arange(self._next_id, self._next_id + len(corners), dtype=np.int64)
        self._next_id += len(corners)
        return np.vstack([uv, corners]), np.concatenate([ids, new_ids])


def keypoints_of(frame: CameraFrame, tracker: KltTracker) -> Keypoints:
    """The frame's keypoints: given by a geometric source, tracked in a rendered image."""
    if frame.keypoints is not None:
        n = len(frame.keypoints)
        depth = np.asarray(frame.depth, float) if frame.depth is not None else np.full(n, np.nan)
        keypoints = Keypoints(np.asarray(frame.keypoint_ids, np.int64),
                              np.asarray(frame.keypoints, float).reshape(n, 2), depth.reshape(n))
        return tracker.check(keypoints, np.asarray(frame.calibration["K"], float))
    if frame.image is not None:
        return tracker.track(frame)
    return Keypoints.empty()


def is_keyframe(params: FrontendParams, t: float, last_keyframe: float, known: int,
                total: int) -> bool:
    """A keyframe when `keyframe_period` has passed or too few of the tracks are in the map."""
    gap = t - last_keyframe
    if gap < params.min_keyframe_gap:
        return False
    return gap >= params.keyframe_period - 1e-6 or known < params.keyframe_overlap * total
