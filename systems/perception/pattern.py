"""The landing pattern (L Sec. 5.2, Fig. 4-5): geometry, keypoints T r_t of L(9), template images.

A square platform of side `side` with a black band along its edges around a white square; inside,
a black ring and a black cross whose bars reach the ring. Frame T: centre of the top surface,
x forward, y left, z up (the pattern lies in z_T = 0). Keypoints (docs/target.md):
0-3 the corners of the white square (counter-clockwise about z_T from (+a, +a)), 4-7 the junctions
of the cross bars with the inside of the ring (+x, +y, -x, -y), 8 the centre of the cross.

Template images map T to pixels as u = (x + side/2) / side * n, v = (side/2 - y) / side * n
(the pattern seen from above with x right and y up): `template_pixel` and `template_homography`.
"""
import dataclasses as dc
from pathlib import Path

import cv2
import numpy as np

from alight.models import model_path
from alight.systems.params import bounded, load_params

CORNER_IDS = (0, 1, 2, 3)
NUM_KEYPOINTS = 9


@dc.dataclass
class PatternParams:
    side: float = bounded(1.5, 0.2, 10.0, "m")
    border: float = bounded(0.1, 0.0, 1.0, "m")
    ring_outer_radius: float = bounded(0.55, 0.05, 5.0, "m")
    ring_width: float = bounded(0.13, 0.01, 2.0, "m")
    bar_width: float = bounded(0.13, 0.01, 2.0, "m")
    template_size: int = bounded(255, 32, 4096, "px")


def load_pattern_params(filename: str = "target_pattern.yaml") -> PatternParams:
    return load_params(PatternParams, model_path(filename))


class Pattern:
    """The pattern's geometry in T and its template images (cached per size)."""

    def __init__(self, params: PatternParams):
        if params.border * 2 >= params.side or params.ring_outer_radius > _half_inner(params) \
                or params.ring_width >= params.ring_outer_radius:
            raise ValueError(f"inconsistent pattern geometry: {params}")
        self.params = params
        self.half_inner = _half_inner(params)  # a: half side of the white square
        self.inner_radius = params.ring_outer_radius - params.ring_width
        a, r = self.half_inner, self.inner_radius
        self.p_TK = np.array([[a, a, 0], [-a, a, 0], [-a, -a, 0], [a, -a, 0],
                              [r, 0, 0], [0, r, 0], [-r, 0, 0], [0, -r, 0], [0, 0, 0]], float)
        self._templates = {}

    @property
    def corners(self) -> np.ndarray:
        """(4, 3) corners of the white square (the detected quad), keypoints 0-3."""
        return self.p_TK[list(CORNER_IDS)]

    def template(self, size: int | None = None) -> np.ndarray:
        """The pattern as a size x size uint8 image (white 255, black 0), whole platform."""
        size = size or self.params.template_size
        if size not in self._templates:
            self._templates[size] = self._draw(size)
        return self._templates[size]

    def template_pixel(self, p_T: np.ndarray, size: int) -> np.ndarray:
        """Pixel coordinates (u, v) in a size-pixel template of points (..., >=2) in T."""
        p_T = np.asarray(p_T, float)
        s = self.params.side
        return np.stack([(p_T[..., 0] + s / 2) / s * size,
                         (s / 2 - p_T[..., 1]) / s * size], axis=-1)

    def template_to_T(self, size: int) -> np.ndarray:
        """3x3 map of template pixels (u, v, 1) to T-plane points (x, y, 1)."""
        s = self.params.side
        k = s / size
        return np.array([[k, 0, -s / 2], [0, -k, s / 2], [0, 0, 1.0]])

    def _draw(self, size: int, supersample: int = 4) -> np.ndarray:
        """Rendered at `supersample` x the size and area-averaged down; the pixel centres' x as
        a row and y as a column, so that only the shapes' tests span the whole grid."""
        n = size * supersample
        s = self.params.side
        centres = (np.arange(n) + 0.5) / n * s - s / 2
        x, y = centres[None, :], -centres[:, None]  # image rows go down: y decreases
        a = self.half_inner
        rho = np.hypot(x, y)
        w = self.params.bar_width / 2
        white = (np.abs(x) <= a) & (np.abs(y) <= a)
        ring = (rho <= self.params.ring_outer_radius) & (rho >= self.inner_radius)
        cross = (rho <= self.inner_radius) & ((np.abs(x) <= w) | (np.abs(y) <= w))
        image = np.where(white & ~ring & ~cross, np.float32(255.0), np.float32(0.0))
        return cv2.resize(image, (size, size), interpolation=cv2.INTER_AREA).round() \
            .astype(np.uint8)


def _half_inner(params: PatternParams) -> float:
    return params.side / 2 - params.border


def write_pattern_texture(pattern: Pattern, filename: str | Path, size: int = 2048) -> Path:
    """The platform texture for rendering (models/target_pattern.png)."""
    path = Path(filename)
    cv2.imwrite(str(path), pattern.template(size))
    return path
