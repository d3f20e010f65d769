"""Builds the moving target and the downward camera into a simulation diagram (issue 5):
`add_target_scene` (before the plant is finalized: the car, its platform, the textured ground) and
`add_target_systems` (after: the motion profile driving the car, the platform's true state, the
camera source). `DownCameraRig` renders or observes single frames at chosen poses, without dynamics,
for the detection tests and the benchmarks.
"""
import dataclasses as dc

import numpy as np
from pydrake.common import RandomDistribution
from pydrake.common.value import AbstractValue
from pydrake.geometry import (Box, ClippingRange, ColorRenderCamera, Cylinder, DepthRange,
                              DepthRenderCamera, GeometryInstance, Mesh,
                              RenderCameraCore)
from pydrake.math import RigidTransform
from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlantConfig
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import (ConstantValueSource, Multiplexer, RandomSource,
                                        TrajectorySource)
from pydrake.systems.sensors import CameraInfo, RgbdSensor

from alight.diagrams.world.ground import add_ground
from alight.diagrams.world.lighting import RENDERER, LightingParams, add_renderer
from alight.models import model_path
from alight.systems.boundary import CameraFrame
from alight.systems.perception.pattern import Pattern, load_pattern_params
from alight.systems.sensors.down_camera import (DownCameraParams, GeometricDownCamera,
                                                RenderedDownCamera, render_intrinsics)
from alight.systems.target.motion import (NOISE_SIZE, STATE_SIZE, TargetMotion, path_evaluator,
                                          straight_path)
from alight.systems.target.vehicle import (PlatformState, TargetParams, TargetVehicle,
                                           add_target_vehicle, target_drive)



@dc.dataclass
class TargetScene:
    """What `add_target_scene` put into the plant."""
    target: TargetParams
    camera: DownCameraParams
    vehicle: TargetVehicle | None  # None when the scene has no target
    pattern: Pattern


def add_target_scene(plant, target: TargetParams, camera: DownCameraParams,
                     grain: bool = False) -> TargetScene:
    """Adds the target vehicle (unless `target.profile` is none) and, for a rendered camera, the
    textured ground the camera sees: with `grain` (the forward VIO camera renders too) the
    field ground, the same field with centimetre grain the VIO finds corners on (models/
    textures.py). Call before `plant.Finalize()`."""
    vehicle = add_target_vehicle(plant, target) if target.profile != "none" else None
    if camera.source == "rendered":
        ground = "field_ground.obj" if grain else "target_ground.obj"
        plant.RegisterVisualGeometry(plant.world_body(), GeometryInstance(
            RigidTransform(), Mesh(str(model_path(ground))), "ground_texture"))
    return TargetScene(target, camera, vehicle, Pattern(target.pattern))


def perceived_ground(camera: DownCameraParams) -> bool:
    """Whether the plain ground plane should be seen by cameras (not when the textured ground is)."""
    return camera.source != "rendered"


def add_target_systems(builder: DiagramBuilder, plant, scene_graph, scene: TargetScene,
                       vehicle_body):
    """After Finalize: the motion profile driving the target's joints, and the camera source.
    Returns (`target_state` output port or None, `down_image` output port)."""
    target_state = None
    if scene.vehicle is not None:
        target_state = _add_motion(builder, plant, scene)
    down_image = _add_camera(builder, plant, scene_graph, scene, vehicle_body)
    return target_state, down_image


def _add_motion(builder, plant, scene: TargetScene):
    """The profile's desired state, evaluated in C++ at every plant step where it can be (the
    straight path, the field test's per-period polynomial; systems/target/motion.py), drives the
    car's joints through their PD law (`target_drive`)."""
    p = scene.target
    if p.profile == "straight":
        desired = builder.AddNamedSystem("target_motion", TrajectorySource(straight_path(
            p.initial_position, p.initial_heading, p.straight))).get_output_port()
    else:
        motion = builder.AddNamedSystem("target_motion", TargetMotion(
            p.profile, p.initial_position, p.initial_heading, p.straight, p.figure_eight,
            p.field_test))
        desired = motion.GetOutputPort("desired_state")
    if p.profile == "field_test":
        noise = builder.AddNamedSystem("target_motion_noise", RandomSource(
            RandomDistribution.kGaussian, NOISE_SIZE, p.field_test.period))
        builder.Connect(noise.get_output_port(), motion.GetInputPort("noise"))
        evaluator = builder.AddNamedSystem("target_path", path_evaluator())
        builder.Connect(motion.GetOutputPort("path_coefficients"), evaluator.get_input_port())
        desired = evaluator.get_output_port()
    drive_input = builder.AddNamedSystem("target_drive_input", Multiplexer(
        [STATE_SIZE, plant.num_multibody_states()]))
    drive = builder.AddNamedSystem("target_drive", target_drive(plant, scene.vehicle))
    builder.Connect(desired, drive_input.get_input_port(0))
    builder.Connect(plant.get_state_output_port(), drive_input.get_input_port(1))
    builder.Connect(drive_input.get_output_port(), drive.get_input_port())
    builder.Connect(drive.get_output_port(),
                    plant.get_actuation_input_port(scene.vehicle.instance))
    state = builder.AddNamedSystem("target_platform_state", PlatformState(
        scene.vehicle.platform.index()))
    builder.Connect(plant.get_body_poses_output_port(), state.GetInputPort("body_poses"))
    builder.Connect(plant.get_body_spatial_velocities_output_port(),
                    state.GetInputPort("body_spatial_velocities"))
    return state.GetOutputPort("target_state")


