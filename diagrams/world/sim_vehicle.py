"""Builds the simulated hexacopter: plant + motors + drag + wind + flight controller + sensors,
exporting exactly the vehicle-boundary ports of DESIGN.md (alight.systems.boundary)."""
import dataclasses as dc

import numpy as np
from pydrake.common import RandomDistribution
from pydrake.geometry import Box, Meshcat, Sphere
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.multibody.plant import (AddMultibodyPlant, ExternallyAppliedSpatialForceMultiplexer,
                                     MultibodyPlantConfig, Propeller)
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import RandomSource
from pydrake.systems.sensors import Accelerometer, Gyroscope

from alight.diagrams.world.contacts import add_contacts
from alight.diagrams.world.flight_controller import make_flight_controller
from alight.diagrams.world.ground import add_ground
from alight.diagrams.world.lighting import LightingParams, add_renderer
from alight.diagrams.world.rgbd_camera import add_rgbd_camera, add_rgbd_scene
from alight.systems.sensors.sampled import add_sampled_sensor
from alight.diagrams.world.target import add_target_scene, add_target_systems, perceived_ground
from alight.models import model_path
from alight.systems.autopilot.config import FlightControllerParams
from alight.systems.params import ConfigError, bounded, load_params, param_file
from alight.systems.plant.drag import AerodynamicDrag
from alight.systems.plant.hexacopter import (HexacopterParams, add_hexacopter, airframe,
                                             propeller_infos)
from alight.systems.plant.motor_fault import MotorFault, MotorFaultParams
from alight.systems.plant.motors import EscThrustMap, first_order_motors
from alight.systems.plant.tether import Tether, TetherParams
from alight.systems.plant.wind import Wind, WindParams
from alight.systems.sensors.command_faults import LinkLoss
from alight.systems.sensors.down_camera import DownCameraParams
from alight.systems.sensors.fc_estimate import FcEstimate, FcEstimateParams
from alight.systems.sensors.ground_truth import GroundTruth
from alight.systems.sensors.imu import Imu, ImuParams
from alight.systems.sensors.rangefinder import Rangefinder, RangefinderParams
from alight.systems.sensors.rgbd_camera import RgbdCameraParams
from alight.systems.target.vehicle import TargetParams


@dc.dataclass
class SimVehicleConfig:
    airframe: HexacopterParams = param_file(HexacopterParams, "hexacopter_f550.yaml")
    time_step: float = bounded(0.002, 1e-4, 0.01, "s")  # discrete MultibodyPlant (SAP contact)
    # Body drag sampled and held at this period (the flight controller's 250 Hz), 0: at every
    # plant step (AerodynamicDrag).
    drag_period: float = bounded(0.004, 0.0, 0.1, "s")
    # The contacts (ground truth, landing scores) sampled at this period, 0: at every plant step.
    # At 250 Hz a touchdown's peak leg force is seen within 3 % (the legs' force changes by
    # under 1 % per ms), at a quarter of the CPU of every step.
    contact_period: float = bounded(0.004, 0.0, 0.1, "s")
    ground_friction: float = bounded(0.8, 0.0, 2.0)
    initial_position: list[float] = bounded([0.0, 0.0], -1e4, 1e4, "m")  # x, y on the ground
    initial_heading: float = bounded(0.0, -360.0, 360.0, "deg")
    flight_controller: FlightControllerParams = dc.field(default_factory=FlightControllerParams)
    imu: ImuParams = dc.field(default_factory=ImuParams)
    fc_estimate: FcEstimateParams = dc.field(default_factory=FcEstimateParams)
    wind: WindParams = dc.field(default_factory=WindParams)
    down_camera: DownCameraParams = dc.field(default_factory=DownCameraParams)  # source none: no camera
    target: TargetParams = dc.field(default_factory=TargetParams)  # profile none: no target
    rgbd_camera: RgbdCameraParams = dc.field(default_factory=RgbdCameraParams)  # the VIO camera
    lighting: LightingParams = dc.field(default_factory=LightingParams)  # of rendered cameras
    # the downward rangefinder on `range` (against the ground and the car; an outage window over
    # the whole flight: none fitted)
    rangefinder: RangefinderParams = param_file(RangefinderParams, "rangefinder.yaml")
    tether: TetherParams = dc.field(default_factory=TetherParams)  # enabled false: none
    motor_fault: MotorFaultParams = dc.field(default_factory=MotorFaultParams)  # loss 0: none
    link_losses: list[list[float]] = dc.field(default_factory=list)  # command link lost [s]


