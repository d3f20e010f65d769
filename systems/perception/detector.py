"""Landing-pattern detection and initial pose, L Sec. 5.2.1 (Fig. 4).

Undistortion (to the rectified pinhole image of `down_camera_lens.Lens`), smoothing, locally adaptive
threshold, contours with polygon simplification, convex quadrilateral candidates, the pose of each
candidate from its four corners (`cv2.solvePnP`, P3P as in the paper or IPPE for planar squares),
then verification: the candidate is warped into the template's frame (`cv2.warpPerspective`) and
compared with the template. The paper compares one BRISK descriptor (255 x 255 template); on this
4-fold symmetric pattern BRISK's orientation assignment is unstable and its distance does not
separate the pattern from look-alike squares (bench/detector.py measures both), so the default test is
the zero-mean normalized cross-correlation of the warp with the template at 32 x 32 px; `brisk` is
selectable. The pattern's symmetry leaves its yaw ambiguous by multiples of 90 degrees: the
detection returns the rotation closest to a reference orientation.

Speed (bench/detector.py): with a `Prediction` of the pattern (the target EKF's pose and its
uncertainty, L(9)) the search runs first in a window around the predicted pattern, growing with the
uncertainty, and at a reduced pyramid level when the pattern is large (`RectifiedFrame` rectifies
only that window, at that level); a miss there falls back to the whole frame. Candidates are scored
on their raw corners first and only the plausible ones are refined to sub-pixel corners (at the
search level, then at full resolution in a small rectified patch) and scored again.
"""
import dataclasses as dc

import cv2
import numpy as np
from pydrake.math import RigidTransform, RotationMatrix

from alight.systems.params import bounded, choice
from alight.systems.perception.pattern import Pattern
from alight.systems.sensors.down_camera_lens import Lens


@dc.dataclass
class DetectorParams:
    blur_sigma: float = bounded(0.8, 0.0, 10.0, "px")        # smoothing before the threshold
    threshold_block: float = bounded(0.05, 0.005, 0.5)      # adaptive threshold window / width
    threshold_offset: float = bounded(7.0, -50.0, 50.0, "grey levels")
    min_quad_area: float = bounded(150.0, 4.0, 1e7, "px^2")
    approx_epsilon: float = bounded(0.04, 0.001, 0.3)        # of the contour's perimeter
    border_margin: float = bounded(3.0, 0.0, 100.0, "px")   # quads touching the border are partial
    pnp: str = choice("ippe", "p3p")
    verification: str = choice("ncc", "brisk")
    verify_size: int = bounded(32, 8, 255, "px")             # NCC comparison resolution
    min_correlation: float = bounded(0.75, -1.0, 1.0)
    brisk_keypoint_size: float = bounded(60.0, 5.0, 255.0, "px")
    brisk_max_distance: float = bounded(100.0, 0.0, 512.0, "bits")
    # NCC: a candidate's raw corners must score min_correlation - prefilter_slack to be refined
    prefilter_slack: float = bounded(0.15, 0.0, 2.0)
    roi_sigmas: float = bounded(3.0, 0.0, 20.0)      # window margin: sigmas of the prediction
    roi_margin: float = bounded(0.5, 0.0, 10.0)      # window margin: fraction of the square's side
    roi_min_side: float = bounded(48.0, 8.0, 1000.0, "px")  # the square's side at the level
    max_level: int = bounded(2, 0, 4)                # coarsest pyramid level (1/2^level)


@dc.dataclass(frozen=True)
class Detection:
    """A verified pattern: X_CT (T in the camera frame), the corners' rectified pixels (keypoints
    0-3 in order) and the verification score (correlation, or BRISK distance)."""
    X_CT: RigidTransform
    corners: np.ndarray
    score: float


@dc.dataclass(frozen=True)
class Candidate:
    """A quadrilateral candidate before the verification decision (for measurements)."""
    corners: np.ndarray   # (4, 2) rectified pixels, ordered like keypoints 0-3 up to rotation
    correlation: float
    brisk_distance: float


