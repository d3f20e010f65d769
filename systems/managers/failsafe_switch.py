"""The control manager's fallback (M Sec. 7.2) for a stack with one controller and no tracker: the
direct stacks, whose mission drives the landing paper's linear MPC (diagrams/onboard/mpc_loop.py).
It hands over to the feedforward failsafe controller (M Sec. 5.10), as the control manager does
(systems/managers/control_manager.py), for the same causes (`FailsafeCause`):

- no valid state estimate (BAD_ESTIMATE);
- the controller reports `valid = 0` (its estimate, its solver), or its command is not usable:
  NaN or infinite anywhere, thrust out of [0, 1] (BAD_CONTROLLER, `controller_failed`);
- a control error |p_ref - p_EB| over `failsafe_threshold` plus the step allowance plus the
  chase allowance (CONTROL_ERROR): a vehicle that accelerates at `chase_acceleration` after a
  reference moving at v falls v^2 / (2 a) behind it before it is up to speed (issue 23: a car at
  8 m/s, passing the vehicle hovering at the waypoint, led it by 9-10 m, over the fixed 8 m,
  and the failsafe landed the vehicle on the road);
- the flight controller flying its own failsafe descent (`fc_status` mode FAILSAFE_DESCENT: the
  command link was lost, PX4's offboard loss), which no longer obeys the mission's commands
  (FLIGHT_CONTROLLER). Found by the fault campaign (bench/faults.py): the landing mission, not
  knowing, went on to Landing Phase 2 over the car it no longer followed and disarmed 1.1 m over
  the ground (4.2 m/s impact, 281 N on a leg). Without a tracker the mission steps its reference (a waypoint, the target at
  its first detection), and a step is not an error: the part of each change of the reference that
  its own velocity does not explain is added to the allowance, which shrinks at `step_speed`;
  the reference the vehicle takes off to is a step from where it rests.

It watches while the mission flies (its `arm` request [arm, thrust enable] both 1; before the
take-off and after the mission has disarmed nothing is watched). There is no way back: the
failsafe flies until it has landed and disarmed (as the control manager's FAILSAFE).

The switch follows the activation contract of alight.systems.control.controller: the decision is
a function of the inputs and the switch's state at the tick, so `failsafe.active` rises at the tick
of the hand-over, the failsafe controller computes at that tick and reads, as `last_command`, the
command issued last (the switch's output still forwards it until the update). The output never
carries a command that is not usable: such a command is replaced by the last usable one (and the
failsafe takes over at that tick). Its `arm` output is what the arm gate applies: the mission's
request until the hand-over, then [1, 1]: the failsafe owns the vehicle until it has landed and
disarms itself (a mission that judges itself landed from its estimate cannot disarm it in the
air).
"""
import dataclasses as dc
import math

import numpy as np

from alight.systems.boundary import (CONTROLLER_STATUS, FC_COMMAND, FC_STATUS, REFERENCE,
                                     STATE_ESTIMATE, ActiveMode, VectorLayout, estimate_is_valid)
from alight.systems.control.controller import command_is_usable, controller_failed
from alight.systems.control.failsafe import FailsafeParams
from alight.systems.managers.control_manager import (MANAGER_STATUS, CommandSwitch,
                                                     FailsafeCause, ManagerMode)
from alight.systems.params import bounded, param_file
from alight.systems.rotations import all_finite, norm


@dc.dataclass
class FailsafeSwitchParams:
    """The fallback of a direct stack (models/failsafe_switch.yaml)."""
    period: float = bounded(0.01, 0.001, 0.1, "s")      # with the failsafe controller, 100 Hz
    failsafe_threshold: float = bounded(8.0, 0.1, 1000.0, "m")   # control error beyond steps
    step_speed: float = bounded(1.0, 0.01, 100.0, "m/s")   # the allowance for a step shrinks
    # the vehicle's horizontal acceleration behind a moving reference (module text)
    chase_acceleration: float = bounded(3.0, 0.1, 100.0, "m/s^2")
    failsafe: FailsafeParams = param_file(FailsafeParams, "failsafe.yaml")


_STATE = VectorLayout("failsafe_switch_state", [
    ("mode", 1), ("failsafe_cause", 1), ("control_error", 1), ("allowance", 1),
    ("p_ref", 3), ("v_ref", 3), ("t_ref", 1)])   # the reference as last seen changing