def _add_camera(builder, plant, scene_graph, scene: TargetScene, vehicle_body):
    params = scene.camera
    if params.source == "none":
        source = builder.AddNamedSystem("down_camera", ConstantValueSource(
            AbstractValue.Make(CameraFrame())))
        return source.get_output_port()
    if params.source == "rendered":
        sensor = add_render_sensor(builder, plant, scene_graph, params, vehicle_body)
        camera = builder.AddNamedSystem("down_camera", RenderedDownCamera(params))
        builder.Connect(sensor.color_image_output_port(), camera.GetInputPort("color_image"))
        seed = builder.AddNamedSystem("down_camera_noise", RandomSource(
            RandomDistribution.kUniform, 1, params.period))
        builder.Connect(seed.get_output_port(), camera.GetInputPort("noise_seed"))
        return camera.GetOutputPort("down_image")
    if scene.vehicle is None:
        raise ValueError("the geometric down camera observes the target: set a target profile")
    inspector = scene_graph.model_inspector()
    camera = builder.AddNamedSystem("down_camera", GeometricDownCamera(
        params, scene.pattern.p_TK, vehicle_body.index(), scene.vehicle.platform.index(),
        legs=leg_capsules(plant, inspector, vehicle_body),
        outline_T=body_outline(plant, inspector, scene.vehicle.platform)))
    builder.Connect(plant.get_body_poses_output_port(), camera.GetInputPort("body_poses"))
    builder.Connect(plant.get_body_spatial_velocities_output_port(),
                    camera.GetInputPort("body_spatial_velocities"))
    seed = builder.AddNamedSystem("down_camera_noise", RandomSource(
        RandomDistribution.kUniform, 1, params.period))
    builder.Connect(seed.get_output_port(), camera.GetInputPort("noise_seed"))
    return camera.GetOutputPort("down_image")


def _visuals(plant, inspector, body, name: str):
    """(shape, X_BG) of the body's visual geometries whose name contains `name`."""
    return [(inspector.GetShape(g), inspector.GetPoseInFrame(g))
            for g in plant.GetVisualGeometriesForBody(body) if name in inspector.GetName(g)]


def leg_capsules(plant, inspector, body) -> tuple:
    """The vehicle's legs as (end, end, radius) in B: its `leg` visual cylinders (airframe SDF)."""
    return tuple((X_BG.multiply([0.0, 0.0, -s.length() / 2]),
                  X_BG.multiply([0.0, 0.0, s.length() / 2]), s.radius())
                 for s, X_BG in _visuals(plant, inspector, body, "leg") if isinstance(s, Cylinder))


def body_outline(plant, inspector, platform) -> np.ndarray | None:
    """The top rectangle (4, 3) in T of the car's `body` visual box (target_vehicle.sdf)."""
    boxes = [(s, X) for s, X in _visuals(plant, inspector, platform, "body") if isinstance(s, Box)]
    if not boxes:
        return None
    box, X_TG = boxes[0]
    w, d, h = np.asarray(box.size()) / 2
    return X_TG.multiply(np.array([[w, d, h], [-w, d, h], [-w, -d, h], [w, -d, h]]).T).T


def add_render_sensor(builder, plant, scene_graph, params: DownCameraParams, body,
                      intrinsics=None, name: str = "down_camera_render") -> RgbdSensor:
    """A Drake RgbdSensor on the scene's renderer (`lighting.add_renderer`, added before)
    attached to `body` at `params.X_BC()`, with the pinhole `intrinsics` (width, height, f, cx,
    cy), by default the one that covers the down camera's lens (`render_intrinsics`)."""
    width, height, f, cx, cy = intrinsics or render_intrinsics(params)
    core = RenderCameraCore(RENDERER, CameraInfo(width, height, f, f, cx, cy),
                            ClippingRange(0.05, 200.0), RigidTransform())
    sensor = builder.AddNamedSystem(name, RgbdSensor(
        plant.GetBodyFrameIdOrThrow(body.index()), params.X_BC(), ColorRenderCamera(core, False),
        DepthRenderCamera(core, DepthRange(0.05, 60.0))))
    builder.Connect(scene_graph.get_query_output_port(), sensor.query_object_input_port())
    return sensor


