"""What a downward range or flow sensor sees (DESIGN.md "Simulation fidelity": range and flow
sensors measure against the scene's geometry, moving vehicles included): a ray from the body against
the ground plane z = 0 and the target vehicle's collision boxes (its platform and body, from the
target's SDF, posed by the ground truth's p_WT, q_WT when `target_present`).
"""
import functools
import math

import numpy as np
from pydrake.geometry import Box, SceneGraph
from pydrake.multibody.parsing import Parser
from pydrake.multibody.plant import MultibodyPlant

from alight.models import model_path
from alight.systems.boundary import GROUND_TRUTH
from alight.systems.rotations import rotation_matrix

PLATFORM_BODY = "platform"   # the body whose frame is T (systems/target/vehicle.py)
# the ground truth's fields a ray reads (by index: this runs at every sample)
_P_WB, _Q_WB, _P_WT, _Q_WT = (GROUND_TRUTH.slice(f) for f in ("p_WB", "q_WB", "p_WT", "q_WT"))
_TARGET_PRESENT = GROUND_TRUTH.slice("target_present").start


@functools.lru_cache(maxsize=8)
def target_boxes(model: str) -> tuple:
    """The collision boxes of the target's platform body in T: ((R_TG (3, 3), p_TG (3,), half
    size (3,)), ...), read from the target's SDF (`model`, a file in models/ or a path)."""
    plant = MultibodyPlant(0.0)
    scene_graph = SceneGraph()
    plant.RegisterAsSourceForSceneGraph(scene_graph)
    Parser(plant).AddModels(str(model_path(model)))
    plant.Finalize()
    inspector = scene_graph.model_inspector()
    boxes = []
    for g in plant.GetCollisionGeometriesForBody(plant.GetBodyByName(PLATFORM_BODY)):
        shape = inspector.GetShape(g)
        if isinstance(shape, Box):
            X_TG = inspector.GetPoseInFrame(g)
            boxes.append((X_TG.rotation().matrix(), X_TG.translation(),
                          np.asarray(shape.size()) / 2))
    return tuple(boxes)


def ray_hit(truth: np.ndarray, d_B: np.ndarray, boxes: tuple,
            R_WB: np.ndarray | None = None) -> tuple[float, bool]:
    """Distance [m] from the body's origin along `d_B` (a unit direction in B) to the first
    surface, and whether that surface is the target's (inf: nothing hit). `R_WB`: the truth's
    rotation_matrix(q_WB), when the caller has it."""
    if R_WB is None:
        R_WB = rotation_matrix(truth[_Q_WB])
    p_WB = truth[_P_WB]
    d_W = R_WB @ d_B
    ground = max(p_WB[2], 0.0) / -d_W[2] if d_W[2] < -1e-9 else np.inf
    if not boxes or truth[_TARGET_PRESENT] < 0.5:
        return float(ground), False
    R_WT = rotation_matrix(truth[_Q_WT])
    p_TB_W = p_WB - truth[_P_WT]
    target = min(_box_entry_in(R_WT @ R_TG, p_TB_W - R_WT @ p_TG, d_W, half)
                 for R_TG, p_TG, half in boxes)
    return (float(target), True) if target < ground else (float(ground), False)


def _box_entry_in(R_WG: np.ndarray, p_GB_W: np.ndarray, d_W: np.ndarray, half: np.ndarray
                  ) -> float:
    """`_box_entry` of the ray from p_GB_W (in W, from the box's centre) along d_W against the
    box G of orientation R_WG: both re-expressed in G."""
    R_GW = R_WG.T
    return _box_entry(R_GW @ p_GB_W, R_GW @ d_W, half)


def _box_entry(p: np.ndarray, d: np.ndarray, half: np.ndarray) -> float:
    """Slab test: the ray p + s d (s >= 0) against the box |x| <= half (its own frame)."""
    # On the three axes as Python floats (this runs at every rangefinder sample): NumPy's
    # element-wise operations, without its per-call overhead and its division warnings.
    near, far = -math.inf, math.inf
    for p_i, d_i, half_i in zip(p.tolist(), d.tolist(), half.tolist()):
        if abs(d_i) < 1e-12:   # parallel to this slab: inside it or never
            if abs(p_i) > half_i:
                return math.inf
            continue
        a, b = (-half_i - p_i) / d_i, (half_i - p_i) / d_i
        near, far = max(near, min(a, b)), min(far, max(a, b))
    return max(near, 0.0) if far >= max(near, 0.0) else math.inf
