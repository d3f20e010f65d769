"""The F550-class hexacopter model: SDF rigid body plus rotor, motor and drag parameters (YAML).

`add_hexacopter` loads the SDF into a MultibodyPlant; `propeller_infos` gives Drake `Propeller`
the six rotors with alternating spin; `airframe` is what a configured flight controller knows about
the vehicle (geometry, inertia, thrust curve).
"""
import dataclasses as dc

import numpy as np
from pydrake.math import RigidTransform
from pydrake.multibody.parsing import Parser
from pydrake.multibody.plant import MultibodyPlant, PropellerInfo

from alight.models import model_path
from alight.systems.params import ConfigError, bounded, choice, load_params
from alight.systems.thrust_curve import ThrustCurve


@dc.dataclass
class RotorParams:
    name: str = ""
    xyz: list[float] = bounded([0.0, 0.0, 0.0], -2.0, 2.0, "m")  # rotor centre in B
    spin: str = choice("ccw", "cw")  # seen from above


@dc.dataclass
class HexacopterParams:
    sdf: str = "hexacopter_f550.sdf"
    body: str = "base_link"
    max_thrust: float = bounded(9.0, 0.1, 200.0, "N")       # per rotor at full ESC command
    time_constant: float = bounded(0.035, 0.001, 1.0, "s")  # first-order motor response
    idle: float = bounded(0.1, 0.0, 0.5)                    # rotor-speed fraction at zero command
    moment_ratio: float = bounded(0.016, 0.0, 0.2, "m")     # reaction moment / thrust
    drag_linear: list[float] = bounded([0.25, 0.25, 0.35], 0.0, 20.0, "N/(m/s)")
    drag_quadratic: list[float] = bounded([0.06, 0.06, 0.15], 0.0, 20.0, "N/(m/s)^2")
    rotors: list[RotorParams] = dc.field(default_factory=list)
    # The landing legs: collision geometries of `body` in the SDF (their contacts judge a landing).
    legs: list[str] = dc.field(default_factory=lambda: ["foot_1", "foot_2", "foot_3", "foot_4"])
    # Structural limit of one leg: the largest normal force it withstands (hexacopter_f550.yaml).
    max_leg_force: float = bounded(180.0, 1.0, 1e5, "N")


def load_hexacopter_params(filename: str = "hexacopter_f550.yaml") -> HexacopterParams:
    params = load_params(HexacopterParams, model_path(filename))
    if len(params.rotors) < 4:
        raise ConfigError(f"{model_path(filename)}: key 'rotors' needs at least 4 rotors, "
                          f"got {len(params.rotors)}")
    return params


@dc.dataclass(frozen=True)
class Airframe:
    """What a flight controller configured for this vehicle knows (PX4's airframe + tuning)."""
    p_BR: np.ndarray          # (n, 3) rotor positions in B [m]
    yaw_moment: np.ndarray    # (n,) reaction moment about z_B per newton of thrust [m]
    max_thrust: float         # per rotor [N]
    idle: float
    inertia: np.ndarray       # (3,) principal moments of inertia [kg m^2]
    mass: float               # [kg]

    @property
    def num_rotors(self) -> int:
        return len(self.yaw_moment)

    @property
    def thrust_curve(self) -> ThrustCurve:
        """Collective curve M(32)-(34) of all rotors."""
        return ThrustCurve.from_rotors(self.num_rotors, self.max_thrust, self.idle)

    @property
    def rotor_curve(self) -> ThrustCurve:
        """ESC command -> thrust of one rotor."""
        return ThrustCurve.from_rotors(1, self.max_thrust, self.idle)

    @property
    def min_thrust(self) -> float:
        """Thrust of one armed rotor at zero command (idle spin) [N]."""
        return self.max_thrust * self.idle**2


def add_hexacopter(plant: MultibodyPlant, params: HexacopterParams):
    """Adds the hexacopter model to `plant` (before Finalize); returns its model instance."""
    (instance,) = Parser(plant).AddModels(str(model_path(params.sdf)))
    return instance


def _yaw_moments(params: HexacopterParams) -> np.ndarray:
    # A rotor spinning counter-clockwise seen from above pushes the body clockwise (-z_B).
    return np.array([-params.moment_ratio if r.spin == "ccw" else params.moment_ratio
                     for r in params.rotors])


def propeller_infos(plant: MultibodyPlant, params: HexacopterParams) -> list[PropellerInfo]:
    """Drake `Propeller` entries: command = rotor thrust [N], alternating reaction moments."""
    body = plant.GetBodyByName(params.body)
    return [PropellerInfo(body.index(), RigidTransform(np.array(r.xyz)), 1.0, k)
            for r, k in zip(params.rotors, _yaw_moments(params))]


def airframe(plant: MultibodyPlant, params: HexacopterParams) -> Airframe:
    """The flight controller's view of the vehicle, read from the finalized plant and params."""
    body = plant.GetBodyByName(params.body)
    spatial_inertia = body.default_spatial_inertia()
    inertia = spatial_inertia.CalcRotationalInertia().CopyToFullMatrix3()
    return Airframe(p_BR=np.array([r.xyz for r in params.rotors]), yaw_moment=_yaw_moments(params),
                    max_thrust=params.max_thrust, idle=params.idle,
                    inertia=np.diag(inertia).copy(), mass=body.default_mass())