class DownCameraRig:
    """The target scene and the down camera without dynamics: `render(X_WB, target_pose)` gives the
    distorted grey image of the camera on a body at X_WB, `observe` the geometric source's
    noise-free keypoints, `X_CT` the true pattern pose in the camera; lit by `lighting` (default
    Drake's headlight)."""

    def __init__(self, camera: DownCameraParams, target: TargetParams,
                 lighting: LightingParams | None = None):
        builder = DiagramBuilder()
        plant, scene_graph = AddMultibodyPlant(MultibodyPlantConfig(time_step=0.0), builder)
        from pydrake.multibody.tree import SpatialInertia
        self._body = plant.AddRigidBody("camera_carrier", SpatialInertia.SolidSphereWithMass(
            1.0, 0.1))
        camera = dc.replace(camera, source="rendered")
        target = dc.replace(target, profile="straight" if target.profile == "none"
                            else target.profile)
        self.scene = add_target_scene(plant, target, camera)
        add_ground(plant, 0.8, perceived=False)
        plant.Finalize()
        # Drake's headlight by default: the light the detector's grid tests are calibrated in
        add_renderer(scene_graph, lighting or LightingParams(kind="camera"),
                     camera.renderer_backend)
        self._sensor = add_render_sensor(builder, plant, scene_graph, camera, self._body)
        self.camera = RenderedDownCamera(camera)
        self.lens = camera.lens()
        outline_T = body_outline(plant, scene_graph.model_inspector(), self.scene.vehicle.platform)
        self.geometric = GeometricDownCamera(camera, self.scene.pattern.p_TK, 0, 0,
                                             outline_T=outline_T)
        self._plant = plant
        self._height = target.platform_height
        self._diagram = builder.Build()
        self._context = self._diagram.CreateDefaultContext()
        self._plant_context = plant.GetMyMutableContextFromRoot(self._context)
        self.X_BC = camera.X_BC()
        instance = self.scene.vehicle.instance
        self._joints = [plant.GetJointByName(n, instance) for n in ("x", "y", "heading")]

    def set_poses(self, X_WB: RigidTransform, target_xy_heading=(0.0, 0.0, 0.0)) -> None:
        self._plant.SetFreeBodyPose(self._plant_context, self._body, X_WB)
        x, y, heading = target_xy_heading
        self._joints[0].set_translation(self._plant_context, x)
        self._joints[1].set_translation(self._plant_context, y)
        self._joints[2].set_angle(self._plant_context, heading)

    def X_WT(self) -> RigidTransform:
        return self._plant.EvalBodyPoseInWorld(self._plant_context, self.scene.vehicle.platform)

    def X_CT(self) -> RigidTransform:
        X_WC = self._plant.EvalBodyPoseInWorld(self._plant_context, self._body) @ self.X_BC
        return X_WC.inverse() @ self.X_WT()

    def render(self, X_WB: RigidTransform, target_xy_heading=(0.0, 0.0, 0.0),
               seed: int = 0) -> np.ndarray:
        self.set_poses(X_WB, target_xy_heading)
        rgba = self._sensor.color_image_output_port().Eval(
            self._sensor.GetMyContextFromRoot(self._context)).data
        return self.camera.distort(rgba, seed)

    def observe(self, X_WB: RigidTransform, target_xy_heading=(0.0, 0.0, 0.0)):
        """Noise-free distorted keypoint pixels and their visibility (the geometric source)."""
        self.set_poses(X_WB, target_xy_heading)
        return self.geometric.observe(self.X_CT().inverse())

    def candidates(self, X_WB: RigidTransform, target_xy_heading=(0.0, 0.0, 0.0),
                   rng: np.random.Generator | None = None,
                   X_TC_before: RigidTransform | None = None):
        """The geometric source's candidates (distorted pixels) and what each is (keypoint id, or
        -1 for a false one); `X_TC_before`: the camera `exposure` earlier (default: no motion)."""
        self.set_poses(X_WB, target_xy_heading)
        X_TC = self.X_CT().inverse()
        return self.geometric.candidates(X_TC, X_TC if X_TC_before is None else X_TC_before,
                                         rng if rng is not None else np.random.default_rng(0))
