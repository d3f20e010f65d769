"""The disarmed simulated vehicle let go from a chosen state: the drop experiments of the contact
and touchdown tests."""
import numpy as np
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.multibody.math import SpatialVelocity
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import VectorLogSink

from alight.diagrams.world.sim_vehicle import make_sim_vehicle
from alight.systems.boundary import FC_COMMAND, GROUND_TRUTH


def drop(config, height: float, duration: float = 1.0, rpy=(0.0, 0.0, 0.0), p_WB=None,
         v_WB=(0.0, 0.0, 0.0)):
    """The disarmed vehicle of `config` let go `height` m above its resting pose (or at `p_WB`),
    turned by roll-pitch-yaw `rpy` [rad], moving at `v_WB` [m/s]; its ground truth at every
    plant step: (times, {field: samples})."""
    builder = DiagramBuilder()
    vehicle = builder.AddSystem(make_sim_vehicle(config))
    log = builder.AddSystem(VectorLogSink(GROUND_TRUTH.size, config.time_step))
    builder.Connect(vehicle.GetOutputPort("ground_truth"), log.get_input_port())
    diagram = builder.Build()
    context = diagram.CreateDefaultContext()
    vehicle.GetInputPort("fc_command").FixValue(vehicle.GetMyContextFromRoot(context),
                                                FC_COMMAND.vector())
    plant = vehicle.GetSubsystemByName("plant")
    plant_context = plant.GetMyMutableContextFromRoot(context)
    body = plant.GetBodyByName(config.airframe.body)
    rest = plant.EvalBodyPoseInWorld(plant_context, body).translation()
    p = rest + [0.0, 0.0, height] if p_WB is None else np.asarray(p_WB)
    plant.SetFreeBodyPose(plant_context, body, RigidTransform(RollPitchYaw(*rpy), p))
    plant.SetFreeBodySpatialVelocity(plant_context, body,
                                     SpatialVelocity(np.zeros(3), np.asarray(v_WB, float)))
    simulator = Simulator(diagram, context)
    simulator.AdvanceTo(duration)
    data = log.FindLog(simulator.get_context())
    return data.sample_times(), {field: data.data()[GROUND_TRUTH.slice(field)].T.squeeze()
                                 for field, _ in GROUND_TRUTH.fields}
