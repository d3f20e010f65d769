"""Builds the forward RGB-D camera (issue 8) into the simulated vehicle: `add_rgbd_scene` (before
`Finalize`: the textured ground a rendered camera needs) and `add_rgbd_camera` (after: the camera
source, exported by `make_sim_vehicle` as the `rgbd` port). Reuses the down camera's render sensor
(`target.add_render_sensor`) and timing (`down_camera.TimedCamera`).
"""
from pydrake.common import RandomDistribution
from pydrake.common.value import AbstractValue
from pydrake.geometry import GeometryInstance, Mesh
from pydrake.math import RigidTransform
from pydrake.systems.primitives import ConstantValueSource, RandomSource

from alight.diagrams.world.target import add_render_sensor
from alight.models import model_path
from alight.systems.boundary import CameraFrame
from alight.systems.sensors.rgbd_camera import (GeometricRgbdCamera, RenderedRgbdCamera,
                                                RgbdCameraParams)


def add_rgbd_scene(plant, params: RgbdCameraParams, ground_textured: bool) -> bool:
    """Adds the textured ground for a rendered camera unless it is there already; returns whether
    the scene now has it (then the plain ground must not be perceived)."""
    if params.source != "rendered" or ground_textured:
        return ground_textured
    plant.RegisterVisualGeometry(plant.world_body(), GeometryInstance(
        RigidTransform(), Mesh(str(model_path("rgbd_ground.obj"))), "rgbd_ground_texture"))
    return True


def add_rgbd_camera(builder, plant, scene_graph, params: RgbdCameraParams, vehicle_body):
    """The camera source of `params.source`; returns its CameraFrame output port."""
    if params.source == "none":
        return builder.AddNamedSystem("rgbd_camera", ConstantValueSource(
            AbstractValue.Make(CameraFrame()))).get_output_port()
    seed = builder.AddNamedSystem("rgbd_camera_noise", RandomSource(
        RandomDistribution.kUniform, 1, params.period))
    if params.source == "geometric":
        camera = builder.AddNamedSystem("rgbd_camera", GeometricRgbdCamera(
            params, vehicle_body.index()))
        builder.Connect(plant.get_body_poses_output_port(), camera.GetInputPort("body_poses"))
    else:
        K = params.calibration()["K"]
        sensor = add_render_sensor(builder, plant, scene_graph, params, vehicle_body,
                                   (params.width, params.height, params.focal_length,
                                    K[0, 2], K[1, 2]), name="rgbd_camera_render")
        camera = builder.AddNamedSystem("rgbd_camera", RenderedRgbdCamera(params))
        builder.Connect(sensor.color_image_output_port(), camera.GetInputPort("color_image"))
        builder.Connect(sensor.depth_image_32F_output_port(), camera.GetInputPort("depth_image"))
    builder.Connect(seed.get_output_port(), camera.GetInputPort("noise_seed"))
    return camera.GetOutputPort("rgbd")
