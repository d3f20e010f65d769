"""Wind: a mean horizontal wind plus Ornstein-Uhlenbeck gusts (a first-order, Dryden-like forming
filter on white noise), sampled at `period`. The noise comes from a Drake `RandomSource`, so the
gusts are reproducible from the diagram's seed (`Diagram.SetRandomContext`)."""
import dataclasses as dc

import numpy as np
from pydrake.systems.framework import LeafSystem

from alight.systems.params import bounded


@dc.dataclass
class WindParams:
    mean_speed: float = bounded(0.0, 0.0, 30.0, "m/s")  # 15 km/h = 4.17 m/s (L Sec. 7)
    direction: float = bounded(0.0, -360.0, 360.0, "deg")  # blowing toward, from x_W, CCW
    gust_std: float = bounded(0.0, 0.0, 10.0, "m/s")   # horizontal gust standard deviation
    vertical_gust_std: float = bounded(0.0, 0.0, 10.0, "m/s")
    correlation_time: float = bounded(2.0, 0.05, 100.0, "s")
    period: float = bounded(0.01, 0.001, 1.0, "s")

    @property
    def mean_velocity(self) -> np.ndarray:
        heading = np.radians(self.direction)
        return self.mean_speed * np.array([np.cos(heading), np.sin(heading), 0.0])


class Wind(LeafSystem):
    """Input  `noise` (3) unit white Gaussian noise, resampled every `period`
    Output `wind`  (3) air velocity v_WA [m/s, in W] = mean + gusts
    State: the gust velocity (3), an exact discretization of d(g) = -g/tau dt + sigma sqrt(2/tau) dW,
    and the output (3) kept with it (a state output port: no Python call when read).
    """

    def __init__(self, params: WindParams):
        super().__init__()
        self._mean = params.mean_velocity
        self._decay = np.exp(-params.period / params.correlation_time)
        self._drive = np.array([params.gust_std, params.gust_std, params.vertical_gust_std]) \
            * np.sqrt(1.0 - self._decay**2)
        self._noise = self.DeclareVectorInputPort("noise", 3)
        self._gust = self.DeclareDiscreteState(3)
        self._wind = self.DeclareDiscreteState(self._mean + np.zeros(3))
        # (pydrake converts a DiscreteStateIndex per call: the update takes ints)
        self._groups = (int(self._gust), int(self._wind))
        self.DeclarePeriodicDiscreteUpdateEvent(params.period, 0.0, self._update)
        self.DeclareStateOutputPort("wind", self._wind)

    def _update(self, context, discrete_state):
        # `discrete_state` holds the current state on entry (Drake copies it in): updated in place.
        gust = discrete_state.get_mutable_value(self._groups[0])
        gust[:] = self._decay * gust + self._drive * self._noise.Eval(context)
        discrete_state.get_mutable_value(self._groups[1])[:] = self._mean + gust