def load_sim_vehicle_config(filename: str = "sim_vehicle.yaml") -> SimVehicleConfig:
    return load_params(SimVehicleConfig, model_path(filename))


def check_rate_grid(config: SimVehicleConfig) -> None:
    """Every sampled part of the vehicle (IMU, flight controller, its estimate, drag, contacts)
    runs at a multiple of the plant's `time_step`, so that each sample reads the plant state of
    its own instant (between steps the discrete plant holds the next step's state). Raises
    ConfigError naming the key otherwise."""
    periods = {"imu.period": config.imu.period,
               "flight_controller.period": config.flight_controller.period,
               "fc_estimate.period": config.fc_estimate.period,
               "drag_period": config.drag_period, "contact_period": config.contact_period,
               "rangefinder.period": config.rangefinder.period}
    for key, period in periods.items():
        steps = period / config.time_step
        if period and abs(steps - round(steps)) > 1e-6:
            raise ConfigError(f"vehicle: key '{key}' = {period} s is not a multiple of the plant's "
                              f"time_step {config.time_step} s: its samples would read the state "
                              f"of another instant (give a multiple, or a smaller time_step)")


def make_sim_vehicle(config: SimVehicleConfig, meshcat: Meshcat | None = None,
                     autopilot_outputs: bool = False) -> Diagram:
    """The simulated vehicle diagram. Inputs `fc_command` and `odometry` (the onboard estimate,
    fused by the flight controller as PX4's EKF2 fuses external vision; unconnected: no external
    vision); outputs `imu`, `fc_attitude`,
    `fc_status`, `rgbd` (the forward RGB-D camera of `config.rgbd_camera`, empty frames with source
    none), `down_image` (the downward camera of `config.down_camera`, empty frames with source
    none), `range` (the downward rangefinder of `config.rangefinder`) and the simulation-only
    `ground_truth` (with the target of `config.target`, if any).
    `autopilot_outputs` also exports the flight controller's `local_position` (its fused
    estimate, never a boundary port: for the simulated PX4 of hw/sim_autopilot.py).
    Seed it with `Diagram.SetRandomContext`. Its rates must lie on the plant's step
    (`check_rate_grid`)."""
    check_rate_grid(config)
    params = config.airframe
    builder = DiagramBuilder()
    # Point contact: no geometry here has hydroelastic properties, so the default
    # "hydroelastic_with_fallback" computed the same point pairs after an empty hydroelastic
    # query at every step (the same streams; the landing world's plant 10-25 % cheaper).
    plant, scene_graph = AddMultibodyPlant(
        MultibodyPlantConfig(time_step=config.time_step, discrete_contact_approximation="sap",
                             contact_model="point"),
        builder)
    add_ground(plant, config.ground_friction, perceived_ground(config.down_camera)
               and config.rgbd_camera.source != "rendered")
    instance = add_hexacopter(plant, params)
    scene = add_target_scene(plant, config.target, config.down_camera,
                             grain=config.rgbd_camera.source == "rendered")
    add_rgbd_scene(plant, config.rgbd_camera, not perceived_ground(config.down_camera))
    plant.Finalize()
    rendered = [c for c in (config.down_camera, config.rgbd_camera) if c.source == "rendered"]
    if rendered:    # the one renderer both cameras see the scene through
        add_renderer(scene_graph, config.lighting, rendered[0].renderer_backend)
    body = plant.GetBodyByName(params.body)
    frame = airframe(plant, params)
    n = frame.num_rotors

    # Rest on the ground at the start.
    plant.SetDefaultFloatingBaseBodyPose(body, RigidTransform(
        RollPitchYaw(0, 0, np.radians(config.initial_heading)),
        [*config.initial_position, _lowest_point_height(plant, scene_graph.model_inspector(), body)]))

    # Rotors: ESC map (saturation) -> first-order motors -> Drake Propeller -> plant.
    esc = builder.AddNamedSystem("esc", EscThrustMap(n, frame.rotor_curve))
    motors = builder.AddNamedSystem("motors", first_order_motors(
        params.time_constant, n, config.time_step))
    propellers = builder.AddNamedSystem("propellers", Propeller(propeller_infos(plant, params)))
    builder.Connect(esc.get_output_port(), motors.get_input_port())
    rotor_thrust = motors.get_output_port()
    if config.motor_fault.active:
        fault = builder.AddNamedSystem("motor_fault", MotorFault(n, config.motor_fault))
        builder.Connect(rotor_thrust, fault.get_input_port())
        rotor_thrust = fault.get_output_port()
    builder.Connect(rotor_thrust, propellers.get_command_input_port())
    builder.Connect(plant.get_body_poses_output_port(), propellers.get_body_poses_input_port())

    # Wind and drag.
    wind = builder.AddNamedSystem("wind", Wind(config.wind))
    wind_noise = builder.AddNamedSystem("wind_noise", RandomSource(
        RandomDistribution.kGaussian, 3, config.wind.period))
    builder.Connect(wind_noise.get_output_port(), wind.GetInputPort("noise"))
    drag = builder.AddNamedSystem("drag", AerodynamicDrag(
        body.index(), params.drag_linear, params.drag_quadratic, config.drag_period))
    body_state = plant.get_state_output_port(instance)
    builder.Connect(body_state, drag.GetInputPort("body_state"))
    builder.Connect(wind.GetOutputPort("wind"), drag.GetInputPort("wind"))
    sources = [propellers.get_spatial_forces_output_port(), drag.GetOutputPort("spatial_forces")]
    if config.tether.enabled:
        tether = builder.AddNamedSystem("tether", Tether(body.index(), config.tether))
        builder.Connect(body_state, tether.GetInputPort("body_state"))
        sources.append(tether.GetOutputPort("spatial_forces"))
    forces = builder.AddNamedSystem("applied_forces",
                                    ExternallyAppliedSpatialForceMultiplexer(len(sources)))
    for i, source in enumerate(sources):
        builder.Connect(source, forces.get_input_port(i))
    builder.Connect(forces.get_output_port(), plant.get_applied_spatial_force_input_port())

    # Sensors: IMU (Drake's ideal accelerometer and gyroscope + noise model), FC estimate.
    X_BS = RigidTransform()
    accelerometer = builder.AddNamedSystem("accelerometer", Accelerometer(
        body, X_BS, plant.gravity_field().gravity_vector()))
    gyroscope = builder.AddNamedSystem("gyroscope", Gyroscope(body, X_BS))
    for sensor in (accelerometer, gyroscope):
        builder.Connect(plant.get_body_poses_output_port(), sensor.get_body_poses_input_port())
        builder.Connect(plant.get_body_spatial_velocities_output_port(),
                        sensor.get_body_velocities_input_port())
    builder.Connect(plant.get_body_spatial_accelerations_output_port(),
                    accelerometer.get_body_accelerations_input_port())
    imu = builder.AddNamedSystem("imu", Imu(config.imu))
    imu_noise = builder.AddNamedSystem("imu_noise", RandomSource(
        RandomDistribution.kGaussian, 12, config.imu.period))
    builder.Connect(accelerometer.get_measurement_output_port(),
                    imu.GetInputPort("specific_force"))
    builder.Connect(gyroscope.get_measurement_output_port(), imu.GetInputPort("angular_velocity"))
    builder.Connect(imu_noise.get_output_port(), imu.GetInputPort("noise"))
    estimate = builder.AddNamedSystem("fc_estimate", FcEstimate(config.fc_estimate))
    estimate_noise = builder.AddNamedSystem("fc_estimate_noise", RandomSource(
        RandomDistribution.kGaussian, 7, config.fc_estimate.period))
    builder.Connect(body_state, estimate.GetInputPort("body_state"))
    builder.Connect(estimate_noise.get_output_port(), estimate.GetInputPort("noise"))

    # Flight controller.
    fc = builder.AddSystem(make_flight_controller(config.flight_controller, frame))
    builder.Connect(estimate.GetOutputPort("fc_attitude"), fc.GetInputPort("fc_attitude"))
    builder.Connect(estimate.GetOutputPort("vertical_velocity"),
                    fc.GetInputPort("vertical_velocity"))
    builder.Connect(fc.GetOutputPort("motor_command"), esc.GetInputPort("motor_command"))
    builder.Connect(fc.GetOutputPort("armed"), esc.GetInputPort("armed"))
    builder.Connect(imu.GetOutputPort("imu"), fc.GetInputPort("imu"))

    target_state, down_image = add_target_systems(builder, plant, scene_graph, scene, body)
    truth = builder.AddNamedSystem("ground_truth", GroundTruth(n, target_state is not None))
    builder.Connect(add_contacts(builder, plant, scene_graph, params, body,
                                 scene.vehicle.platform if scene.vehicle is not None else None,
                                 config.contact_period or config.time_step),
                    truth.GetInputPort("contacts"))
    if target_state is not None:
        builder.Connect(target_state, truth.GetInputPort("target_state"))
    builder.Connect(body_state, truth.GetInputPort("body_state"))
    builder.Connect(wind.GetOutputPort("wind"), truth.GetInputPort("wind"))
    builder.Connect(fc.GetOutputPort("motor_command"), truth.GetInputPort("motor_command"))
    builder.Connect(rotor_thrust, truth.GetInputPort("rotor_thrust"))

    if meshcat is not None:
        from alight.diagrams.world.visualization import add_meshcat_visualizer
        add_meshcat_visualizer(builder, scene_graph, meshcat)

    if config.link_losses:
        link = builder.AddNamedSystem("link_loss", LinkLoss(config.link_losses))
        builder.Connect(link.get_output_port(), fc.GetInputPort("fc_command"))
        builder.ExportInput(link.get_input_port(), "fc_command")
    else:
        builder.ExportInput(fc.GetInputPort("fc_command"), "fc_command")
    builder.ExportInput(fc.GetInputPort("odometry"), "odometry")
    builder.ExportOutput(imu.GetOutputPort("imu"), "imu")
    builder.ExportOutput(estimate.GetOutputPort("fc_attitude"), "fc_attitude")
    builder.ExportOutput(fc.GetOutputPort("fc_status"), "fc_status")
    builder.ExportOutput(add_rgbd_camera(builder, plant, scene_graph, config.rgbd_camera, body),
                         "rgbd")
    builder.ExportOutput(down_image, "down_image")
    rangefinder = dc.replace(config.rangefinder, target_model=config.target.model)  # the car's
    builder.ExportOutput(add_sampled_sensor(
        builder, "rangefinder", Rangefinder(rangefinder), rangefinder.latency,
        truth.GetOutputPort("ground_truth")), "range")
    builder.ExportOutput(truth.GetOutputPort("ground_truth"), "ground_truth")
    if autopilot_outputs:
        builder.ExportOutput(fc.GetOutputPort("local_position"), "local_position")
    diagram = builder.Build()
    diagram.set_name("sim_vehicle")
    return diagram


def _lowest_point_height(plant, inspector, body) -> float:
    """Height of the body origin when its lowest collision geometry touches z = 0."""
    lowest = 0.0
    for geometry_id in plant.GetCollisionGeometriesForBody(body):
        X_BG = inspector.GetPoseInFrame(geometry_id)
        shape = inspector.GetShape(geometry_id)
        extent = shape.radius() if isinstance(shape, Sphere) else \
            shape.depth() / 2 if isinstance(shape, Box) else 0.0
        lowest = min(lowest, X_BG.translation()[2] - extent)
    return -lowest
