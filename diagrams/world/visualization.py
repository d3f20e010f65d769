"""Meshcat: live view and self-contained HTML replays, framed on the flight.

`add_meshcat_visualizer` draws the scene's illustration geometry. `add_flight_view` adds a
`FlightView`: the view follows the vehicle and the car (the scene is shifted so that their
midpoint stays in front of the camera, which backs off as they part), their paths drawn as
lines, the mission's mode as a label above the vehicle. Everything it sets is also recorded
(Meshcat animations hold transforms and properties, not objects: the paths are drawn in
one-second pieces shown from their end, the labels are textured planes made visible in turn), so
a replay opens framed on the action as the live view does.
"""
import enum
import tempfile
from pathlib import Path

import cv2
import numpy as np
from pydrake.geometry import (Meshcat, MeshcatVisualizer, MeshcatVisualizerParams, Mesh, Rgba,
                              Role)
from pydrake.math import RigidTransform
from pydrake.systems.framework import LeafSystem

from alight.systems.boundary import FC_STATUS, GROUND_TRUTH, ActiveMode, VectorLayout


def add_meshcat_visualizer(builder, scene_graph, meshcat: Meshcat):
    """Illustration geometry of the scene, published at 30 Hz."""
    return MeshcatVisualizer.AddToBuilder(builder, scene_graph, meshcat, MeshcatVisualizerParams(
        role=Role.kIllustration, publish_period=1 / 30))


def start_recording(meshcat: Meshcat) -> None:
    meshcat.StartRecording(frames_per_second=30.0, set_visualizations_while_recording=True)


def write_recording(meshcat: Meshcat, filename: str | Path) -> Path:
    """Stops the recording and writes a replay that opens in a browser without a server."""
    meshcat.StopRecording()
    meshcat.PublishRecording()
    path = Path(filename)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(meshcat.StaticHtml())
    return path


# Where the view's parts live in Meshcat's scene tree (under /drake, shifted with the scene).
SCENE = "/drake"
PATHS = "/drake/flight_view/paths"
MODE = "/drake/flight_view/mode"
CAMERA = "/Cameras/default/rotated/<object>"
GRID = "/Grid"
GRID_CELL = 1.0                                # m: the grid is moved by whole cells
CAMERA_OFFSET = np.array([-5.0, -5.0, 3.5])    # m, from the framed point (behind-left, above)
FIT = 8.0           # m: the vehicle-car distance framed from CAMERA_OFFSET (farther: backed off)
NEAR, FAR = 15.0, 30.0  # m: the car is framed with the vehicle from FAR in, fully from NEAR
LABEL_HEIGHT = 0.7  # m above the vehicle
LABEL_SIZE = (1.6, 0.2)  # m, width and height (the texture's 8:1)
COLORS = {"vehicle": Rgba(0.1, 0.3, 0.9, 1.0), "target": Rgba(0.9, 0.4, 0.0, 1.0)}


def framing(p_WB: np.ndarray, p_WT: np.ndarray | None) -> tuple[np.ndarray, float]:
    """The framed point and how far the camera backs off (CAMERA_OFFSET times it): the vehicle
    from 1 while the car is absent or more than FAR away; from NEAR in, their midpoint, backed
    off while they are more than FIT apart; in between, a blend of the two."""
    if p_WT is None:
        return p_WB.copy(), 1.0
    distance = float(np.linalg.norm(p_WB - p_WT))
    weight = float(np.clip((FAR - distance) / (FAR - NEAR), 0.0, 1.0))
    return p_WB + weight * (p_WT - p_WB) / 2, max(1.0, weight * distance / FIT)


def three_js(p_W: np.ndarray) -> list[float]:
    """A point of Drake's z-up world in three.js's y-up coordinates (the camera's properties)."""
    return [float(p_W[0]), float(p_W[2]), float(-p_W[1])]


