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


class Rectifier:
    """The rectified image and its adaptive-threshold binarization, shared by detection and
    tracking (maps cached per calibration)."""

    def __init__(self, params: DetectorParams):
        self._params = params
        self._maps = {}

    def rectify(self, image: np.ndarray, lens: Lens) -> np.ndarray:
        return cv2.remap(image, *self._lens_maps(lens)[:2], cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_REPLICATE)

    def valid(self, lens: Lens) -> np.ndarray:
        """The rectified pixels that see the distorted image (uint8 0/255, margin removed)."""
        return self._lens_maps(lens)[2]

    def _lens_maps(self, lens: Lens):
        key = (lens.width, lens.height, lens.K.tobytes(), lens.distortion.tobytes(),
               lens.K_rectified.tobytes())
        if key not in self._maps:
            map1, map2 = lens.rectify_maps()
            ones = np.full((lens.height, lens.width), 255, np.uint8)
            valid = cv2.remap(ones, map1, map2, cv2.INTER_NEAREST,
                              borderMode=cv2.BORDER_CONSTANT, borderValue=0)
            margin = int(np.ceil(self._params.border_margin)) * 2 + 1
            valid = cv2.erode(valid, np.ones((margin, margin), np.uint8))
            self._maps[key] = (map1, map2, valid)
        return self._maps[key]

    def smooth(self, rectified: np.ndarray) -> np.ndarray:
        sigma = self._params.blur_sigma
        return cv2.GaussianBlur(rectified, (0, 0), sigma) if sigma > 0 else rectified

    def binarize(self, smoothed: np.ndarray) -> np.ndarray:
        block = max(3, int(self._params.threshold_block * smoothed.shape[1]) // 2 * 2 + 1)
        return cv2.adaptiveThreshold(smoothed, 255, cv2.ADAPTIVE_THRESH_MEAN_C, cv2.THRESH_BINARY,
                                     block, self._params.threshold_offset)


class PatternDetector:
    """Finds the pattern in a rectified, smoothed, binarized image (`Rectifier`)."""

    def __init__(self, pattern: Pattern, params: DetectorParams):
        self._pattern = pattern
        self._params = params
        n = pattern.params.template_size
        self._template_size = n
        self._template_corners = pattern.template_pixel(pattern.corners, n).astype(np.float32)
        self._references = {}
        self._brisk = cv2.BRISK_create()
        self._brisk_template = self._brisk_descriptor(pattern.template(n))

    def candidates(self, smoothed: np.ndarray, binary: np.ndarray, valid: np.ndarray,
                   both_scores: bool = False) -> list[Candidate]:
        """Every convex quadrilateral wholly inside `valid` with its verification score (both
        scores if asked; the other one is nan)."""
        return [self._score(smoothed, corners, both_scores)
                for corners in self._quads(smoothed, binary, valid)]

    def detect(self, smoothed: np.ndarray, binary: np.ndarray, valid: np.ndarray, K: np.ndarray,
               R_CT_reference: np.ndarray | None = None,
               z_up_C: np.ndarray | None = None) -> list[Detection]:
        """Verified detections, best first; nested duplicates (the same pattern's inner and outer
        quads) are merged. `R_CT_reference`, `z_up_C`: see `pose`."""
        detections = []
        for candidate in self.candidates(smoothed, binary, valid):
            if not self._accepted(candidate):
                continue
            X_CT = self.pose(candidate.corners, K, R_CT_reference, z_up_C=z_up_C)
            if X_CT is None:
                continue
            score = candidate.correlation if self._params.verification == "ncc" \
                else -candidate.brisk_distance
            detections.append(Detection(X_CT, self._rotate_corners(candidate.corners, X_CT, K),
                                        score))
        detections.sort(key=lambda d: -d.score)
        kept = []
        for d in detections:
            if all(np.linalg.norm(d.X_CT.translation() - k.X_CT.translation())
                   > 0.25 * k.X_CT.translation()[2] for k in kept):
                kept.append(d)
        return kept

    # --- steps --------------------------------------------------------------------------------
    def _quads(self, smoothed, binary, valid) -> list[np.ndarray]:
        p = self._params
        h, w = binary.shape
        contours, _ = cv2.findContours(binary, cv2.RETR_LIST, cv2.CHAIN_APPROX_SIMPLE)
        quads = []
        for contour in contours:
            if abs(cv2.contourArea(contour)) < p.min_quad_area:
                continue
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
            band = np.sqrt(abs(_signed_area(corners))) * self._pattern.params.border \
                / (2 * self._pattern.half_inner)  # the black band's width [px], if it is ours
            quads.append(refine_corners(smoothed, corners, float(np.clip(0.6 * band, 1.0, 2.5))))
        return quads

    def _score(self, smoothed, corners, both_scores: bool) -> Candidate:
        ncc = both_scores or self._params.verification == "ncc"
        brisk = both_scores or self._params.verification == "brisk"
        correlation = distance = float("nan")
        if ncc:  # compare at the candidate's own resolution, at most verify_size
            side = np.sqrt(abs(_signed_area(corners))) * self._pattern.params.side \
                / (2 * self._pattern.half_inner)
            n = int(np.clip(side, 12, self._params.verify_size))
            size = int(np.clip(2 * side, n, self._template_size))
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
    least-squares line through them, and the intersections of adjacent lines."""
    image = grey.astype(np.float32)
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
        samples = points[:, None, :] + offsets[None, :, None] * normal
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
