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
from alight.systems.rotations import heading, heading_quaternion, rotation_matrix
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


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    """np.array_equal(a, b, equal_nan=True) for two short vectors of the same size, cheaper."""
    return all(p == q or (p != p and q != q) for p, q in zip(a.tolist(), b.tolist()))


# Commander state vector: last raw command seen (to tell new messages), last accepted command,
# then flags and counters.
_STATE = [("seen", FC_COMMAND.size), ("held", FC_COMMAND.size), ("accepted_once", 1),
          ("armed", 1), ("arm_released", 1), ("failsafe", 1), ("refused", 1),
          ("last_refusal", 1), ("land_timer", 1), ("landed", 1), ("airborne", 1),
          ("setpoint", SETPOINT.size),
          ("status", FC_STATUS.size)]


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
        self._layout = VectorLayout("commander_state", _STATE)
        self._p = params
        self._curve = thrust_curve
        self._period = period
        self._hover_force = thrust_curve.force(params.hover_thrust)
        self._command = self.DeclareVectorInputPort("fc_command", FC_COMMAND.size)
        self._attitude = self.DeclareVectorInputPort("fc_attitude", FC_ATTITUDE.size)
        self._vz = self.DeclareVectorInputPort("vertical_velocity", 1)
        initial = np.zeros(self._layout.size)
        initial[self._layout.slice("seen")] = np.nan
        initial[self._layout.slice("held")] = FC_COMMAND.pack(
            stamp=-np.inf, mode=CommandMode.ATTITUDE_THRUST, q_WD=[1, 0, 0, 0], w_D=np.zeros(3),
            thrust=0.0, arm=0.0)
        initial[self._layout.slice("arm_released")] = 1.0
        initial[self._layout.slice("status")] = FC_STATUS.vector(
            last_command_stamp=NO_COMMAND_STAMP)
        initial[self._layout.slice("setpoint")] = SETPOINT.pack(
            mode=CommandMode.ATTITUDE_THRUST, q_WD=[1, 0, 0, 0], w_D=np.zeros(3), thrust=0.0,
            armed=0.0)
        self._xd = self.DeclareDiscreteState(initial)
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._update)
        self._outputs = {}
        for name, field in (("setpoint", "setpoint"), ("armed", "armed"),
                            ("fc_status", "status")):
            self._outputs[field] = self.DeclareDiscreteState(initial[self._layout.slice(field)])
            self.DeclareStateOutputPort(name, self._outputs[field])

    def _get(self, context):
        return context.get_discrete_state(self._xd).get_value()

    def _update(self, context, discrete_state):
        L = self._layout
        x = self._get(context).copy()
        now = context.get_time()
        command = self._command.Eval(context)
        held = x[L.slice("held")]
        if not _same(command, x[L.slice("seen")]):  # a new message
            x[L.slice("seen")] = command
            refusal = check_command(command, self._p, FC_COMMAND.get(held, "stamp"), now)
            if refusal == Refusal.NONE:
                held = command.copy()
                x[L.slice("held")] = held
                x[L.slice("accepted_once")] = 1.0
            else:
                x[L.slice("refused")] += 1.0
                x[L.slice("last_refusal")] = refusal
        link_alive = bool(x[L.slice("accepted_once")][0]) \
            and now - FC_COMMAND.get(held, "stamp") <= self._p.stale_timeout
        armed = bool(x[L.slice("armed")][0])
        arm_request = FC_COMMAND.get(held, "arm") > 0.5
        if not arm_request:
            x[L.slice("arm_released")] = 1.0
        if armed and (not arm_request and link_alive):
            armed = False
        if armed and not link_alive:
            x[L.slice("failsafe")] = 1.0
        failsafe = bool(x[L.slice("failsafe")][0])
        if (not armed and arm_request and link_alive and not failsafe
                and x[L.slice("arm_released")][0] > 0.5
                and FC_COMMAND.get(held, "thrust") <= self._p.max_arm_thrust):
            armed = True
            x[L.slice("land_timer")] = 0.0
            x[L.slice("airborne")] = 0.0
        attitude = self._attitude.Eval(context)
        vz = self._vz.Eval(context)[0]
        if failsafe:
            thrust = self._failsafe_thrust(vz)
            setpoint = SETPOINT.pack(mode=CommandMode.ATTITUDE_THRUST,
                                     q_WD=heading_quaternion(heading(rotation_matrix(
                                         FC_ATTITUDE.get(attitude, "q_WB")))),
                                     w_D=np.zeros(3), thrust=thrust, armed=float(armed))
        else:
            setpoint = SETPOINT.pack(mode=FC_COMMAND.get(held, "mode"),
                                     q_WD=FC_COMMAND.get(held, "q_WD"),
                                     w_D=FC_COMMAND.get(held, "w_D"),
                                     thrust=FC_COMMAND.get(held, "thrust") if armed else 0.0,
                                     armed=float(armed))
        # Land detector: no vertical motion with low thrust, or while the failsafe asks for a
        # descent (ground contact), for land_time -> landed, disarm.
        force = self._curve.force(SETPOINT.get(setpoint, "thrust"))
        low_thrust = force < self._p.land_thrust_fraction * self._hover_force
        quiet = (low_thrust or failsafe) and abs(vz) < self._p.land_speed
        x[L.slice("land_timer")] = x[L.slice("land_timer")] + self._period if armed and quiet \
            else 0.0
        if armed and (force >= self._p.takeoff_thrust_fraction * self._hover_force
                      or vz > self._p.land_speed):
            x[L.slice("airborne")] = 1.0
        landed = (not armed) or x[L.slice("airborne")][0] < 0.5 \
            or x[L.slice("land_timer")][0] >= min(self._p.ground_contact_time, self._p.land_time)
        if armed and x[L.slice("land_timer")][0] >= self._p.land_time:
            armed = False
            x[L.slice("arm_released")] = 0.0
            setpoint[SETPOINT.slice("armed")] = 0.0
            setpoint[SETPOINT.slice("thrust")] = 0.0
        if not armed:
            x[L.slice("failsafe")] = 0.0
            failsafe = False
        x[L.slice("armed")] = float(armed)
        x[L.slice("landed")] = float(landed)
        x[L.slice("setpoint")] = setpoint
        mode = ActiveMode.DISARMED if not armed else (
            ActiveMode.FAILSAFE_DESCENT if failsafe else ActiveMode(int(SETPOINT.get(setpoint,
                                                                                     "mode"))))
        x[L.slice("status")] = FC_STATUS.pack(
            stamp=now, armed=float(armed), mode=mode, link_alive=float(link_alive),
            last_command_stamp=FC_COMMAND.get(held, "stamp") if x[L.slice("accepted_once")][0]
            else NO_COMMAND_STAMP,
            refused=x[L.slice("refused")], last_refusal=x[L.slice("last_refusal")],
            landed=float(landed))
        discrete_state.set_value(self._xd, x)
        for field, group in self._outputs.items():
            discrete_state.set_value(group, x[L.slice(field)])

    def _failsafe_thrust(self, vz: float) -> float:
        """Hover thrust corrected by a vertical-speed loop toward -failsafe_descent_speed."""
        error = -self._p.failsafe_descent_speed - vz
        acceleration = np.clip(self._p.failsafe_speed_gain * error, -0.5 * GRAVITY, 0.5 * GRAVITY)
        return float(self._curve.thrust(self._hover_force * (1.0 + acceleration / GRAVITY)))