@dc.dataclass(frozen=True)
class Prediction:
    """Where the pattern should be: X_CT (rectified camera) and the 1-sigma uncertainty of its
    position [m] and rotation [rad] (e.g. the target EKF's prediction, L(9))."""
    X_CT: RigidTransform
    position_std: float
    rotation_std: float


@dc.dataclass(frozen=True)
class View:
    """A window of the rectified image at pyramid level `level`: its smoothed and binarized images
    and the pixels that see the distorted image. View pixel (u, v) is rectified full-resolution
    pixel s (u + x0, v + y0) + (s - 1) / 2 with s = 2^level, (x0, y0) = `origin`."""
    smoothed: np.ndarray
    binary: np.ndarray | None
    valid: np.ndarray
    level: int
    origin: tuple[int, int]

    @property
    def scale(self) -> int:
        return 1 << self.level

    def to_full(self, uv: np.ndarray) -> np.ndarray:
        s = self.scale
        return (s * (np.asarray(uv, np.float32) + np.float32(self.origin)) + (s - 1) / 2) \
            .astype(np.float32)


class Rectifier:
    """The rectified image and its adaptive-threshold binarization, shared by detection and
    tracking (maps cached per calibration and pyramid level)."""

    def __init__(self, params: DetectorParams):
        self._params = params
        self._maps = {}

    def rectify(self, image: np.ndarray, lens: Lens, level: int = 0,
                window: tuple[int, int, int, int] | None = None) -> np.ndarray:
        """The rectified image at `level` (1/2^level of the size, same field of view), or its
        window (x0, y0, x1, y1) in that level's pixels."""
        map1, map2, _ = self._lens_maps(lens, level)
        if window is not None:
            x0, y0, x1, y1 = window
            map1, map2 = map1[y0:y1, x0:x1], map2[y0:y1, x0:x1]
        return cv2.remap(image, map1, map2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

    def valid(self, lens: Lens, level: int = 0) -> np.ndarray:
        """The rectified pixels that see the distorted image (uint8 0/255, margin removed)."""
        return self._lens_maps(lens, level)[2]

    def _lens_maps(self, lens: Lens, level: int = 0):
        key = (lens.width, lens.height, lens.K.tobytes(), lens.distortion.tobytes(),
               lens.K_rectified.tobytes(), level)
        if key not in self._maps:
            s = 1 << level
            K = lens.K_rectified / s  # level pixel u <-> full-resolution s u + (s - 1) / 2
            K[:2, 2] = (lens.K_rectified[:2, 2] - (s - 1) / 2) / s
            K[2, 2] = 1.0
            size = (lens.width // s, lens.height // s)
            map1, map2 = cv2.initUndistortRectifyMap(lens.K, lens.distortion, None, K, size,
                                                     cv2.CV_16SC2)
            ones = np.full((lens.height, lens.width), 255, np.uint8)  # the distorted image
            valid = cv2.remap(ones, map1, map2, cv2.INTER_NEAREST,
                              borderMode=cv2.BORDER_CONSTANT, borderValue=0)
            margin = int(np.ceil(self._params.border_margin)) * 2 + 1
            valid = cv2.erode(valid, np.ones((margin, margin), np.uint8))
            self._maps[key] = (map1, map2, valid)
        return self._maps[key]

    @property
    def border_margin(self) -> float:
        return self._params.border_margin

    def smooth(self, rectified: np.ndarray) -> np.ndarray:
        sigma = self._params.blur_sigma
        return cv2.GaussianBlur(rectified, (0, 0), sigma) if sigma > 0 else rectified

    def binarize(self, smoothed: np.ndarray, width: int | None = None) -> np.ndarray:
        """Adaptive threshold over a window of `threshold_block` x `width` (the whole image's
        width at this level; default: this image's)."""
        width = smoothed.shape[1] if width is None else width
        return cv2.adaptiveThreshold(smoothed, 255, cv2.ADAPTIVE_THRESH_MEAN_C, cv2.THRESH_BINARY,
                                     self.block(width), self._params.threshold_offset)

    def block(self, width: int) -> int:
        """The adaptive threshold's window [px] in an image `width` px wide."""
        return max(3, int(self._params.threshold_block * width) // 2 * 2 + 1)


class RectifiedFrame:
    """One distorted frame and the `View`s of it that detection and tracking ask for: the whole
    frame at a pyramid level (computed once), or a window of it."""

    def __init__(self, rectifier: Rectifier, image: np.ndarray, lens: Lens):
        if image.ndim != 2 or image.shape != (lens.height, lens.width):
            raise ValueError(f"expected a {lens.width} x {lens.height} grey image, got "
                             f"{image.shape}")
        self.lens = lens
        self._rectifier = rectifier
        self._image = image
        self._whole = {}

    def view(self, level: int = 0, window: tuple[float, float, float, float] | None = None,
             binary: bool = True) -> View:
        """The view at `level` of the window (x0, y0, x1, y1) of full-resolution rectified pixels
        (default: the whole frame; a window of an already computed whole frame is cut from it);
        pixels within border_margin of a window's edge are invalid, so that a quadrilateral cut by
        it is not taken for a whole one. `binary=False` skips the threshold."""
        s = 1 << level
        width, height = self.lens.width // s, self.lens.height // s
        box = (0, 0, width, height) if window is None else (
            max(0, int(np.floor(window[0] / s))), max(0, int(np.floor(window[1] / s))),
            min(width, int(np.ceil(window[2] / s))), min(height, int(np.ceil(window[3] / s))))
        if box[2] <= box[0] or box[3] <= box[1]:
            raise ValueError(f"window {window} is outside the {self.lens.width} x "
                             f"{self.lens.height} image")
        if box == (0, 0, width, height) or level in self._whole:
            view = _crop(self._whole_view(level), box)
        else:
            smoothed = self._rectifier.smooth(self._rectifier.rectify(self._image, self.lens,
                                                                      level, box))
            view = View(smoothed, self._rectifier.binarize(smoothed, width) if binary else None,
                        self._rectifier.valid(self.lens, level)[box[1]:box[3], box[0]:box[2]],
                        level, box[:2])
        if box != (0, 0, width, height):
            m = int(np.ceil(self._rectifier.border_margin)) + 1
            valid = view.valid.copy()
            valid[:m], valid[-m:], valid[:, :m], valid[:, -m:] = 0, 0, 0, 0
            view = dc.replace(view, valid=valid)
        return view

    def threshold_block(self, level: int) -> int:
        """The adaptive threshold's window [px] at `level`."""
        return self._rectifier.block(self.lens.width >> level)

    def _whole_view(self, level: int) -> View:
        if level not in self._whole:
            smoothed = self._rectifier.smooth(self._rectifier.rectify(self._image, self.lens,
                                                                      level))
            self._whole[level] = View(smoothed, self._rectifier.binarize(smoothed),
                                      self._rectifier.valid(self.lens, level), level, (0, 0))
        return self._whole[level]


def _crop(view: View, box) -> View:
    x0, y0, x1, y1 = box
    return View(view.smoothed[y0:y1, x0:x1], None if view.binary is None
                else view.binary[y0:y1, x0:x1], view.valid[y0:y1, x0:x1], view.level,
                (view.origin[0] + x0, view.origin[1] + y0))


class PatternDetector:
    """Finds the pattern in a `RectifiedFrame`: around a `Prediction` first if one is given, else
    (or when that misses) in the whole frame."""

    def __init__(self, pattern: Pattern, params: DetectorParams):
        self._pattern = pattern
        self._params = params
        n = pattern.params.template_size
        self._template_size = n
        self._template_corners = pattern.template_pixel(pattern.corners, n).astype(np.float32)
        self._references = {}
        self._brisk = cv2.BRISK_create()
        self._brisk_template = self._brisk_descriptor(pattern.template(n))
        self._corner_side = float(np.linalg.norm(pattern.corners[1] - pattern.corners[0]))

    def candidates(self, view: View, both_scores: bool = False) -> list[Candidate]:
        """Every convex quadrilateral wholly inside the view's valid pixels, refined, with its
        verification score (both scores if asked; the other one is nan), in view pixels."""
        return [self._score(view.smoothed, self._refine(view.smoothed, corners), both_scores)
                for corners in self._quads(view)]

    def detect(self, frame: RectifiedFrame, R_CT_reference: np.ndarray | None = None,
               z_up_C: np.ndarray | None = None,
               prediction: Prediction | None = None, height: float | None = None) \
            -> list[Detection]:
        """Verified detections, best first; nested duplicates (the same pattern's inner and outer
        quads) are merged. With a `prediction`, the window around it (`search_region`) is searched
        first and the whole frame only if that finds nothing; the whole frame at the level
        `whole_frame_level` gives for `height` (with `z_up_C`), else at full resolution.
        `R_CT_reference`, `z_up_C`: see `pose`."""
        if prediction is not None:
            region = self.search_region(prediction, frame.lens)
            if region is not None:
                found = self._detect_in(frame, frame.view(*region), R_CT_reference, z_up_C)
                if found:
                    return found
        level = 0 if height is None or z_up_C is None else \
            self.whole_frame_level(frame.lens, height, z_up_C)
        return self._detect_in(frame, frame.view(level), R_CT_reference, z_up_C)

    def whole_frame_level(self, lens: Lens, height: float, z_up_C: np.ndarray) -> int:
        """The coarsest pyramid level (up to max_level) at which the pattern still spans
        roi_min_side px wherever it lies in the frame, on a level platform at most `height` below
        the camera (`z_up_C`: up in the camera frame). The rectified image of a plane at depth Z
        along the optical axis scales by f / Z, foreshortened by at most the cosine of the
        camera's tilt; Z is largest at a corner of the image."""
        p = self._params
        K = lens.K_rectified
        corners = (np.array([[0, 0], [lens.width, 0], [0, lens.height],
                             [lens.width, lens.height]]) - K[:2, 2]) / K[[0, 1], [0, 1]]
        facing = -(np.column_stack([corners, np.ones(4)]) @ z_up_C)  # h / Z at each corner
        tilt_cos = -z_up_C[2] / np.linalg.norm(z_up_C)
        if height <= 0.0 or facing.min() <= 0.0 or tilt_cos <= 0.0:
            return 0                                      # the plane's horizon is in view
        side = K[0, 0] * self._corner_side * tilt_cos * facing.min() / height
        return int(np.clip(np.floor(np.log2(max(side / p.roi_min_side, 1.0))), 0, p.max_level))

    def search_region(self, prediction: Prediction, lens: Lens) \
            -> tuple[int, tuple[float, float, float, float]] | None:
        """(pyramid level, window (x0, y0, x1, y1) in rectified pixels) around the predicted
        platform: its projected outline grown by roi_sigmas times the prediction's uncertainty
        at the platform's nearest point plus roi_margin of the square's side; the coarsest level
        (up to max_level) where the square's side still spans roi_min_side px. None if the
        platform is predicted behind the camera or out of the image."""
        p = self._params
        K = lens.K_rectified
        R, t = prediction.X_CT.rotation().matrix(), prediction.X_CT.translation()
        s = self._pattern.params.side / 2
        outline = np.array([[s, s, 0], [-s, s, 0], [-s, -s, 0], [s, -s, 0]]) @ R.T + t
        squares = self._pattern.corners @ R.T + t
        if min(outline[:, 2].min(), squares[:, 2].min()) < 0.05:
            return None
        uv = outline[:, :2] / outline[:, 2:] @ K[:2, :2].T + K[:2, 2]
        side = np.sqrt(abs(_signed_area(squares[:, :2] / squares[:, 2:] @ K[:2, :2].T)))
        sigma = K[0, 0] * (prediction.position_std + prediction.rotation_std * s * np.sqrt(2)) \
            / outline[:, 2].min()
        grow = p.roi_sigmas * sigma + p.roi_margin * side
        x0, y0 = np.maximum(uv.min(axis=0) - grow, 0)
        x1, y1 = np.minimum(uv.max(axis=0) + grow, [lens.width, lens.height])
        if not (x1 - x0 > 8 and y1 - y0 > 8):
            return None
        level = int(np.clip(np.floor(np.log2(max(side / p.roi_min_side, 1.0))), 0, p.max_level))
        return level, (float(x0), float(y0), float(x1), float(y1))

    def _detect_in(self, frame: RectifiedFrame, view: View, R_CT_reference, z_up_C) \
            -> list[Detection]:
        p = self._params
        K = frame.lens.K_rectified
        ncc = p.verification == "ncc"
        detections = []
        for corners in self._quads(view):
            if ncc and self._score(view.smoothed, corners, False, coarse=True).correlation \
                    < p.min_correlation - p.prefilter_slack:
                continue  # raw corners: clearly not the pattern, not worth refining
            corners = self._refine(view.smoothed, corners)
            candidate = self._score(view.smoothed, corners, False)
            if not self._accepted(candidate):
                continue
            corners = view.to_full(corners)
            if view.level > 0:  # sub-pixel at full resolution, in a patch around the square
                reach = self._reach(corners) + 2
                patch = frame.view(0, (*(corners.min(axis=0) - reach),
                                       *(corners.max(axis=0) + reach + 1)), binary=False)
                corners = patch.to_full(self._refine(patch.smoothed,
                                                     corners - np.float32(patch.origin)))
            X_CT = self.pose(corners, K, R_CT_reference, z_up_C=z_up_C)
            if X_CT is None:
                continue
            score = candidate.correlation if ncc else -candidate.brisk_distance
            detections.append(Detection(X_CT, self._rotate_corners(corners, X_CT, K), score))
        detections.sort(key=lambda d: -d.score)
        kept = []
        for d in detections:
            if all(np.linalg.norm(d.X_CT.translation() - k.X_CT.translation())
                   > 0.25 * k.X_CT.translation()[2] for k in kept):
                kept.append(d)
        return kept

    # --- steps --------------------------------------------------------------------------------
    def _quads(self, view: View) -> list[np.ndarray]:
        """Raw corners (view pixels, ordered like keypoints 0-3 up to rotation) of the convex
        quadrilateral contours wholly inside the valid pixels."""
        p = self._params
        binary, valid = view.binary, view.valid
        h, w = binary.shape
        min_area = p.min_quad_area / view.scale ** 2
        contours, _ = cv2.findContours(binary, cv2.RETR_LIST, cv2.CHAIN_APPROX_SIMPLE)
        quads = []
        for contour in [c for c in contours if len(c) >= 4 and cv2.contourArea(c) >= min_area]:
            approx = cv2.approxPolyDP(contour, p.approx_epsilon * cv2.arcLength(contour, True),
                                      True)
            if len(approx) != 4 or not cv2.isContourConvex(approx):
                continue
            corners = approx.reshape(4, 2).astype(np.float32)
            u, v = np.clip(corners.round().astype(int).T, 0, [[w - 1], [h - 1]])
            if not valid[v, u].all():  # partly outside the image: not a whole pattern
                continue
            if _signed_area(corners) > 0:  # order like keypoints 0-3 (see pattern.py)
                corners = corners[::-1].copy()
            quads.append(corners)
        return quads

    def _reach(self, corners: np.ndarray) -> float:
        """How far from the raw side the refinement looks [px]: 0.6 of the black band's width
        (if the quad is the pattern's square), 1-2.5 px."""
        band = np.sqrt(abs(_signed_area(corners))) * self._pattern.params.border \
            / (2 * self._pattern.half_inner)
        return float(np.clip(0.6 * band, 1.0, 2.5))

    def _refine(self, smoothed: np.ndarray, corners: np.ndarray) -> np.ndarray:
        return refine_corners(smoothed, corners, self._reach(corners))

    def _score(self, smoothed, corners, both_scores: bool, coarse: bool = False) -> Candidate:
        """Verification scores of a candidate; `coarse`: the NCC from a warp of at most twice the
        comparison size (the prefilter; the full test warps up to the template's size)."""
        ncc = both_scores or self._params.verification == "ncc"
        brisk = both_scores or self._params.verification == "brisk"
        correlation = distance = float("nan")
        if ncc:  # compare at the candidate's own resolution, at most verify_size
            side = np.sqrt(abs(_signed_area(corners))) * self._pattern.params.side \
                / (2 * self._pattern.half_inner)
            n = int(np.clip(side, 12, self._params.verify_size))
            size = int(np.clip(2 * side, n, 2 * n if coarse else self._template_size))
            warped = cv2.warpPerspective(smoothed, self._homography(corners, size), (size, size),
                                         flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            small = _zero_mean_unit(cv2.resize(warped, (n, n), interpolation=cv2.INTER_AREA))
            correlation = float((small * self._reference(n)).sum())
        if brisk:  # the paper's test: one BRISK descriptor on the 255 x 255 warp
            n = self._template_size
            warped = cv2.warpPerspective(smoothed, self._homography(corners, n), (n, n),
                                         flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            descriptor = self._brisk_descriptor(warped)
            distance = float(cv2.norm(descriptor, self._brisk_template, cv2.NORM_HAMMING)) \
                if descriptor is not None and self._brisk_template is not None else 512.0
        return Candidate(corners, correlation, distance)

    def _reference(self, n: int) -> np.ndarray:
        if n not in self._references:
            self._references[n] = _zero_mean_unit(cv2.resize(
                self._pattern.template(self._template_size), (n, n), interpolation=cv2.INTER_AREA))
        return self._references[n]

    def _homography(self, corners, size: int) -> np.ndarray:
        target = self._template_corners * (size / self._template_size)
        return cv2.getPerspectiveTransform(corners.astype(np.float32), target.astype(np.float32))

    def _accepted(self, candidate: Candidate) -> bool:
        if self._params.verification == "ncc":
            return candidate.correlation >= self._params.min_correlation
        return candidate.brisk_distance <= self._params.brisk_max_distance

    def _brisk_descriptor(self, image) -> np.ndarray | None:
        n = image.shape[0]
        pad = n // 2
        padded = cv2.copyMakeBorder(image, pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=0)
        keypoints, descriptors = self._brisk.compute(padded, [cv2.KeyPoint(
            pad + (n - 1) / 2, pad + (n - 1) / 2, self._params.brisk_keypoint_size * n / 255)])
        return descriptors if keypoints else None

    def pose(self, corners: np.ndarray, K: np.ndarray, R_CT_reference: np.ndarray | None = None,
             symmetric: bool = True, z_up_C: np.ndarray | None = None) -> RigidTransform | None:
        """X_CT from the four corners (rectified pixels, no distortion). A planar square has two
        pose solutions (the plane tilted either way; `cv2.solvePnPGeneric`): the one whose normal
        z_T is closest to `z_up_C` (the world's up in the camera frame: the platform is level) or
        to the reference's z is kept, else the one with the smaller reprojection error. With
        `symmetric` (corners known only up to a cyclic shift), the 90-degree rotation of the
        pattern closest to `R_CT_reference` (default: T's x along the image's up); otherwise the
        corners are keypoints 0-3 in order."""
        method = cv2.SOLVEPNP_IPPE if self._params.pnp == "ippe" else cv2.SOLVEPNP_P3P
        count, rvecs, tvecs, errors = cv2.solvePnPGeneric(
            self._pattern.corners, corners.astype(np.float64), K, None, flags=method)
        solutions = [(cv2.Rodrigues(r)[0], t.ravel(), float(e)) for r, t, e in
                     zip(rvecs, tvecs, np.ravel(errors)) if np.all(np.isfinite(t)) and t[2] > 0]
        if not solutions:
            return None
        if z_up_C is None and R_CT_reference is not None:
            z_up_C = R_CT_reference[:, 2]
        if z_up_C is not None:
            R_CT, p_CT, _ = max(solutions, key=lambda s: s[0][:, 2] @ z_up_C)
        else:
            R_CT, p_CT, _ = min(solutions, key=lambda s: s[2])
        if not symmetric:
            return RigidTransform(RotationMatrix(R_CT), p_CT)
        if R_CT_reference is None:
            R_CT_reference = _image_up_reference(R_CT)
        best = max(range(4), key=lambda k: np.trace(
            R_CT_reference.T @ R_CT @ _rz(k * np.pi / 2)))
        return RigidTransform(RotationMatrix(R_CT @ _rz(best * np.pi / 2)), p_CT)

    def _rotate_corners(self, corners, X_CT, K) -> np.ndarray:
        """The corners reordered to match keypoints 0-3 under the chosen rotation."""
        p_C = (X_CT.GetAsMatrix34() @ np.vstack([self._pattern.corners.T, np.ones(4)])).T
        uv = p_C[:, :2] / p_C[:, 2:3] @ K[:2, :2].T + K[:2, 2]
        order = [int(np.argmin(np.linalg.norm(corners - u, axis=1))) for u in uv]
        return corners[order]


def refine_corners(grey: np.ndarray, corners: np.ndarray, reach: float = 2.5) -> np.ndarray:
    """Sub-pixel corners: along each side, the strongest intensity step across the side (within
    `reach` px of the contour, parabolic peak of the gradient) at evenly spaced points, a
    least-squares line through them, and the intersections of adjacent lines. Only the quad's
    neighbourhood is converted to float (not the whole frame per quad)."""
    h, w = grey.shape
    x0, y0 = np.maximum(np.floor(corners.min(axis=0) - reach - 2).astype(int), 0)
    x1, y1 = np.minimum(np.ceil(corners.max(axis=0) + reach + 3).astype(int), [w, h])
    image = grey[y0:y1, x0:x1].astype(np.float32)
    origin = np.array([x0, y0], float)
    lines = []
    for i in range(4):
        a, b = corners[i].astype(float), corners[(i + 1) % 4].astype(float)
        length = np.linalg.norm(b - a)
        if length < 4:
            return corners
        direction = (b - a) / length
        normal = np.array([-direction[1], direction[0]])
        t = np.linspace(0.15, 0.85, int(np.clip(length / 2, 4, 40)))
        offsets = np.arange(-reach, reach + 1e-9, 0.5)
        points = a + np.outer(t * length, direction)
        samples = points[:, None, :] + offsets[None, :, None] * normal - origin
        profile = cv2.remap(image, samples[..., 0].astype(np.float32),
                            samples[..., 1].astype(np.float32), cv2.INTER_LINEAR)
        gradient = np.abs(np.diff(profile, axis=1))
        k = np.clip(np.argmax(gradient, axis=1), 1, gradient.shape[1] - 2)
        rows = np.arange(len(k))
        g0, g1, g2 = gradient[rows, k - 1], gradient[rows, k], gradient[rows, k + 1]
        denominator = g0 - 2 * g1 + g2
        safe = np.where(np.abs(denominator) > 1e-9, denominator, 1.0)
        delta = np.where(np.abs(denominator) > 1e-9, 0.5 * (g0 - g2) / safe, 0.0)
        shift = offsets[0] + 0.25 + 0.5 * (k + np.clip(delta, -0.5, 0.5))
        edge = points + shift[:, None] * normal
        centre = edge.mean(axis=0)
        _, _, vt = np.linalg.svd(edge - centre)
        lines.append((centre, vt[0]))
    refined = []
    for i in range(4):
        (p1, d1), (p2, d2) = lines[i - 1], lines[i]
        A = np.column_stack([d1, -d2])
        if abs(np.linalg.det(A)) < 1e-6:
            return corners
        s = np.linalg.solve(A, p2 - p1)
        refined.append(p1 + s[0] * d1)
    refined = np.array(refined, np.float32)
    if np.max(np.linalg.norm(refined - corners, axis=1)) > 2 * reach:
        return corners
    return refined


def _image_up_reference(R_CT: np.ndarray) -> np.ndarray:
    """The orientation with T's z as in R_CT and T's x as close as possible to the image's up."""
    z = R_CT[:, 2]
    x = np.array([0.0, -1.0, 0.0]) - z * (-z[1])
    if np.linalg.norm(x) < 1e-6:
        x = np.array([1.0, 0.0, 0.0]) - z * z[0]
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def _rz(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def _signed_area(corners: np.ndarray) -> float:
    """Shoelace area in pixel coordinates (u right, v down)."""
    return float(cv2.contourArea(corners.astype(np.float32), oriented=True))


def _zero_mean_unit(image: np.ndarray) -> np.ndarray:
    x = image.astype(np.float64)
    x -= x.mean()
    norm = np.linalg.norm(x)
    return x / norm if norm > 0 else x
