"""The controller role of the control manager, M Sec. 7.2, written once (as the MRS controller
interface: activate with the last command, update while active or inactive, switch the odometry
source).

The manager makes one controller active at a time (its `active` input) and only that one
computes. At its first active tick a controller starts from `last_command`, the command the
manager issued last (M Sec. 7.2: "the newly activated plugin is given the last state and result of
the previously-active plugin", so that the switch is imperceptible). When the state estimate's
`frame_counter` changes (the arbiter switched estimator frames, M Sec. 3.5), the states a
controller keeps in the estimator frame are re-expressed in the new one.

Also here: what the manager reads of every controller (`ControllerReason`, `status_vector`,
`command_is_usable`, `controller_failed`) and the safe level command (`level_command`).
"""
import enum
import time

import numpy as np
from pydrake.systems.framework import LeafSystem

from alight.systems.boundary import (CONTROLLER_STATUS, FC_COMMAND, REFERENCE, STATE_ESTIMATE,
                                     CommandMode, estimate_is_valid)
from alight.systems.estimation.frames import frame_switch
from alight.systems.rotations import all_finite, heading_quaternion
from alight.systems.timing import ComputeTimer

_FRAME_COUNTER = STATE_ESTIMATE.slice("frame_counter").start
_THRUST = FC_COMMAND.slice("thrust").start


class ControllerReason(enum.IntEnum):
    """`controller_status.reason` of the flight-stack controllers; the manager reads INACTIVE."""
    OK = 0
    INACTIVE = 1
    BAD_ESTIMATE = 2      # estimate invalid or not finite
    BAD_REFERENCE = 3     # reference not finite
    SOLVER_FALLBACK = 4   # the QP failed; the previous solution is used (still valid)
    SOLVER_FAILED = 5     # the QP failed for too long
    NOT_FINITE = 6        # the computation gave a non-finite command
    TOUCHDOWN = 7         # failsafe: on the ground, disarming


VALID_REASONS = (ControllerReason.OK, ControllerReason.SOLVER_FALLBACK, ControllerReason.TOUCHDOWN)


def status_vector(reason: ControllerReason, solver_status: float = 0.0) -> np.ndarray:
    return CONTROLLER_STATUS.pack(valid=float(reason in VALID_REASONS), reason=float(reason),
                                  solver_status=solver_status)


# what an inactive controller reports at every tick (set_value copies it)
_INACTIVE_STATUS = status_vector(ControllerReason.INACTIVE)
_INACTIVE_STATUS.setflags(write=False)


def level_command(stamp: float, eta: float, thrust: float, arm: float) -> np.ndarray:
    """Level attitude at heading `eta` with `thrust`: the safe command of a tick that cannot
    compute, and the failsafe's command (M Sec. 5.10)."""
    return FC_COMMAND.pack(stamp=stamp, mode=CommandMode.ATTITUDE_THRUST,
                           q_WD=heading_quaternion(eta), w_D=np.zeros(3),
                           thrust=float(np.clip(thrust, 0.0, 1.0)), arm=arm)


def command_is_usable(command: np.ndarray) -> bool:
    """A finite FC_COMMAND with thrust in [0, 1] (what a controller may start from)."""
    return bool(all_finite(command) and 0.0 <= command[_THRUST] <= 1.0)


def controller_failed(status: np.ndarray, command: np.ndarray) -> bool:
    """What makes the control manager fall back to the failsafe (M Sec. 7.2): `valid = 0` on a
    computing controller's CONTROLLER_STATUS (INACTIVE: it has not computed yet), or a command
    that is not usable (`command_is_usable`: NaN or infinite anywhere, thrust out of [0, 1])."""
    # (the reason as a Python float: a NumPy scalar compared with an IntEnum takes ~10 us)
    refused = CONTROLLER_STATUS.get(status, "valid") < 0.5 \
        and float(CONTROLLER_STATUS.get(status, "reason")) != ControllerReason.INACTIVE
    return bool(refused or not command_is_usable(command))