_MODE, _FAILSAFE = _STATE.slice("mode").start, float(ManagerMode.FAILSAFE)
# The fields read at every tick, by index (the decision runs at every tick: no layout lookups).
_CAUSE, _ERROR, _ALLOWANCE, _T_REF = (_STATE.slice(field).start for field in (
    "failsafe_cause", "control_error", "allowance", "t_ref"))
_P_REF, _V_REF = _STATE.slice("p_ref"), _STATE.slice("v_ref")
_REFERENCE_P, _REFERENCE_V = REFERENCE.slice("p"), REFERENCE.slice("v")
_REFERENCE_V_XY = slice(_REFERENCE_V.start, _REFERENCE_V.start + 2)
_P_EB = STATE_ESTIMATE.slice("p_EB")
_FC_MODE, _FC_FAILSAFE = FC_STATUS.slice("mode").start, float(ActiveMode.FAILSAFE_DESCENT)
_NO_CAUSE = FailsafeCause.NONE
_STATUS_DEFAULT = MANAGER_STATUS.vector()
_STATUS_ACTIVE, _STATUS_MODE, _STATUS_ERROR, _STATUS_CAUSE, _STATUS_SWITCHES = (
    MANAGER_STATUS.slice(field).start for field in (
        "active", "mode", "control_error", "failsafe_cause", "switches"))


