"""A motor fault of the simulated airframe (issue 21's fault campaign): from `time` on, rotor
`rotor` delivers only (1 - `loss`) of the thrust its ESC command asks for (a damaged propeller,
a weak motor or ESC). It sits between the first-order motors and Drake's `Propeller`, so the
flight controller's mixer and everything onboard see it only through the vehicle's motion."""
import dataclasses as dc

import numpy as np
from pydrake.systems.framework import LeafSystem

from alight.systems.params import bounded


@dc.dataclass
class MotorFaultParams:
    loss: float = bounded(0.0, 0.0, 1.0)          # fraction of the thrust lost, 0: no fault
    rotor: int = bounded(0, 0, 11)                # which rotor (the airframe's order)
    time: float = bounded(0.0, 0.0, 1e6, "s")     # from this time on

    @property
    def active(self) -> bool:
        return self.loss > 0.0


class MotorFault(LeafSystem):
    """Input `thrust` (n) rotor thrusts [N]; output `thrust` (n), rotor `rotor`'s scaled by
    1 - `loss` from `time` on."""

    def __init__(self, num_rotors: int, params: MotorFaultParams):
        super().__init__()
        if not 0 <= params.rotor < num_rotors:
            raise ValueError(f"motor fault: rotor {params.rotor} does not exist (the airframe "
                             f"has rotors 0..{num_rotors - 1})")
        self._p = params
        self._scale = np.ones(num_rotors)
        self._scale[params.rotor] = 1.0 - params.loss
        self._thrust = self.DeclareVectorInputPort("thrust", num_rotors)
        self.DeclareVectorOutputPort("thrust", num_rotors, self._calc)

    def _calc(self, context, output):
        thrust = self._thrust.Eval(context)
        output.SetFromVector(thrust * self._scale if context.get_time() >= self._p.time
                             else thrust)
