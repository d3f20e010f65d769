"""A scripted reference for experiments and tests: p(t), v(t) (and a(t)) from a function of time.

Outputs a REFERENCE (position, velocity, the acceleration when the function gives one; zero jerk
and heading) and an arm
request [arm, armed-after-idle] that arms first and lets the controller lift off after 0.5 s.
"""
from collections.abc import Callable

import numpy as np
from pydrake.systems.framework import LeafSystem

from alight.systems.boundary import REFERENCE


class ScriptedReference(LeafSystem):
    """Output `reference` REFERENCE from `fn(t) -> (p_W, v_W)` or `(p_W, v_W, a_W)`; output
    `arm` (2)."""

    def __init__(self, fn: Callable[[float], tuple[np.ndarray, ...]],
                 idle_time: float = 0.5):
        super().__init__()
        self._fn = fn
        self.DeclareVectorOutputPort("reference", REFERENCE.size, self._calc)
        self.DeclareVectorOutputPort("arm", 2, lambda c, o: o.SetFromVector(
            [1.0, float(c.get_time() > idle_time)]))

    def _calc(self, context, output):
        p, v, *a = self._fn(context.get_time())
        output.SetFromVector(REFERENCE.pack(stamp=context.get_time(), p=p, v=v,
                                            a=a[0] if a else np.zeros(3),
                                            j=np.zeros(3), heading=0.0, heading_rate=0.0))
