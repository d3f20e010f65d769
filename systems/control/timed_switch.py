"""A timed controller switch for experiments: controller i is active from `start_times[i]` until
the next start. It stands in for the control manager (M Sec. 7.2) in the `alight track`
experiments and in tests until the manager exists, and follows the same activation contract.

The selection is sampled state, updated every `period` together with the controllers: at a switch
time the newly active controller still reads, as `last_command`, the command the previous one
issued (the selection changes in the same update), then its own from the next tick on.
"""
import numpy as np
from pydrake.systems.framework import LeafSystem

from alight.systems.boundary import FC_COMMAND


class TimedSwitch(LeafSystem):
    """Inputs  `fc_command_0` ... `fc_command_{n-1}` FC_COMMAND of the controllers
    Outputs `fc_command` FC_COMMAND of the selected controller (also every controller's
            `last_command`); `active_0` ... `active_{n-1}` (1) from the time alone; `selected` (1)
    """

    def __init__(self, start_times: list[float], period: float = 0.01):
        super().__init__()
        if not start_times or start_times[0] != 0.0 or np.any(np.diff(start_times) < 0):
            raise ValueError(f"start times must begin at 0 and not decrease: {start_times}")
        self._starts = np.asarray(start_times, dtype=float)
        self._inputs = [self.DeclareVectorInputPort(f"fc_command_{i}", FC_COMMAND.size)
                        for i in range(len(start_times))]
        self._selected = self.DeclareDiscreteState(1)
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._update)
        self.DeclareVectorOutputPort("fc_command", FC_COMMAND.size, self._calc_command)
        for i in range(len(start_times)):
            self.DeclareVectorOutputPort(f"active_{i}", 1,
                                         lambda context, output, i=i: output.SetFromVector(
                                             [float(self.index_at(context.get_time()) == i)]),
                                         prerequisites_of_calc={self.time_ticket()})
        self.DeclareStateOutputPort("selected", self._selected)

    def index_at(self, t: float) -> int:
        return int(np.searchsorted(self._starts, t, side="right") - 1)

    def _update(self, context, discrete_state):
        discrete_state.set_value(self._selected, [self.index_at(context.get_time())])

    def _calc_command(self, context, output):
        selected = int(context.get_discrete_state(self._selected).get_value()[0])
        output.SetFromVector(self._inputs[selected].Eval(context))
