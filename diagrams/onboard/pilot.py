"""The onboard side of the hover demo (`alight hover`): the scripted pilot commanding the vehicle
through take-off, hover and landing on an attitude/thrust profile (no position controller)."""


from pydrake.multibody.plant import MultibodyPlant

from alight.diagrams.running.run_log import RunLoggers, add_run_logging
from alight.models import model_path
from alight.systems.control.scripted_pilot import PilotModel, PilotProfile, ScriptedPilot
from alight.systems.params import load_params
from alight.systems.plant.hexacopter import HexacopterParams, add_hexacopter, airframe


def load_pilot_profile(filename: str = "hover_profile.yaml") -> PilotProfile:
    return load_params(PilotProfile, model_path(filename))


def pilot_model(params: HexacopterParams) -> PilotModel:
    """The pilot's knowledge of the vehicle: mass, thrust curve and vertical drag of its airframe
    model (a SimVehicleConfig's `airframe`)."""
    plant = MultibodyPlant(0.0)
    add_hexacopter(plant, params)
    plant.Finalize()
    frame = airframe(plant, params)
    return PilotModel(mass=frame.mass, curve=frame.thrust_curve,
                      drag_linear=params.drag_linear[2], drag_quadratic=params.drag_quadratic[2])


def add_pilot_onboard(builder, vehicle, profile: PilotProfile, model: PilotModel,
                      stop_at: float | None = None) -> RunLoggers:
    """The onboard side of `alight hover` on `vehicle`'s ports (simulated or MAVLink): the
    scripted pilot commanding it, and the run logging."""
    pilot = builder.AddNamedSystem("pilot", ScriptedPilot(profile, model, stop_at=stop_at))
    builder.Connect(pilot.GetOutputPort("fc_command"), vehicle.GetInputPort("fc_command"))
    return add_run_logging(builder, vehicle, pilot.GetOutputPort("fc_command"))