class FlightView(LeafSystem):
    """Follows the flight in Meshcat (no outputs; publishes only, live and into a recording).

    Input `ground_truth` (GROUND_TRUTH): the vehicle p_WB, the car p_WT when `target_present`.
    Input `status` (`status_layout`): its field `mode_field` is the mode shown, named by `modes`.
    Every `period` the scene (/drake) is shifted by minus the framed point and the camera,
    looking at it, backed off (`framing`); every `path_period` the paths get a point, a piece
    closing every `piece` s; the label of the current mode is the one visible. The camera is
    moved only when its back-off changes (it is continuous: a recording's linear interpolation
    between two keys is within one change). What has been drawn (the open path pieces, the
    mode, the back-off) is kept by the system, as MeshcatVisualizer keeps what it has sent, not
    in the context: it describes the browser's scene, not the simulation."""

    def __init__(self, meshcat: Meshcat, status_layout: VectorLayout, mode_field: str,
                 modes: type[enum.IntEnum], period: float = 1 / 30, path_period: float = 0.1,
                 piece: float = 1.0):
        super().__init__()
        self._meshcat = meshcat
        self._truth = self.DeclareVectorInputPort("ground_truth", GROUND_TRUTH.size)
        self._status = self.DeclareVectorInputPort("status", status_layout.size)
        self._status_layout, self._mode_field = status_layout, mode_field
        self._modes = modes
        self._piece_points = int(round(piece / path_period)) + 1
        self.DeclareInitializationPublishEvent(self._start)
        self.DeclarePeriodicPublishEvent(period, 0.0, self._frame)
        self.DeclarePeriodicPublishEvent(path_period, 0.0, self._extend_paths)
        self._pieces: dict[str, list] = {}
        self._mode = self._back_off = None
        _draw_labels(meshcat, modes)

    def _positions(self, context) -> tuple[np.ndarray, np.ndarray | None]:
        truth = self._truth.Eval(context)
        present = GROUND_TRUTH.get(truth, "target_present") > 0.5
        return (GROUND_TRUTH.get(truth, "p_WB"),
                GROUND_TRUTH.get(truth, "p_WT") if present else None)

    def _start(self, context):
        for name in self._modes.__members__:
            self._meshcat.SetProperty(f"{MODE}/{name}", "visible", False, 0.0)
        self._mode = self._back_off = None
        self._pieces = {name: [0, []] for name in COLORS}
        self._meshcat.Delete(PATHS)
        self._meshcat.SetCameraPose(CAMERA_OFFSET, np.zeros(3))

    def _frame(self, context):
        t = context.get_time()
        p_WB, p_WT = self._positions(context)
        center, back_off = framing(p_WB, p_WT)
        self._meshcat.SetTransform(SCENE, RigidTransform(-center), t)
        grid = GRID_CELL * np.round(center / GRID_CELL)
        grid[2] = 0.0
        self._meshcat.SetTransform(GRID, RigidTransform(grid - center), t)
        if back_off != self._back_off:  # else the live view's camera is the user's to turn
            self._meshcat.SetProperty(CAMERA, "position", three_js(back_off * CAMERA_OFFSET), t)
            self._back_off = back_off
        self._meshcat.SetTransform(MODE, RigidTransform(p_WB + [0, 0, LABEL_HEIGHT]), t)
        mode = self._modes(int(round(self._status_layout.get(self._status.Eval(context),
                                                             self._mode_field))))
        if mode != self._mode:
            if self._mode is not None:
                self._meshcat.SetProperty(f"{MODE}/{self._mode.name}", "visible", False, t)
            self._meshcat.SetProperty(f"{MODE}/{mode.name}", "visible", True, t)
            self._mode = mode

    def _extend_paths(self, context):
        t = context.get_time()
        for name, p in zip(COLORS, self._positions(context)):
            index, points = self._pieces[name]
            if p is None:
                continue
            points.append(np.array(p))
            path = f"{PATHS}/{name}/{index}"
            if len(points) >= 2:
                self._meshcat.SetLine(path, np.array(points).T, 3.0, COLORS[name])
            if len(points) == self._piece_points:  # closed: shown in the replay from now on
                self._meshcat.SetProperty(path, "visible", False, 0.0)
                self._meshcat.SetProperty(path, "visible", True, t)
                self._pieces[name] = [index + 1, [points[-1]]]


def _draw_labels(meshcat: Meshcat, modes: type[enum.IntEnum]) -> None:
    """One textured plane per mode under MODE, facing the camera, its name written on it."""
    forward = -CAMERA_OFFSET / np.linalg.norm(CAMERA_OFFSET)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    width, height = LABEL_SIZE
    corners = [s * width / 2 * right + u * height / 2 * up for s, u in
               ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    with tempfile.TemporaryDirectory() as folder:
        for mode in modes:
            image = np.zeros((64, 512, 3), np.uint8)
            cv2.putText(image, mode.name, (14, 48), cv2.FONT_HERSHEY_DUPLEX, 1.5,
                        (255, 255, 255), 3, cv2.LINE_AA)
            cv2.imwrite(str(Path(folder) / f"{mode.name}.png"), image)
            # Self-lit (emissive map): readable whatever the lights.
            (Path(folder) / f"{mode.name}.mtl").write_text(
                f"newmtl label\nKa 1 1 1\nKd 1 1 1\nKe 1 1 1\nmap_Kd {mode.name}.png\n"
                f"map_Ke {mode.name}.png\n")
            (Path(folder) / f"{mode.name}.obj").write_text(
                f"mtllib {mode.name}.mtl\n"
                + "".join(f"v {x:.4f} {y:.4f} {z:.4f}\n" for x, y, z in corners)
                + "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nusemtl label\nf 1/1 2/2 3/3 4/4\n"
                + "f 4/4 3/3 2/2 1/1\n")
            meshcat.SetObject(f"{MODE}/{mode.name}", Mesh(str(Path(folder) / f"{mode.name}.obj")))


def add_flight_view(builder, meshcat: Meshcat, ground_truth, status, status_layout: VectorLayout,
                    mode_field: str, modes: type[enum.IntEnum]) -> FlightView:
    """A FlightView on the `ground_truth` and `status` output ports."""
    view = builder.AddNamedSystem("flight_view", FlightView(meshcat, status_layout, mode_field,
                                                            modes))
    builder.Connect(ground_truth, view.GetInputPort("ground_truth"))
    builder.Connect(status, view.GetInputPort("status"))
    return view


def add_vehicle_flight_view(builder, meshcat: Meshcat, vehicle) -> FlightView:
    """A FlightView on a simulated `vehicle` (its `ground_truth`), labelling the flight
    controller's mode (`fc_status`): for stacks without a mission of their own."""
    return add_flight_view(builder, meshcat, vehicle.GetOutputPort("ground_truth"),
                           vehicle.GetOutputPort("fc_status"), FC_STATUS, "mode", ActiveMode)
