"""The flight controller's commander: command checks, arming, offboard-loss failsafe, land detector.

Every distinct `fc_command` is checked; a non-finite or out-of-range one is refused (the previous
valid command holds, the refusal is counted and its reason shown on `fc_status`). With no valid
command for `stale_timeout` while armed, the vehicle enters the failsafe descent, like PX4's
offboard-loss failsafe: level attitude at the current heading, thrust from the configured hover
thrust with a vertical-speed loop on the flight controller's own estimate, down at
`failsafe_descent_speed`; it stays in failsafe until it lands and disarms. The land detector
(no vertical motion for `land_time` with low thrust, or while the failsafe asks for a descent)
disarms, as PX4's auto-disarm; arming again needs the arm request to drop and rise. As PX4's
land detector, it reports `landed` from arming until take-off is detected (thrust above
`takeoff_thrust_fraction` of the hover force, or climbing faster than `land_speed`), and again
after `ground_contact_time` of low thrust without vertical motion (PX4's ground contact): the
spool-up and the settling on the ground are not flight (consumers that integrate commanded
accelerations, such as the estimator bank's M(53) stand-in, rely on this).
"""
import dataclasses as dc
import math

import numpy as np
from pydrake.systems.framework import LeafSystem

from alight.systems.autopilot.setpoint import SETPOINT
from alight.systems.boundary import (FC_ATTITUDE, FC_COMMAND, FC_STATUS, NO_COMMAND_STAMP,
                                     ActiveMode, CommandMode, Refusal, VectorLayout)
from alight.systems.params import bounded
from alight.systems.rotations import heading_quaternion, quaternion_heading
from alight.systems.thrust_curve import GRAVITY, ThrustCurve


@dc.dataclass
class CommanderParams:
    stale_timeout: float = bounded(0.5, 0.01, 10.0, "s")
    max_body_rate: float = bounded(6.0, 0.1, 50.0, "rad/s")  # commands above are refused
    max_arm_thrust: float = bounded(0.15, 0.0, 1.0)          # arming needs thrust below this
    hover_thrust: float = bounded(0.637, 0.05, 0.95)         # PX4 MPC_THR_HOVER
    failsafe_descent_speed: float = bounded(1.0, 0.1, 3.0, "m/s")
    failsafe_speed_gain: float = bounded(2.0, 0.0, 20.0, "1/s")
    land_thrust_fraction: float = bounded(0.5, 0.0, 1.0)  # of hover force
    land_speed: float = bounded(0.25, 0.01, 2.0, "m/s")
    land_time: float = bounded(2.0, 0.1, 30.0, "s")       # PX4 COM_DISARM_LAND
    takeoff_thrust_fraction: float = bounded(0.9, 0.1, 2.0)  # of hover force: airborne above
    ground_contact_time: float = bounded(0.3, 0.01, 30.0, "s")  # quiet this long: landed


def check_command(command: np.ndarray, params: CommanderParams, last_stamp: float,
                  now: float) -> Refusal:
    """Why `command` (FC_COMMAND) must be refused, or Refusal.NONE."""
    stamp, mode, qw, qx, qy, qz, wx, wy, wz, thrust, arm = np.asarray(command).tolist()
    if not all(math.isfinite(v) for v in (stamp, mode, qw, qx, qy, qz, wx, wy, wz, thrust,
                                          arm)):
        return Refusal.NOT_FINITE
    if int(mode) not in (CommandMode.ATTITUDE_THRUST, CommandMode.RATES_THRUST) \
            or mode != int(mode):
        return Refusal.BAD_MODE
    if not 0.0 <= thrust <= 1.0:
        return Refusal.THRUST_RANGE
    if abs(math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz) - 1.0) > 0.1:
        return Refusal.QUATERNION_NORM
    if max(abs(wx), abs(wy), abs(wz)) > params.max_body_rate:
        return Refusal.BODY_RATE_RANGE
    if arm not in (0.0, 1.0):
        return Refusal.ARM_FLAG
    if stamp < last_stamp or stamp > now + params.stale_timeout:
        return Refusal.STAMP_ORDER
    return Refusal.NONE


# check_command unpacks the command in this order.
assert [name for name, _ in FC_COMMAND.fields] == ["stamp", "mode", "q_WD", "w_D", "thrust", "arm"]


