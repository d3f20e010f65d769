"""The target vehicle in the MultibodyPlant: a car carrying the landing platform (L Sec. 1: MBZIRC
2017 Challenge 1, a 1.5 m x 1.5 m platform on a moving vehicle), moved along its motion profile by
three actuated joints (x, y, heading) under PD control toward the profile's desired state. The
platform has contact geometry, so a landing on it is judged physically.

The PD law u = Kp (q_d - q) + Kd (v_d - v) is a Drake `MatrixGain` on the plant's state
(`target_drive`), applied as actuation: explicit, where SAP's implicit PD controllers would make
every plant step a constrained solve (about 50 us more per 1 ms step in free flight). With the
gains tuned to `tracking_frequency` (4 Hz, critically damped) the explicit law is far inside its
stability limit (omega dt = 0.025 at 1 ms) and tracks the profile as the implicit one did.
"""
import dataclasses as dc

import numpy as np
from pydrake.math import RigidTransform
from pydrake.multibody.parsing import Parser
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import FixedOffsetFrame, JointIndex, PrismaticJoint
from pydrake.systems.framework import LeafSystem
from pydrake.systems.primitives import MatrixGain

from alight.models import model_path
from alight.systems.params import bounded, choice, load_params, param_file
from alight.systems.perception.pattern import PatternParams
from alight.systems.target.motion import FieldTestParams, FigureEightParams, StraightParams

PLATFORM_BODY = "platform"


@dc.dataclass
class TargetParams:
    profile: str = choice("none", "straight", "figure_eight", "field_test")
    model: str = "target_vehicle.sdf"
    pattern: PatternParams = param_file(PatternParams, "target_pattern.yaml")   # on the platform
    platform_height: float = bounded(1.0, 0.2, 5.0, "m")
    initial_position: list[float] = bounded([0.0, -40.0], -1e4, 1e4, "m")
    initial_heading: float = bounded(90.0, -360.0, 360.0, "deg")
    tracking_frequency: float = bounded(4.0, 0.5, 50.0, "Hz")
    straight: StraightParams = dc.field(default_factory=StraightParams)
    figure_eight: FigureEightParams = dc.field(default_factory=FigureEightParams)
    field_test: FieldTestParams = dc.field(default_factory=FieldTestParams)


def load_target_params(filename: str = "target.yaml") -> TargetParams:
    return load_params(TargetParams, model_path(filename))


@dc.dataclass(frozen=True)
class TargetVehicle:
    instance: object       # ModelInstanceIndex
    platform: object       # the platform body (its frame is T)
    joints: tuple = ()     # the actuated joints x, y, heading (JointIndex), in actuator order
    kp: tuple = ()         # their PD gains [N/m or N m/rad], [N s/m or N m s/rad]
    kd: tuple = ()


def add_target_vehicle(plant: MultibodyPlant, params: TargetParams) -> TargetVehicle:
    """Adds the car, its planar joints and their actuators (before Finalize) with the PD gains
    of `target_drive`; the default pose is the profile's start."""
    (instance,) = Parser(plant).AddModels(model_path(params.model))
    base = plant.AddFrame(FixedOffsetFrame("target_base", plant.world_frame(), RigidTransform(
        [0.0, 0.0, params.platform_height]), instance))
    carriage_x = plant.GetBodyByName("carriage_x", instance)
    x_joint = plant.AddJoint(PrismaticJoint("x", base, carriage_x.body_frame(), [1.0, 0.0, 0.0]))
    y_joint = plant.GetJointByName("y", instance)
    heading = plant.GetJointByName("heading", instance)
    platform = plant.GetBodyByName(PLATFORM_BODY, instance)
    bodies = [plant.GetBodyByName(name, instance) for name in ("carriage_x", "carriage_y")]
    mass = sum(b.default_mass() for b in bodies) + platform.default_mass()
    inertia_z = platform.default_spatial_inertia().CalcRotationalInertia().get_moments()[2]
    omega = 2 * np.pi * params.tracking_frequency
    joints = (x_joint, y_joint, heading)
    masses = (mass, mass, inertia_z)
    for joint in joints:
        plant.AddJointActuator(joint.name(), joint)
    x0, y0 = params.initial_position
    x_joint.set_default_translation(x0)
    y_joint.set_default_translation(y0)
    heading.set_default_angle(np.radians(params.initial_heading))
    return TargetVehicle(instance, platform, tuple(j.index() for j in joints),
                         tuple(m * omega ** 2 for m in masses), tuple(2 * m * omega for m in masses))


def target_drive(plant: MultibodyPlant, vehicle: TargetVehicle) -> MatrixGain:
    """The car's PD drive (after Finalize): input [desired state (6) of the joints x, y, heading:
    positions then velocities; the plant's whole state], output the joints' actuation
    Kp (q_d - q) + Kd (v_d - v), for `plant.get_actuation_input_port(vehicle.instance)`."""
    selector = plant.MakeStateSelectorMatrix([JointIndex(int(j)) for j in vehicle.joints])
    gains = np.hstack([np.diag(vehicle.kp), np.diag(vehicle.kd)])
    return MatrixGain(np.hstack([gains, -gains @ selector]))


class PlatformState(LeafSystem):
    """The platform body's state in the free-body layout, for `GroundTruth` and the geometric camera.

    Input  `body_poses`            the plant's body poses
    Input  `body_spatial_velocities` the plant's body spatial velocities
    Output `target_state`          (13) [q_WT, p_WT, w_WT (W), v_WT (W)] of the target frame T
    """

    def __init__(self, platform_index):
        super().__init__()
        self._index = int(platform_index)
        self._poses = self.DeclareAbstractInputPort(
            "body_poses", _abstract_list(RigidTransform()))
        self._velocities = self.DeclareAbstractInputPort(
            "body_spatial_velocities", _abstract_list_velocity())
        # A pure function of the inputs (not of the time): recomputed only when they change.
        self.DeclareVectorOutputPort("target_state", 13, self._calc,
                                     prerequisites_of_calc={self.all_input_ports_ticket()})

    def _calc(self, context, output):
        # written in place: [q_WT, p_WT] then V_WT's coefficients [w_WT, v_WT]
        # (EvalAbstract(...).get_value(): the same list as Eval, with less pydrake overhead)
        X_WT = self._poses.EvalAbstract(context).get_value()[self._index]
        V_WT = self._velocities.EvalAbstract(context).get_value()[self._index]
        y = output.get_mutable_value()
        y[:4] = X_WT.rotation().ToQuaternion().wxyz()
        y[4:7] = X_WT.translation()
        y[7:] = V_WT.get_coeffs()


def _abstract_list(value):
    from pydrake.common.value import AbstractValue
    return AbstractValue.Make([value])


def _abstract_list_velocity():
    from pydrake.common.value import AbstractValue
    from pydrake.multibody.math import SpatialVelocity
    return AbstractValue.Make([SpatialVelocity()])
