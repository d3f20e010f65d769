"""The quadratic thrust curve M(32)-(34): normalized thrust T in [0, 1] <-> thrust force f.

    T = a_t sqrt(f) + b_t          M(32), and M(33) with f = m g at hover
    m_a = ((T - b_t) / a_t)^2 / g  M(34), the apparent mass

With rotor speed linear in the ESC command between an idle fraction and full speed, and thrust
proportional to rotor speed squared, f = f_max (idle + (1 - idle) T)^2 per rotor; n equal rotors
give the curve with a_t = 1 / ((1 - idle) sqrt(n f_max)) and b_t = -idle / (1 - idle).
"""
import dataclasses as dc
import math

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
        if isinstance(force, float):
            return np.float64(self.thrust_floats([float(force)])[0])
        return np.minimum(np.maximum(self.a_t * np.sqrt(np.maximum(force, 0.0)) + self.b_t, 0.0),
                          1.0)

    def force(self, thrust):
        """Inverse of M(32): thrust force [N] for a normalized thrust in [0, 1]."""
        if isinstance(thrust, float):
            return np.float64(self.force_floats([float(thrust)])[0])
        root = (np.minimum(np.maximum(thrust, 0.0), 1.0) - self.b_t) / self.a_t
        return root * root

    # The same IEEE operations on Python floats, for scalars and per-tick short vectors: NumPy's
    # per-call overhead dominates there. As np.maximum(x, 0.0) and np.minimum(x, 1.0), the clips
    # keep NaN and give the bound when x equals it (-0.0 -> 0.0).
    def thrust_floats(self, forces) -> list[float]:
        """`thrust` of each float of `forces`, as floats."""
        thrusts = []
        for f in forces:
            t = self.a_t * math.sqrt(f if f > 0.0 or f != f else 0.0) + self.b_t
            t = t if t > 0.0 or t != t else 0.0
            thrusts.append(t if t < 1.0 or t != t else 1.0)
        return thrusts

    def force_floats(self, thrusts) -> list[float]:
        """`force` of each float of `thrusts`, as floats."""
        forces = []
        for t in thrusts:
            t = t if t > 0.0 or t != t else 0.0
            root = ((t if t < 1.0 or t != t else 1.0) - self.b_t) / self.a_t
            forces.append(root * root)
        return forces

    def apparent_mass(self, thrust, g: float = GRAVITY):
        """M(34): the mass that the normalized thrust would hold in hover [kg]."""
        return self.force(thrust) / g
