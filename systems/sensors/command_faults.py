"""A fault injector between a controller and its consumers (simulation only): within
[`start`, `start` + `duration`) the controller's FC_COMMAND is replaced by garbage, as a
controller bug would emit it (issue 21's fault campaign):
- `nan`: every field NaN;
- `out_of_range`: thrust `1 + thrust_excess` (beyond [0, 1]), the reference quaternion scaled
  by 3 (not a rotation) and 50 rad/s reference rates, stamp and arm unchanged.
What a stack must do with it (DESIGN.md "no NaN or infinite value ever leaves a controller"):
never forward it to the vehicle, and fall back to the failsafe (M Sec. 5.10, 7.2).
Not onboard code: it models a broken controller."""
import dataclasses as dc

import numpy as np
from pydrake.systems.framework import LeafSystem

from alight.systems.boundary import FC_COMMAND
from alight.systems.params import bounded, choice


@dc.dataclass
class CommandFaultParams:
    kind: str = choice("none", "nan", "out_of_range")
    start: float = bounded(0.0, 0.0, 1e6, "s")
    duration: float = bounded(1.0, 0.0, 1e6, "s")
    thrust_excess: float = bounded(1.0, 0.0, 100.0)     # out_of_range: thrust 1 + this

    @property
    def active(self) -> bool:
        return self.kind != "none"


def faulty_command(command: np.ndarray, params: CommandFaultParams) -> np.ndarray:
    """`command` as the fault `params.kind` garbles it."""
    if params.kind == "nan":
        return np.full_like(command, np.nan)
    garbled = command.copy()
    garbled[FC_COMMAND.slice("thrust")] = 1.0 + params.thrust_excess
    garbled[FC_COMMAND.slice("q_WD")] *= 3.0
    garbled[FC_COMMAND.slice("w_D")] = 50.0
    return garbled


class CommandFaults(LeafSystem):
    """Input `fc_command` FC_COMMAND from a controller; output `fc_command` FC_COMMAND, garbled
    (`faulty_command`) within the fault's window."""

    def __init__(self, params: CommandFaultParams):
        super().__init__()
        if not params.active:
            raise ValueError("CommandFaults needs a fault kind ('nan' or 'out_of_range')")
        self._p = params
        self._command = self.DeclareVectorInputPort("fc_command", FC_COMMAND.size)
        self.DeclareVectorOutputPort("fc_command", FC_COMMAND.size, self._calc)

    def _calc(self, context, output):
        command = self._command.Eval(context)
        t = context.get_time()
        within = self._p.start <= t < self._p.start + self._p.duration
        output.SetFromVector(faulty_command(command, self._p) if within else command)


class LinkLoss(LeafSystem):
    """The command link of the simulated vehicle losing messages (a MAVLink link loss, simulation
    only): within each window [(start, end), ...] [s] the flight controller keeps receiving the
    last command that got through before it, so its stamp goes stale and the flight controller's
    own stale-command failsafe acts (PX4's offboard loss, systems/autopilot/commander.py).
    Input `fc_command` FC_COMMAND as sent; output `fc_command` FC_COMMAND as received. The
    command getting through is sampled every `period` [s]."""

    def __init__(self, windows, period: float = 0.002):
        super().__init__()
        self._windows = np.asarray(windows, float).reshape(-1, 2)
        if not np.all(np.isfinite(self._windows)) or np.any(self._windows[:, 1]
                                                            < self._windows[:, 0]):
            raise ValueError(f"link loss windows must be finite (start, end) pairs, got "
                             f"{windows!r}")
        self._command = self.DeclareVectorInputPort("fc_command", FC_COMMAND.size)
        self._received = self.DeclareDiscreteState(np.full(FC_COMMAND.size, np.nan))
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._update)
        self.DeclareVectorOutputPort("fc_command", FC_COMMAND.size, self._calc,
                                     {self.all_input_ports_ticket(), self.all_state_ticket(),
                                      self.time_ticket()})

    def _lost(self, t: float) -> bool:
        return bool(np.any((self._windows[:, 0] <= t) & (t < self._windows[:, 1])))

    def _update(self, context, discrete_state):
        if not self._lost(context.get_time()):
            discrete_state.set_value(self._received, self._command.Eval(context))

    def _calc(self, context, output):
        held = context.get_discrete_state(self._received).get_value()
        output.SetFromVector(held if self._lost(context.get_time()) and np.all(np.isfinite(held))
                             else self._command.Eval(context))