def _same(a: list, b: list) -> bool:
    """np.array_equal(a, b, equal_nan=True) for two short lists of floats of one size, cheaper."""
    return all(p == q or (p != p and q != q) for p, q in zip(a, b))


# Commander memory: last raw command seen (to tell new messages), last accepted command, then flags
# and counters. The outputs are state groups of their own.
_MEMORY = VectorLayout("commander_memory", [
    ("seen", FC_COMMAND.size), ("held", FC_COMMAND.size), ("accepted_once", 1), ("armed", 1),
    ("arm_released", 1), ("failsafe", 1), ("refused", 1), ("last_refusal", 1), ("land_timer", 1),
    ("airborne", 1)])
# The update works on lists of Python floats with these int indices and slices: a NumPy slice, a
# VectorLayout.get or pack costs about a microsecond each, and there are dozens per tick.
_SEEN, _HELD = _MEMORY.slice("seen"), _MEMORY.slice("held")
(_ACCEPTED_ONCE, _ARMED, _ARM_RELEASED, _FAILSAFE, _REFUSED, _LAST_REFUSAL, _LAND_TIMER,
 _AIRBORNE) = (_MEMORY.slice(f).start for f, _ in _MEMORY.fields[2:])
_STAMP, _MODE, _THRUST, _ARM = (FC_COMMAND.slice(f).start
                                for f in ("stamp", "mode", "thrust", "arm"))
_SP_MODE, _SP_THRUST, _SP_ARMED = (SETPOINT.slice(f).start for f in ("mode", "thrust", "armed"))
_Q_WB = FC_ATTITUDE.slice("q_WB")
# A SETPOINT is the command's mode, q_WD and w_D (in this order), then thrust and armed; FC_STATUS
# is built in its field order.
assert SETPOINT.names() == FC_COMMAND.names()[_MODE:_THRUST] + ["thrust", "armed"]
assert [name for name, _ in FC_STATUS.fields] == [
    "stamp", "armed", "mode", "link_alive", "last_command_stamp", "refused", "last_refusal",
    "landed"]


