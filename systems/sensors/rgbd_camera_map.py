"""The landmark map seen by the `geometric` forward RGB-D camera (issue 8, L Sec. 5.1; DESIGN.md
"Simulation fidelity"): the salient points a feature detector would find in the scene, as 3D points
p_WL in the world. Textured ground (random points on z = 0) plus box-shaped objects standing on it
(points on their four sides and top), all drawn from one seed so that a scenario is reproducible.

The map may stretch hundreds of metres along a road (a chase at 5-10 m/s); `LandmarkGrid` indexes
the landmarks by square cells on the ground so that a camera projects only the landmarks within
its range instead of the whole map every frame.

Each landmark carries the outward normal of the surface it lies on (the ground's is +z) and the
index of its box (-1: the ground), so that the camera can tell a back face and an occluded point
(`rgbd_camera.GeometricRgbdCamera`, issue 20).
"""
import dataclasses as dc

import numpy as np

from alight.systems.params import bounded


@dc.dataclass
class LandmarkMapParams:
    seed: int = bounded(7, 0, 2 ** 31 - 1)
    extent: list[float] = bounded([-30.0, -30.0, 30.0, 30.0], -1e4, 1e4, "m")  # x0, y0, x1, y1
    ground_density: float = bounded(3.0, 0.0, 100.0, "1/m^2")
    boxes: int = bounded(40, 0, 10000)
    box_size: list[float] = bounded([0.5, 3.0], 0.05, 50.0, "m")  # edge length range
    box_density: float = bounded(6.0, 0.0, 100.0, "1/m^2")         # points per m^2 of surface


@dc.dataclass(frozen=True)
class LandmarkMap:
    """p_WL (N, 3) landmark positions; boxes (M, 6) as x0, y0, x1, y1, height, unused; n_WL (N, 3)
    the outward unit normal of each landmark's surface; box (N,) its box's row in `boxes` (-1: on
    the ground)."""
    p_WL: np.ndarray
    boxes: np.ndarray
    n_WL: np.ndarray = None
    box: np.ndarray = None


_MAPS: dict[str, LandmarkMap] = {}   # made maps by their parameters (a few per process)


def make_landmark_map(params: LandmarkMapParams) -> LandmarkMap:
    """The map `params` draw, made once per process (about 0.4 s CPU for the landing road's
    178k landmarks, at every mission's build before): the same parameters draw the same map, and
    its arrays are read-only, so the missions of a campaign worker or a test session share it."""
    key = repr(params)
    if key not in _MAPS:
        if len(_MAPS) >= 4:
            _MAPS.pop(next(iter(_MAPS)))
        _MAPS[key] = _draw_landmark_map(params)
    return _MAPS[key]


def _draw_landmark_map(params: LandmarkMapParams) -> LandmarkMap:
    x0, y0, x1, y1 = params.extent
    if not (x1 > x0 and y1 > y0):
        raise ValueError(f"landmark map extent {params.extent} must have x1 > x0 and y1 > y0")
    rng = np.random.default_rng(params.seed)
    n_ground = rng.poisson(params.ground_density * (x1 - x0) * (y1 - y0))
    ground = np.column_stack([rng.uniform(x0, x1, n_ground), rng.uniform(y0, y1, n_ground),
                              np.zeros(n_ground)])
    points, boxes = [ground], []
    normals, owners = [np.tile([0.0, 0.0, 1.0], (n_ground, 1))], [np.full(n_ground, -1)]
    lo, hi = params.box_size
    for _ in range(params.boxes):
        size = rng.uniform(lo, hi, 3)
        centre = rng.uniform([x0, y0], [x1, y1])
        if np.hypot(*centre) < 3.0 + size[:2].max():  # keep the take-off spot clear
            continue
        boxes.append([*(centre - size[:2] / 2), *(centre + size[:2] / 2), size[2], 0.0])
        p, n = _box_surface_points(rng, centre, size, params.box_density)
        points.append(p)
        normals.append(n)
        owners.append(np.full(len(p), len(boxes) - 1))
    arrays = (np.vstack(points), np.array(boxes).reshape(-1, 6), np.vstack(normals),
              np.concatenate(owners))
    for array in arrays:
        array.flags.writeable = False
    return LandmarkMap(*arrays)


def _box_surface_points(rng, centre, size, density) -> tuple[np.ndarray, np.ndarray]:
    """Uniform points on the four sides and the top of a box standing on the ground, and their
    faces' outward normals."""
    sx, sy, sz = size
    faces, normals = [], []
    for axis, extent_a, extent_b in ((0, sy, sz), (1, sx, sz)):
        for side in (-0.5, 0.5):
            n = rng.poisson(density * extent_a * extent_b)
            a, z = rng.uniform(-0.5, 0.5, n) * extent_a, rng.uniform(0, 1, n) * sz
            offset = np.full(n, side * size[axis])
            xy = np.column_stack([offset, a]) if axis == 0 else np.column_stack([a, offset])
            faces.append(np.column_stack([centre + xy, z]))
            normals.append(np.tile(np.eye(3)[axis] * np.sign(side), (n, 1)))
    n = rng.poisson(density * sx * sy)
    top = rng.uniform(-0.5, 0.5, (n, 2)) * [sx, sy] + centre
    faces.append(np.column_stack([top, np.full(n, sz)]))
    normals.append(np.tile([0.0, 0.0, 1.0], (n, 1)))
    return np.vstack(faces), np.vstack(normals)


class LandmarkGrid:
    """`LandmarkGrid(p_WL, cell)`: the landmarks sorted into square cells on the ground. `boxes`
    (K, 5) are the non-empty cells as boxes standing on the ground (x0, y0, x1, y1, height: the
    highest landmark in the cell); `order` the landmark indices cell by cell (increasing within
    a cell), `slot` each landmark's position in `order`, `slots(rows)` the positions in `order`
    of the landmarks of those cells (cell by cell: a camera gathers them close together)."""

    def __init__(self, p_WL: np.ndarray, cell: float):
        p_WL = np.asarray(p_WL, float).reshape(-1, 3)
        origin = p_WL[:, :2].min(axis=0) if len(p_WL) else np.zeros(2)
        ij = np.floor((p_WL[:, :2] - origin) / cell).astype(np.int64)
        key = ij[:, 0] * (ij[:, 1].max(initial=0) + 1) + ij[:, 1]
        self.order = np.argsort(key, kind="stable")
        self.slot = np.empty_like(self.order)
        self.slot[self.order] = np.arange(len(key))
        keys, first = np.unique(key[self.order], return_index=True)
        # the landmarks of non-empty cell r are self.order[first[r]:first[r] + self._count[r]]
        self._first, self._count = first, np.diff(np.append(first, len(key)))
        corner = origin + ij[self.order[first]] * cell
        height = np.maximum.reduceat(p_WL[self.order, 2], first) if len(first) else []
        self.boxes = np.column_stack([corner, corner + cell, height]).reshape(-1, 5)

    def slots(self, rows: np.ndarray) -> np.ndarray:
        first, count = self._first[rows], self._count[rows]
        return np.repeat(first - np.cumsum(count) + count, count) + np.arange(count.sum())
