"""Adds the vehicle's contact monitor (alight.systems.sensors.contacts) on a finalized plant: its
legs (the airframe's `legs` collision geometries), the target's platform plate, the ground (the
geometry fixed to the world)."""
from pydrake.systems.framework import DiagramBuilder

from alight.systems.params import ConfigError
from alight.systems.plant.hexacopter import HexacopterParams
from alight.systems.sensors.contacts import Contacts

PLATFORM_PLATE = "platform_plate"  # the platform top's collision geometry (target_vehicle.sdf)


def add_contacts(builder: DiagramBuilder, plant, scene_graph, airframe: HexacopterParams,
                 body, platform, period: float):
    """The contact monitor of the vehicle `body` (the platform body `platform`, None if the scene
    has no target), sampled every `period` (a multiple of the plant's step); returns its
    `contacts` output port (CONTACTS layout)."""
    inspector = scene_graph.model_inspector()

    def named(owner) -> dict:
        return {inspector.GetName(g).rpartition("::")[2]: g
                for g in plant.GetCollisionGeometriesForBody(owner)}

    vehicle = named(body)
    unknown = [leg for leg in airframe.legs if leg not in vehicle]
    if unknown:
        raise ConfigError(f"{airframe.sdf}: key 'legs' names {unknown}, not collision geometries "
                          f"of '{airframe.body}' (it has {sorted(vehicle)})")
    plate = [] if platform is None else [named(platform)[PLATFORM_PLATE]]
    contacts = builder.AddNamedSystem("contacts", Contacts(
        legs=[vehicle[leg] for leg in airframe.legs], platform=plate,
        ground=plant.GetCollisionGeometriesForBody(plant.world_body()),
        vehicle=list(vehicle.values()), period=period))
    builder.Connect(plant.get_contact_results_output_port(),
                    contacts.GetInputPort("contact_results"))
    return contacts.GetOutputPort("contacts")