class Commander(LeafSystem):
    """Input  `fc_command`        FC_COMMAND from the companion computer
    Input  `fc_attitude`       FC_ATTITUDE estimate (heading for the failsafe)
    Input  `vertical_velocity` (1) the flight controller's vertical speed estimate [m/s]
    Output `setpoint`          SETPOINT for the attitude/rate/mixer stages
    Output `armed`             (1)
    Output `fc_status`         FC_STATUS
    All outputs come from state updated every `period` (a sampled-data flight controller): each
    is its own discrete state group, read by a state output port (no Python call when read).
    """

    def __init__(self, params: CommanderParams, thrust_curve: ThrustCurve, period: float):
        super().__init__()
        self._p = params
        self._curve = thrust_curve
        self._period = period
        hover_force = thrust_curve.force(params.hover_thrust)
        self._hover_force = hover_force
        self._land_force = params.land_thrust_fraction * hover_force
        self._takeoff_force = params.takeoff_thrust_fraction * hover_force
        self._landed_time = min(params.ground_contact_time, params.land_time)
        self._command = self.DeclareVectorInputPort("fc_command", FC_COMMAND.size)
        self._attitude = self.DeclareVectorInputPort("fc_attitude", FC_ATTITUDE.size)
        self._vz = self.DeclareVectorInputPort("vertical_velocity", 1)
        memory = np.zeros(_MEMORY.size)
        memory[_SEEN] = np.nan
        memory[_HELD] = FC_COMMAND.pack(
            stamp=-np.inf, mode=CommandMode.ATTITUDE_THRUST, q_WD=[1, 0, 0, 0], w_D=np.zeros(3),
            thrust=0.0, arm=0.0)
        memory[_ARM_RELEASED] = 1.0
        memory_group = self.DeclareDiscreteState(memory)
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._update)
        setpoint = self.DeclareDiscreteState(SETPOINT.pack(
            mode=CommandMode.ATTITUDE_THRUST, q_WD=[1, 0, 0, 0], w_D=np.zeros(3), thrust=0.0,
            armed=0.0))
        armed = self.DeclareDiscreteState(1)
        status = self.DeclareDiscreteState(FC_STATUS.vector(last_command_stamp=NO_COMMAND_STAMP))
        self.DeclareStateOutputPort("setpoint", setpoint)
        self.DeclareStateOutputPort("armed", armed)
        self.DeclareStateOutputPort("fc_status", status)
        # Groups accessed by int index: pydrake converts a DiscreteStateIndex on every call.
        self._memory, self._setpoint, self._armed, self._status = map(
            int, (memory_group, setpoint, armed, status))

    def _update(self, context, discrete_state):
        # `discrete_state` holds the current state on entry (Drake copies it in).
        p = self._p
        now = context.get_time()
        memory = discrete_state.get_mutable_value(self._memory)
        m = memory.tolist()
        command = self._command.Eval(context)
        seen = command.tolist()
        held = m[_HELD]
        if not _same(seen, m[_SEEN]):  # a new message
            m[_SEEN] = seen
            refusal = check_command(command, p, held[_STAMP], now)
            if refusal == Refusal.NONE:
                held = seen
                m[_HELD] = held
                m[_ACCEPTED_ONCE] = 1.0
            else:
                m[_REFUSED] += 1.0
                m[_LAST_REFUSAL] = float(refusal)
        link_alive = bool(m[_ACCEPTED_ONCE]) and now - held[_STAMP] <= p.stale_timeout
        armed = bool(m[_ARMED])
        arm_request = held[_ARM] > 0.5
        if not arm_request:
            m[_ARM_RELEASED] = 1.0
        if armed and (not arm_request and link_alive):
            armed = False
        if armed and not link_alive:
            m[_FAILSAFE] = 1.0
        failsafe = bool(m[_FAILSAFE])
        if (not armed and arm_request and link_alive and not failsafe
                and m[_ARM_RELEASED] > 0.5 and held[_THRUST] <= p.max_arm_thrust):
            armed = True
            m[_LAND_TIMER] = 0.0
            m[_AIRBORNE] = 0.0
        vz = self._vz.Eval(context)[0]
        if failsafe:  # the attitude is read only here: each Eval costs ~8 us
            q_WB = self._attitude.Eval(context)[_Q_WB].tolist()
            setpoint = [float(CommandMode.ATTITUDE_THRUST),
                        *heading_quaternion(quaternion_heading(*q_WB)).tolist(), 0.0, 0.0, 0.0,
                        self._failsafe_thrust(vz), float(armed)]
        else:
            setpoint = held[_MODE:_THRUST] + [held[_THRUST] if armed else 0.0, float(armed)]
        # Land detector: no vertical motion with low thrust, or while the failsafe asks for a
        # descent (ground contact), for land_time -> landed, disarm.
        force = self._curve.force(setpoint[_SP_THRUST])
        quiet = (force < self._land_force or failsafe) and abs(vz) < p.land_speed
        m[_LAND_TIMER] = m[_LAND_TIMER] + self._period if armed and quiet else 0.0
        if armed and (force >= self._takeoff_force or vz > p.land_speed):
            m[_AIRBORNE] = 1.0
        landed = (not armed) or m[_AIRBORNE] < 0.5 or m[_LAND_TIMER] >= self._landed_time
        if armed and m[_LAND_TIMER] >= p.land_time:
            armed = False
            m[_ARM_RELEASED] = 0.0
            setpoint[_SP_ARMED] = 0.0
            setpoint[_SP_THRUST] = 0.0
        if not armed:
            m[_FAILSAFE] = 0.0
            failsafe = False
        m[_ARMED] = float(armed)
        memory[:] = m
        mode = ActiveMode.DISARMED if not armed else (
            ActiveMode.FAILSAFE_DESCENT if failsafe else ActiveMode(int(setpoint[_SP_MODE])))
        discrete_state.set_value(self._setpoint, setpoint)
        discrete_state.get_mutable_value(self._armed)[0] = m[_ARMED]
        discrete_state.set_value(self._status, [
            now, m[_ARMED], float(mode), float(link_alive),
            held[_STAMP] if m[_ACCEPTED_ONCE] else NO_COMMAND_STAMP, m[_REFUSED],
            m[_LAST_REFUSAL], float(landed)])

    def _failsafe_thrust(self, vz: float) -> float:
        """Hover thrust corrected by a vertical-speed loop toward -failsafe_descent_speed."""
        error = -self._p.failsafe_descent_speed - vz
        acceleration = np.clip(self._p.failsafe_speed_gain * error, -0.5 * GRAVITY, 0.5 * GRAVITY)
        return float(self._curve.thrust(self._hover_force * (1.0 + acceleration / GRAVITY)))