class Controller(LeafSystem):
    """The controller contract of alight.systems.boundary (CONTROLLER_INPUTS, CONTROLLER_OUTPUTS).

    Inputs  `state_estimate` STATE_ESTIMATE (frame E, z up); `reference` REFERENCE (chi of M(16),
            in E); `active` (1: compute this tick); `last_command` FC_COMMAND (the command the
            manager issued last, whichever controller computed it)
    Outputs `fc_command` FC_COMMAND (never NaN, thrust in [0, 1]); `controller_status`
            CONTROLLER_STATUS (both state: the manager reads them at the tick)
    Updated every `period`. Inactive: `_update_inactive` (status INACTIVE, the command held).
    Active, timed by `compute_timer` (alight.systems.timing): `_activate` at the first active
    tick, `_switch_frame` when a valid estimate comes in a new frame, then `_update_active`.
    Subclasses implement `_update_active` and may declare more ports and state.
    """

    def __init__(self, period: float, initial_command: np.ndarray):
        super().__init__()
        self.compute_timer = ComputeTimer()
        self._period = period
        self._estimate = self.DeclareVectorInputPort("state_estimate", STATE_ESTIMATE.size)
        self._reference = self.DeclareVectorInputPort("reference", REFERENCE.size)
        self._active = self.DeclareVectorInputPort("active", 1)
        self._last = self.DeclareVectorInputPort("last_command", FC_COMMAND.size)
        self._command = self.DeclareDiscreteState(initial_command)
        self._status = self.DeclareDiscreteState(status_vector(ControllerReason.INACTIVE))
        # [1 while active, the frame counter of the estimator frame the states are in (NaN: none)]
        self._role = self.DeclareDiscreteState([0.0, np.nan])
        self._role_group = int(self._role)  # (pydrake converts a DiscreteStateIndex per call)
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._tick)
        self.DeclareStateOutputPort("fc_command", self._command)
        self.DeclareStateOutputPort("controller_status", self._status)

    @property
    def period(self) -> float:
        return self._period

    # --- the role's hooks ---------------------------------------------------------------------

    def _activate(self, context, discrete_state, last_command: np.ndarray, estimate) -> None:
        """The first active tick: start from `last_command` (as issued: see `command_is_usable`).
        `estimate` is None when it is not valid."""

    def _update_active(self, context, discrete_state, estimate) -> None:
        """This tick's `fc_command` and `controller_status` (and the subclass's own state).
        `estimate` is None when it is not valid."""
        raise NotImplementedError

    def _update_inactive(self, context, discrete_state) -> None:
        """A tick while another controller flies: status INACTIVE, the command held."""
        discrete_state.set_value(self._status, _INACTIVE_STATUS)

    def _switch_frame(self, context, discrete_state, R_OldNew: np.ndarray,
                      p_OldNew: np.ndarray) -> None:
        """Re-expresses the states kept in the estimator frame in the new frame (M Sec. 3.5);
        nothing to do for a controller that keeps none."""

    # --- the tick -----------------------------------------------------------------------------

    def _tick(self, context, discrete_state):
        role = context.get_discrete_state().get_value(self._role_group)
        was_active, frame_counter = role.tolist()
        if self._active.Eval(context)[0] < 0.5:
            if was_active != 0.0:   # (else the role is unchanged: `discrete_state` holds it)
                discrete_state.set_value(self._role_group, np.array([0.0, frame_counter]))
            return self._update_inactive(context, discrete_state)
        estimate = self._estimate.Eval(context)
        estimate = estimate if estimate_is_valid(estimate) else None
        # (compute_timer.measure, inline: the same clock and record, without the generator)
        stamp, start = context.get_time(), time.perf_counter()
        try:
            if was_active < 0.5:
                self._activate(context, discrete_state, self._last.Eval(context), estimate)
                frame_counter = np.nan
            elif estimate is not None and (switch := frame_switch(estimate, frame_counter)):
                self._switch_frame(context, discrete_state, *switch)
            if estimate is not None:
                frame_counter = float(estimate[_FRAME_COUNTER])
            if was_active != 1.0 or frame_counter != role[1]:  # (else the role is unchanged)
                discrete_state.set_value(self._role_group, np.array([1.0, frame_counter]))
            self._update_active(context, discrete_state, estimate)
        finally:
            self.compute_timer.record(stamp, "tick", time.perf_counter() - start)
