"""The quadratic thrust curve M(32)-(34): normalized thrust T in [0, 1] <-> thrust force f.

    T = a_t sqrt(f) + b_t          M(32), and M(33) with f = m g at hover
    m_a = ((T - b_t) / a_t)^2 / g  M(34), the apparent mass

With rotor speed linear in the ESC command between an idle fraction and full speed, and thrust
proportional to rotor speed squared, f = f_max (idle + (1 - idle) T)^2 per rotor; n equal rotors
give the curve with a_t = 1 / ((1 - idle) sqrt(n f_max)) and b_t = -idle / (1 - idle).
"""
import dataclasses as dc

import numpy as np

GRAVITY = 9.81


@dc.dataclass(frozen=True)
class ThrustCurve:
    a_t: float
    b_t: float

    @staticmethod
    def from_rotors(num_rotors: int, max_thrust: float, idle: float) -> "ThrustCurve":
        """The curve of `num_rotors` rotors of `max_thrust` [N] each sharing one command."""
        return ThrustCurve(a_t=1.0 / ((1.0 - idle) * np.sqrt(num_rotors * max_thrust)),
                           b_t=-idle / (1.0 - idle))

    def thrust(self, force):
        """M(32): normalized thrust for a thrust force [N] (clipped to [0, 1])."""
        return np.minimum(np.maximum(self.a_t * np.sqrt(np.maximum(force, 0.0)) + self.b_t, 0.0),
                          1.0)

    def force(self, thrust):
        """Inverse of M(32): thrust force [N] for a normalized thrust in [0, 1]."""
        root = (np.minimum(np.maximum(thrust, 0.0), 1.0) - self.b_t) / self.a_t
        return root * root

    def apparent_mass(self, thrust, g: float = GRAVITY):
        """M(34): the mass that the normalized thrust would hold in hover [kg]."""
        return self.force(thrust) / g
