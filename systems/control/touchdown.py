"""Touchdown detection from the issued thrust, M(34): on the ground the controllers keep pushing
the reference below the vehicle, the thrust they issue drops, and the apparent mass of that
thrust (on its tilt) stays under a fraction of the vehicle's mass. Used by the control manager's
emergency landing and by the landoff tracker's landing (M Sec. 4.2)."""
import numpy as np

from alight.systems.boundary import FC_COMMAND
from alight.systems.control.force_controller import VehicleModel
from alight.systems.rotations import rotation_matrix


def apparent_mass(command: np.ndarray, vehicle: VehicleModel) -> float:
    """M(34): the mass [kg] the issued thrust of `command` (FC_COMMAND) would hold in hover, times
    the cosine of its tilt; 0 for zero thrust, NaN for a command that is not finite (never
    light)."""
    thrust = FC_COMMAND.get(command, "thrust")
    q_WD = FC_COMMAND.get(command, "q_WD")
    if not (np.isfinite(thrust) and np.all(np.isfinite(q_WD)) and np.linalg.norm(q_WD) > 0.5):
        return float("nan")
    if thrust <= 0.0:
        return 0.0
    return float(vehicle.curve.apparent_mass(thrust)) * rotation_matrix(q_WD)[2, 2]


def light_time(previous: float, command: np.ndarray, vehicle: VehicleModel, fraction: float,
               period: float) -> float:
    """How long [s] the issued thrust has stayed light (apparent mass under `fraction` of the
    vehicle's mass), one `period` after `previous`; 0 when it is not light."""
    light = apparent_mass(command, vehicle) < fraction * vehicle.mass
    return previous + period if light else 0.0
