"""Level touchdown: the attitude command made level for the last decimetres of Landing Phase 2.

L Sec. 6.4 descends in Phase 2 at 1.8 m/s (L Table 2) and switches the motors off at
z_SuccessfulLandingOffset, i.e. at the touchdown; the MPC (L Sec. 6.2) meanwhile holds the
vehicle against the air flowing over the moving platform, tilted by atan(drag / weight): 12 deg in
7 m/s of relative air (car 3 m/s, wind 15 km/h). Touching down at that tilt puts the whole impact
on the upwind legs: their off-centre impulse spins the light airframe (I_xx 0.042 kg m^2, legs
0.21 m out) through level and, disarmed, it tips over (docs/landing.md "Touchdown attitude").
Levelled for the last `height` above the platform (a few tenths of a second at 1.8 m/s, the
attitude loop's response), the four legs meet the platform together; the drift that the wind
adds meanwhile (drag / mass ~2 m/s^2) is a few centimetres at 3 m/s, 13 cm at 5 m/s, which the
landing mission's descending reference leads (reference_generator.level_lead).
"""
import dataclasses as dc

import numpy as np
from pydrake.systems.framework import LeafSystem

from alight.systems.boundary import FC_COMMAND, STATE_ESTIMATE, TARGET_ESTIMATE, CommandMode
from alight.systems.mission.landing import MISSION_STATUS, Mode
from alight.systems.params import bounded
from alight.systems.rotations import heading, heading_quaternion, rotation_matrix


# what `levelling` reads at every tick, by index; the modes as floats (a NumPy scalar compared
# with an IntEnum takes ~10 us)
_MODE = MISSION_STATUS.slice("mode").start
_LEVELLED_MODES = (float(Mode.LANDING_P2), float(Mode.LANDED))
_Z_EB = STATE_ESTIMATE.slice("p_EB").start + 2
_Z_WT, _VALID = TARGET_ESTIMATE.slice("p_WT").start + 2, TARGET_ESTIMATE.slice("valid").start


@dc.dataclass
class TouchdownLevelParams:
    # CoM above the target [m] under which Phase 2's attitude command is level (0: never). The
    # legs reach 0.22 m below the CoM (hexacopter_f550.sdf): from 1.0 m, 1.8 m/s (L Table 2)
    # leaves 0.4 s, what the attitude loop needs to take out 10-12 deg (from 0.55 m the flown
    # seed still had 9 deg at contact). models/touchdown_level.yaml.
    height: float = bounded(1.0, 0.0, 5.0, "m")


def level_attitude(command: np.ndarray) -> np.ndarray:
    """`command` (FC_COMMAND) with its attitude level at its own heading, no feed-forward rate,
    as an attitude command (ATTITUDE_THRUST: a RATES_THRUST command of the force controllers,
    M Sec. 5, levelled only in its rates would hold the tilt it has); thrust and arm unchanged."""
    levelled = np.array(command, dtype=float)
    q_WD = FC_COMMAND.get(command, "q_WD")
    levelled[FC_COMMAND.slice("mode")] = CommandMode.ATTITUDE_THRUST
    levelled[FC_COMMAND.slice("q_WD")] = heading_quaternion(heading(rotation_matrix(q_WD)))
    levelled[FC_COMMAND.slice("w_D")] = 0.0
    return levelled


class TouchdownLevel(LeafSystem):
    """Input  `fc_command`      FC_COMMAND from the controller
    Input  `mission_status`  MISSION_STATUS (its `mode`)
    Input  `state_estimate`  STATE_ESTIMATE (p_EB [m])
    Input  `target_estimate` TARGET_ESTIMATE (p_WT [m], `valid`)
    Output `fc_command`      the command, levelled (`level_attitude`) in Landing Phase 2 and
                             Landed while the CoM is under `height` above the target; otherwise
                             unchanged (direct feed-through of the command)
    The decision (`levelling`) is taken every `period` (the command switch's, whose command the
    vehicle receives: at 100 Hz, 1.8 cm of L Table 2's 1.8 m/s descent) and held: the target
    estimate is a prediction to the current time, and a decision taken at every read would make
    the command, and everything the vehicle reads downstream of it, change at every simulator
    step.
    """

    def __init__(self, params: TouchdownLevelParams, period: float):
        super().__init__()
        self._height = params.height
        self._command = self.DeclareVectorInputPort("fc_command", FC_COMMAND.size)
        self._status = self.DeclareVectorInputPort("mission_status", MISSION_STATUS.size)
        self._estimate = self.DeclareVectorInputPort("state_estimate", STATE_ESTIMATE.size)
        self._target = self.DeclareVectorInputPort("target_estimate", TARGET_ESTIMATE.size)
        self._level = self.DeclareDiscreteState(1)   # 1: levelling
        self._level_group = int(self._level)   # (pydrake converts a DiscreteStateIndex per call)
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._update)
        self.DeclareVectorOutputPort("fc_command", FC_COMMAND.size, self._calc,
                                     {self._command.ticket(), self.discrete_state_ticket(
                                         self._level)})

    def levelling(self, context) -> bool:
        """Whether the command is to be levelled from now (the decision of a tick)."""
        mode = float(self._status.Eval(context)[_MODE])
        if self._height <= 0.0 or mode not in _LEVELLED_MODES:
            return False
        target = self._target.Eval(context)
        height = self._estimate.Eval(context)[_Z_EB] - target[_Z_WT]
        return bool(target[_VALID] > 0.5) and height <= self._height

    def _update(self, context, discrete_state):
        discrete_state.set_value(self._level_group, np.array([float(self.levelling(context))]))

    def _calc(self, context, output):
        command = self._command.Eval(context)
        levelled = context.get_discrete_state().get_value(self._level_group)[0] > 0.5
        output.SetFromVector(level_attitude(command) if levelled else command)
