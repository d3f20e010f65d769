"""The ground: a half-space with contact friction, seen by cameras or hidden from them."""
import numpy as np
from pydrake.geometry import (AddContactMaterial, GeometryInstance, HalfSpace,
                              IllustrationProperties, ProximityProperties, Rgba)
from pydrake.math import RigidTransform
from pydrake.multibody.plant import CoulombFriction


def add_ground(plant, friction: float, perceived: bool = True):
    """The ground half-space; `perceived=False` hides it from cameras (a textured ground is seen)."""
    properties = ProximityProperties()
    AddContactMaterial(friction=CoulombFriction(friction, friction), properties=properties)
    properties.AddProperty("material", "relaxation_time", 0.0)  # rigid: the legs are compliant
    plant.RegisterCollisionGeometry(plant.world_body(), RigidTransform(), HalfSpace(), "ground",
                                    properties)
    colour = np.array([0.45, 0.55, 0.4, 1.0])
    if perceived:
        plant.RegisterVisualGeometry(plant.world_body(), RigidTransform(), HalfSpace(), "ground",
                                     colour)
        return
    instance = GeometryInstance(RigidTransform(), HalfSpace(), "ground")
    illustration = IllustrationProperties()
    illustration.AddProperty("phong", "diffuse", Rgba(*colour))
    instance.set_illustration_properties(illustration)
    plant.RegisterVisualGeometry(plant.world_body(), instance)