class FailsafeSwitch(CommandSwitch):
    """Inputs  `state_estimate` STATE_ESTIMATE; `reference` REFERENCE (what the controller
            follows); `arm` (2) the mission's [arm, thrust enable]; `fc_status` FC_STATUS of the
            vehicle; `controller.fc_command`
            FC_COMMAND and `controller.controller_status` CONTROLLER_STATUS of the controller;
            `failsafe.fc_command` FC_COMMAND of the failsafe controller
    Outputs `fc_command` FC_COMMAND (the controller's, from the hand-over the failsafe's; never
            unusable: the vehicle's command and both controllers' `last_command`);
            `controller.active`, `failsafe.active` (1); `arm` (2) for the arm gate (the
            mission's request, [1, 1] once in FAILSAFE); `manager_status` MANAGER_STATUS (active
            0 controller / 1 failsafe, mode NORMAL / FAILSAFE, failsafe_cause, control_error,
            switches)
    Updated every `period`.
    """

    def __init__(self, params: FailsafeSwitchParams):
        super().__init__()
        self._p = params
        self._estimate = self.DeclareVectorInputPort("state_estimate", STATE_ESTIMATE.size)
        self._reference = self.DeclareVectorInputPort("reference", REFERENCE.size)
        self._arm = self.DeclareVectorInputPort("arm", 2)
        self._fc_status = self.DeclareVectorInputPort("fc_status", FC_STATUS.size)
        self._commands = [self.DeclareVectorInputPort(f"{name}.fc_command", FC_COMMAND.size)
                          for name in ("controller", "failsafe")]
        self._status = self.DeclareVectorInputPort("controller.controller_status",
                                                   CONTROLLER_STATUS.size)
        self._state = self.DeclareDiscreteState(_STATE.vector(
            mode=ManagerMode.NORMAL, p_ref=np.nan, v_ref=np.nan, t_ref=np.nan))
        self._state_group = int(self._state)   # (pydrake converts a DiscreteStateIndex per call)
        # The `NAME.active` outputs and the update read the decision.
        # The command forwarded reads the state and the two commands only (not the decision).
        everything = self._declare_switching(params.period, {
            self.all_state_ticket(), *(port.ticket() for port in self._commands)})
        self._last_command_group = int(self._last_command)
        for index, name in enumerate(("controller", "failsafe")):
            self.DeclareVectorOutputPort(
                f"{name}.active", 1, lambda context, output, index=index: output.SetAtIndex(
                    0, float(self._failsafe_after(context) == index)), everything)
        self.DeclareVectorOutputPort(
            "arm", 2, lambda context, output: output.SetFromVector(
                [1.0, 1.0] if self._in_failsafe(self._x(context)) else self._arm.Eval(context)),
            {self._arm.ticket(), self.all_state_ticket()})
        self.DeclareVectorOutputPort("manager_status", MANAGER_STATUS.size, self._calc_status,
                                     {self.all_state_ticket()})

    def _x(self, context) -> np.ndarray:
        """The switch's state (do not modify it)."""
        return context.get_discrete_state().get_value(self._state_group)

    @staticmethod
    def _in_failsafe(x: np.ndarray) -> bool:
        return x[_MODE] == _FAILSAFE

    def _failsafe_after(self, context) -> int:
        """1 when the failsafe computes at this tick (0: the controller)."""
        return int(self._in_failsafe(self._decide(context)))

    def _calc_command(self, context, output):
        x = self._x(context)
        command = self._commands[int(self._in_failsafe(x))].Eval(context)
        if not command_is_usable(command):
            command = context.get_discrete_state().get_value(self._last_command_group)
        output.SetFromVector(command)

    def _calc_status(self, context, output):
        # (MANAGER_STATUS.vector(active=, mode=, control_error=, failsafe_cause=, switches=),
        # written by index into a copy of the layout's defaults)
        x = self._x(context)
        failsafe = float(self._in_failsafe(x))
        y = _STATUS_DEFAULT.copy()
        y[_STATUS_ACTIVE] = y[_STATUS_SWITCHES] = failsafe
        y[_STATUS_MODE], y[_STATUS_ERROR], y[_STATUS_CAUSE] = x[_MODE], x[_ERROR], x[_CAUSE]
        output.SetFromVector(y)

    def _update(self, context, discrete_state):
        discrete_state.set_value(self._state_group, self._decide(context))
        x = self._x(context)   # what the output forwards
        command = self._commands[int(self._in_failsafe(x))].Eval(context)
        if command_is_usable(command):
            discrete_state.set_value(self._last_command_group, command)

    def _decide(self, context) -> np.ndarray:
        """The switch's state after this tick (cached; do not modify it)."""
        return self._decision.Eval(context)

    def _compute_decision(self, context) -> np.ndarray:
        """The switch's state after this tick (a function of the inputs and the state)."""
        now = context.get_time()
        x = self._x(context).copy()
        estimate, reference = self._estimate.Eval(context), self._reference.Eval(context)
        arm, thrust_enable = self._arm.Eval(context).tolist()
        flying = arm > 0.5 and thrust_enable > 0.5
        estimate_ok = estimate_is_valid(estimate)
        self._follow_reference(x, reference, now, flying,
                               estimate if estimate_ok else None)
        error = norm(reference[_REFERENCE_P] - estimate[_P_EB]) if estimate_ok else math.nan
        x[_ERROR] = error if math.isfinite(error) else 0.0
        if x[_MODE] == _FAILSAFE or not flying:
            return x
        cause = _NO_CAUSE
        if not estimate_ok:
            cause = FailsafeCause.BAD_ESTIMATE
        elif controller_failed(self._status.Eval(context), self._commands[0].Eval(context)):
            cause = FailsafeCause.BAD_CONTROLLER
        elif not error <= self._p.failsafe_threshold + x[_ALLOWANCE] \
                + self._chase_allowance(reference):
            cause = FailsafeCause.CONTROL_ERROR
        elif self._fc_status.Eval(context)[_FC_MODE] == _FC_FAILSAFE:
            cause = FailsafeCause.FLIGHT_CONTROLLER
        if cause != _NO_CAUSE:
            x[_MODE] = _FAILSAFE
            x[_CAUSE] = cause
        return x

    def _chase_allowance(self, reference: np.ndarray) -> float:
        """v^2 / (2 a): how far a vehicle accelerating at `chase_acceleration` falls behind a
        reference moving horizontally at v before it is up to speed."""
        v_x, v_y = reference[_REFERENCE_V_XY].tolist()   # (v @ v: the same sum, as floats)
        return (v_x * v_x + v_y * v_y) / (2.0 * self._p.chase_acceleration)

    def _follow_reference(self, x: np.ndarray, reference: np.ndarray, now: float, flying: bool,
                          estimate) -> None:
        """The step allowance: grown by each change of the reference that its last velocity does
        not explain, shrunk at `step_speed`. Until the take-off the vehicle's own position (the
        `estimate`, None when not valid) stands for the last reference: the reference it takes
        off to is a step too."""
        if not flying or not all_finite(x[_P_REF]):
            x[_P_REF] = np.nan if estimate is None else estimate[_P_EB]
            x[_V_REF], x[_T_REF], x[_ALLOWANCE] = 0.0, now, 0.0
            if not flying:
                return
        p = reference[_REFERENCE_P]
        allowance = max(0.0, x[_ALLOWANCE] - self._p.step_speed * self._p.period)
        changed = any(a != b for a, b in zip(p.tolist(), x[_P_REF].tolist()))   # (NaN: changed)
        if changed and all_finite(reference):
            if all_finite(x[_P_REF]):
                allowance += norm(p - x[_P_REF] - x[_V_REF] * (now - x[_T_REF]))
            x[_P_REF], x[_V_REF], x[_T_REF] = p, reference[_REFERENCE_V], now
        x[_ALLOWANCE] = allowance
