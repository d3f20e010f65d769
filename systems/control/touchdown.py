"""Touchdown detection from the issued thrust, M(34): on the ground the controllers keep pushing
the reference below the vehicle, the thrust they issue drops, and the apparent mass of that
thrust (on its tilt) stays under a fraction of the vehicle's mass. Used by the control manager's
emergency landing and by the landoff tracker's landing (M Sec. 4.2)."""
import math

import numpy as np

from alight.systems.boundary import FC_COMMAND
from alight.systems.control.force_controller import VehicleModel
from alight.systems.rotations import unit_floats

_THRUST, _Q_WD = FC_COMMAND.slice("thrust").start, FC_COMMAND.slice("q_WD")


def apparent_mass(command: np.ndarray, vehicle: VehicleModel) -> float:
    """M(34): the mass [kg] the issued thrust of `command` (FC_COMMAND) would hold in hover, times
    the cosine of its tilt; 0 for zero thrust, NaN for a command that is not finite (never
    light)."""
    # On the elements as floats (this runs at every tick of the failsafe and the managers):
    # R_WD[2, 2] by the operations of rotation_matrix(q_WD)[2, 2].
    thrust = float(command[_THRUST])
    w, x, y, z = command[_Q_WD].tolist()
    if not (math.isfinite(thrust) and math.isfinite(w) and math.isfinite(x)
            and math.isfinite(y) and math.isfinite(z)
            and math.sqrt(w * w + x * x + y * y + z * z) > 0.5):
        return float("nan")
    if thrust <= 0.0:
        return 0.0
    _, x, y, _ = unit_floats(w, x, y, z)
    return float(vehicle.curve.apparent_mass(thrust)) * (1 - 2 * (x * x + y * y))


def light_time(previous: float, command: np.ndarray, vehicle: VehicleModel, fraction: float,
               period: float) -> float:
    """How long [s] the issued thrust has stayed light (apparent mass under `fraction` of the
    vehicle's mass), one `period` after `previous`; 0 when it is not light."""
    light = apparent_mass(command, vehicle) < fraction * vehicle.mass
    return previous + period if light else 0.0
