"""Keypoint tracking in image space, L Sec. 5.2.2 (Fig. 5).

For each pattern keypoint, its location predicted from the target EKF's predicted pose (L(9)), a
20 x 20 px patch of the binarized template warped with the predicted pose (the homography of the
pattern plane), and a brute-force search of the predicted location's 60 x 60 px neighbourhood in the
binarized rectified image for the minimum of the squared difference (`cv2.matchTemplate`, masked to
the platform's pixels). A match whose mean squared difference exceeds `max_difference` is dropped;
the chi-square test on the residual is the EKF's (target_ekf.py). `track` binarizes only the window
of the frame that the searches cover, with a margin of half the threshold's block, so that its
binary image is the whole frame's there.
"""
import dataclasses as dc

import cv2
import numpy as np
from pydrake.math import RigidTransform

from alight.systems.params import bounded
from alight.systems.perception.detector import RectifiedFrame
from alight.systems.perception.pattern import Pattern


@dc.dataclass
class KeypointTrackerParams:
    patch_size: int = bounded(20, 4, 200, "px")       # L Sec. 5.2.2
    search_size: int = bounded(60, 4, 400, "px")      # L Sec. 5.2.2
    max_difference: float = bounded(0.15, 0.0, 1.0)   # mean squared difference, binary in [0, 1]
    min_coverage: float = bounded(0.5, 0.0, 1.0)      # part of the patch on the platform
    template_size: int = bounded(1024, 64, 8192, "px")


@dc.dataclass(frozen=True)
class KeypointMatch:
    id: int
    uv: np.ndarray            # (2,) measured rectified pixel
    predicted: np.ndarray     # (2,)
    difference: float         # mean squared difference of the binary patch, in [0, 1]


class KeypointTracker:
    def __init__(self, pattern: Pattern, params: KeypointTrackerParams):
        self._pattern = pattern
        self._params = params
        n = params.template_size
        self._template = pattern.template(n).astype(np.float32)
        self._support = np.full((n, n), 255.0, np.float32)
        self._M_T_tpl = pattern.template_to_T(n)

    def track(self, frame: RectifiedFrame, X_CT: RigidTransform,
              ids=None) -> list[KeypointMatch]:
        """`match` in the window of the rectified frame around the searches."""
        window = self._window(frame, X_CT)
        if window is None:
            return []
        view = frame.view(0, window)
        K = frame.lens.K_rectified.copy()
        K[:2, 2] -= view.origin
        return [dc.replace(m, uv=m.uv + view.origin, predicted=m.predicted + view.origin)
                for m in self.match(view.binary, view.valid, K, X_CT, ids)]

    def _window(self, frame: RectifiedFrame, X_CT: RigidTransform):
        """(x0, y0, x1, y1) covering every keypoint's search and the threshold's half block."""
        p_C = self._pattern.p_TK @ X_CT.rotation().matrix().T + X_CT.translation()
        p_C = p_C[p_C[:, 2] > 0.05]
        if not len(p_C):
            return None
        K = frame.lens.K_rectified
        uv = p_C[:, :2] / p_C[:, 2:] @ K[:2, :2].T + K[:2, 2]
        grow = self._params.search_size / 2 + self._params.patch_size + 2 \
            + frame.threshold_block(0) // 2 + 4  # + the smoothing's reach
        x0, y0 = np.maximum(uv.min(axis=0) - grow, 0)
        x1, y1 = np.minimum(uv.max(axis=0) + grow, [frame.lens.width, frame.lens.height])
        return (x0, y0, x1, y1) if x1 - x0 >= 1 and y1 - y0 >= 1 else None  # else out of view

    def match(self, binary: np.ndarray, valid: np.ndarray, K: np.ndarray, X_CT: RigidTransform,
              ids=None) -> list[KeypointMatch]:
        """Matches of the keypoints `ids` (default all) predicted with X_CT (rectified K)."""
        p = self._params
        R, t = X_CT.rotation().matrix(), X_CT.translation()
        H_img_T = K @ np.column_stack([R[:, 0], R[:, 1], t])  # the plane z_T = 0 -> image
        H_img_tpl = H_img_T @ self._M_T_tpl
        half_patch = (p.patch_size - 1) / 2
        reach = p.search_size // 2
        h, w = binary.shape
        matches = []
        for k in range(len(self._pattern.p_TK)) if ids is None else ids:
            p_C = R @ self._pattern.p_TK[k] + t
            if p_C[2] <= 0.05:
                continue
            uv = K[:2, :2] @ (p_C[:2] / p_C[2]) + K[:2, 2]
            x0, y0 = int(round(uv[0] - half_patch)) - reach, int(round(uv[1] - half_patch)) - reach
            x1, y1 = x0 + p.search_size + p.patch_size, y0 + p.search_size + p.patch_size
            if x0 < 0 or y0 < 0 or x1 > w or y1 > h or \
                    not valid[int(np.clip(uv[1], 0, h - 1)), int(np.clip(uv[0], 0, w - 1))]:
                continue
            shift = np.array([[1, 0, half_patch - uv[0]], [0, 1, half_patch - uv[1]], [0, 0, 1.0]])
            H_patch = shift @ H_img_tpl
            size = (p.patch_size, p.patch_size)
            patch = cv2.warpPerspective(self._template, H_patch, size, flags=cv2.INTER_LINEAR)
            support = cv2.warpPerspective(self._support, H_patch, size, flags=cv2.INTER_LINEAR)
            mask = (support > 254).astype(np.float32)
            if mask.mean() < p.min_coverage:
                continue
            patch = np.where(patch > 127, 255.0, 0.0).astype(np.float32)
            region = binary[y0:y1 - 1, x0:x1 - 1].astype(np.float32)
            ssd = cv2.matchTemplate(region, patch, cv2.TM_SQDIFF, mask=mask)
            j, i = np.unravel_index(np.argmin(ssd), ssd.shape)
            difference = float(ssd[j, i] / (mask.sum() * 255.0 ** 2))
            di = _parabola(ssd[j, i - 1], ssd[j, i], ssd[j, i + 1]) if 0 < i < ssd.shape[1] - 1 \
                else 0.0
            dj = _parabola(ssd[j - 1, i], ssd[j, i], ssd[j + 1, i]) if 0 < j < ssd.shape[0] - 1 \
                else 0.0
            measured = np.array([x0 + i + di, y0 + j + dj]) + half_patch
            if difference <= p.max_difference:
                matches.append(KeypointMatch(k, measured, uv, difference))
        return matches


def _parabola(a: float, b: float, c: float) -> float:
    denominator = a - 2 * b + c
    return float(np.clip(0.5 * (a - c) / denominator, -0.5, 0.5)) if denominator > 1e-9 else 0.0
