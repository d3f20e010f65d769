"""The PX4 rules the simulated autopilot enforces on top of the simulated flight controller.

The simulated flight controller (systems/autopilot) already checks commands, arms on a rising arm
flag, runs its own stale-command failsafe descent, the land detector and EKF2's external-vision
fusion (its local position). These rules add what a PX4 commander decides over MAVLink, and turn
it into the simulated controller's `fc_command` (docs/hardware.md, each rule next to PX4's):

- modes: AUTO.LOITER ("Hold", at boot), POSCTL ("Position": with no RC, a hold as well),
  OFFBOARD and AUTO.LAND; no other mode (no RC, no mission);
- Hold and Position in the air need a valid local position (external vision fused): they hold
  the position where they were entered (PX4's position controller, position_hold.py); without
  one they are refused, and losing it while holding starts AUTO.LAND (PX4's fallback);
- OFFBOARD is refused without a recent SET_ATTITUDE_TARGET stream; in OFFBOARD every new
  setpoint is forwarded stamped with its time of reception;
- offboard loss (no setpoint for COM_OF_LOSS_T, the flight controller's stale timeout, in
  OFFBOARD, armed): COM_OBL_RC_ACT's action,
  Position (0) or Hold (5) when the local position is valid, else, and for Land (4), AUTO.LAND;
  on the ground OFFBOARD falls back to Hold;
- AUTO.LAND (MAV_CMD_NAV_LAND or DO_SET_MODE, or a failsafe) stops forwarding: the flight
  controller's failsafe descent lands and disarms (PX4's Descend: no position control);
- arming is refused while landing, in the air, in OFFBOARD without a recent setpoint, or with a
  setpoint thrust above the flight controller's arming limit; disarming is refused in the air
  unless forced (param2 = 21196), as PX4.
"""
import dataclasses as dc
import enum
import math

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from alight.hw import px4
from alight.hw.frames import frd_to_b, q_nf_to_wb
from alight.systems.autopilot.ev_fusion import LOCAL_POSITION
from alight.systems.autopilot.position_hold import PositionHold, PositionHoldParams
from alight.systems.boundary import FC_ATTITUDE, FC_COMMAND, FC_STATUS, ActiveMode, CommandMode
from alight.systems.params import bounded
from alight.systems.rotations import heading, heading_quaternion, rotation_matrix

ACCEPTED = mavlink.MAV_RESULT_ACCEPTED
TEMPORARILY_REJECTED = mavlink.MAV_RESULT_TEMPORARILY_REJECTED
DENIED = mavlink.MAV_RESULT_DENIED
UNSUPPORTED = mavlink.MAV_RESULT_UNSUPPORTED

_RATE_IGNORE = (mavlink.ATTITUDE_TARGET_TYPEMASK_BODY_ROLL_RATE_IGNORE
                | mavlink.ATTITUDE_TARGET_TYPEMASK_BODY_PITCH_RATE_IGNORE
                | mavlink.ATTITUDE_TARGET_TYPEMASK_BODY_YAW_RATE_IGNORE)


POSITION_MODE = px4.custom_mode(px4.MainMode.POSCTL)


class FlightMode(enum.Enum):
    HOLD = px4.HOLD
    POSITION = POSITION_MODE
    OFFBOARD = px4.OFFBOARD
    LAND = px4.LAND


HOLDING = (FlightMode.HOLD, FlightMode.POSITION)

# COM_OBL_RC_ACT values (PX4 commander): what offboard loss switches to.
OFFBOARD_LOSS_ACTIONS = {0: FlightMode.POSITION, 4: FlightMode.LAND, 5: FlightMode.HOLD}


@dc.dataclass
class Px4RulesParams:
    """PX4 commander and position-controller parameters the rules emulate (COM_OF_LOSS_T is the
    flight controller's stale timeout, `AutopilotRules.stale_timeout`)."""
    com_obl_rc_act: int = bounded(0, 0, 7)   # COM_OBL_RC_ACT: 0 Position, 4 Land, 5 Hold
    hold: PositionHoldParams = dc.field(default_factory=PositionHoldParams)

    def __post_init__(self):
        if self.com_obl_rc_act not in OFFBOARD_LOSS_ACTIONS:
            raise ValueError(f"COM_OBL_RC_ACT {self.com_obl_rc_act}: emulated are "
                             f"{sorted(OFFBOARD_LOSS_ACTIONS)} (0 Position, 4 Land, 5 Hold)")


@dc.dataclass(frozen=True)
class Answer:
    result: int
    text: str = ""  # a STATUSTEXT for the operator (PX4 explains its refusals so)


@dc.dataclass(frozen=True)
class Setpoint:
    """A SET_ATTITUDE_TARGET in DESIGN.md frames: mode, q_WD, w_D [rad/s, B], thrust."""
    mode: CommandMode
    q_WD: np.ndarray
    w_D: np.ndarray
    thrust: float


def decode_attitude_target(message, previous: Setpoint | None) -> Setpoint | None:
    """The setpoint of a SET_ATTITUDE_TARGET, or None when it is unusable: no attitude and not all
    three rates, no thrust and none before, or a non-finite value."""
    mask = message.type_mask
    rates = frd_to_b([message.body_roll_rate, message.body_pitch_rate, message.body_yaw_rate])
    if mask & mavlink.ATTITUDE_TARGET_TYPEMASK_ATTITUDE_IGNORE:
        if mask & _RATE_IGNORE:
            return None
        mode, q_WD = CommandMode.RATES_THRUST, np.array([1.0, 0.0, 0.0, 0.0])
    else:
        mode, q_WD = CommandMode.ATTITUDE_THRUST, q_nf_to_wb(message.q)
        rates = np.where([mask & 1, mask & 2, mask & 4], 0.0, rates)
    if mask & mavlink.ATTITUDE_TARGET_TYPEMASK_THROTTLE_IGNORE:
        if previous is None:
            return None
        thrust = previous.thrust
    else:
        thrust = float(message.thrust)
    if not (np.all(np.isfinite(q_WD)) and np.all(np.isfinite(rates)) and math.isfinite(thrust)):
        return None
    return Setpoint(mode, q_WD, rates, thrust)


class AutopilotRules:
    """The PX4 commander subset; `fc_command(...)` is called every bridge tick."""

    def __init__(self, stale_timeout: float, max_arm_thrust: float, hover_thrust: float = 0.637,
                 command_period: float = 0.004, params: Px4RulesParams | None = None):
        self.params = params or Px4RulesParams()
        self.stale_timeout = stale_timeout     # the flight controller's, = PX4 COM_OF_LOSS_T here
        self.max_arm_thrust = max_arm_thrust
        self.command_period = command_period
        self.hold = PositionHold(self.params.hold, hover_thrust)
        self.local_position = LOCAL_POSITION.vector()  # the autopilot's, as of the last tick
        self.notices: list[str] = []  # STATUSTEXT for the operator (failsafe actions)
        self.mode = FlightMode.HOLD
        self.arm_request = False
        self.setpoint: Setpoint | None = None
        self.setpoint_stamp = -math.inf       # sim time the setpoint was received (or re-stamped)
        self._fc_was_armed = False
        self._heading = 0.0
        self._output = FC_COMMAND.pack(stamp=0.0, mode=CommandMode.ATTITUDE_THRUST,
                                       q_WD=[1, 0, 0, 0], w_D=np.zeros(3), thrust=0.0, arm=0.0)

    # --- inputs from the link ----------------------------------------------------------------
    def setpoint_received(self, message, now: float) -> bool:
        setpoint = decode_attitude_target(message, self.setpoint)
        if setpoint is None:
            return False
        self.setpoint, self.setpoint_stamp = setpoint, now
        return True

    def stream_fresh(self, now: float, margin: float = 0.0) -> bool:
        return self.setpoint is not None \
            and now - self.setpoint_stamp <= self.stale_timeout - margin

    def position_valid(self) -> bool:
        return LOCAL_POSITION.get(self.local_position, "valid") > 0.5

    def command(self, command: int, params: list[float], now: float, fc_status: np.ndarray
                ) -> Answer:
        """The answer to a COMMAND_LONG/COMMAND_INT this class decides (arm, mode, land)."""
        if command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
            if params[0] == 1.0:
                return self._arm(now, fc_status)
            if params[0] == 0.0:
                return self._disarm(params[1] == px4.FORCE_DISARM, fc_status)
            return Answer(DENIED, "Arm/disarm: param1 must be 0 or 1")
        if command == mavlink.MAV_CMD_DO_SET_MODE:
            if not int(params[0]) & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
                return Answer(DENIED, "Only PX4 custom modes are supported")
            return self._set_mode(px4.custom_mode(int(params[1]), int(params[2])), now,
                                  fc_status)
        if command == mavlink.MAV_CMD_NAV_LAND:
            return self._set_mode(px4.LAND, now, fc_status)
        return Answer(UNSUPPORTED)

    def _arm(self, now, fc_status) -> Answer:
        if FC_STATUS.get(fc_status, "armed") > 0.5:
            return Answer(ACCEPTED)
        if self.mode == FlightMode.LAND:
            return Answer(TEMPORARILY_REJECTED, "Arming denied: landing")
        if FC_STATUS.get(fc_status, "landed") < 0.5:
            return Answer(TEMPORARILY_REJECTED, "Arming denied: not landed")
        if self.mode == FlightMode.OFFBOARD:
            if not self.stream_fresh(now):
                return Answer(TEMPORARILY_REJECTED, "Arming denied: no offboard setpoints")
            if self.setpoint.thrust > self.max_arm_thrust:
                return Answer(TEMPORARILY_REJECTED,
                              f"Arming denied: thrust setpoint above {self.max_arm_thrust:.2f}")
        self.arm_request = True
        return Answer(ACCEPTED, "Armed by external command")

    def _disarm(self, force: bool, fc_status) -> Answer:
        if FC_STATUS.get(fc_status, "armed") < 0.5:
            self.arm_request = False
            return Answer(ACCEPTED)
        if FC_STATUS.get(fc_status, "landed") < 0.5 and not force:
            return Answer(TEMPORARILY_REJECTED, "Disarming denied: not landed")
        self.arm_request = False
        return Answer(ACCEPTED, "Disarmed by external command")

    def _set_mode(self, mode: int, now, fc_status) -> Answer:
        airborne = FC_STATUS.get(fc_status, "armed") > 0.5 \
            and FC_STATUS.get(fc_status, "landed") < 0.5
        if mode == px4.OFFBOARD:
            if self.mode == FlightMode.LAND and airborne:
                return Answer(TEMPORARILY_REJECTED, "Landing: Offboard not available")
            if not self.stream_fresh(now):
                return Answer(TEMPORARILY_REJECTED, "Offboard not available: no setpoints")
            if self.mode != FlightMode.OFFBOARD:
                self.setpoint_stamp = now  # forwarded from now on, never older than the last
            self.mode = FlightMode.OFFBOARD
            return Answer(ACCEPTED)
        if mode == px4.LAND:
            if FC_STATUS.get(fc_status, "armed") < 0.5:
                return Answer(TEMPORARILY_REJECTED, "Land denied: not armed")
            self.mode = FlightMode.LAND
            return Answer(ACCEPTED, "Landing")
        if mode in (px4.HOLD, POSITION_MODE):
            target = FlightMode(mode)
            if airborne and not self.position_valid():
                return Answer(TEMPORARILY_REJECTED,
                              f"{target.name.capitalize()} not available: no position estimate")
            if airborne and self.mode not in HOLDING:
                self._start_hold()
            self.mode = target
            return Answer(ACCEPTED)
        return Answer(DENIED, f"{px4.mode_name(mode)} not available: no RC, no mission")

    # --- every tick --------------------------------------------------------------------------
    def fc_command(self, now: float, fc_status: np.ndarray, fc_attitude: np.ndarray,
                   local_position: np.ndarray | None = None) -> np.ndarray:
        """The simulated flight controller's `fc_command` for this tick (mode bookkeeping too);
        `local_position` (LOCAL_POSITION) is the autopilot's fused estimate, if any."""
        if local_position is not None:
            self.local_position = local_position
        self._heading = heading(rotation_matrix(FC_ATTITUDE.get(fc_attitude, "q_WB")))
        fc_armed = FC_STATUS.get(fc_status, "armed") > 0.5
        airborne = fc_armed and FC_STATUS.get(fc_status, "landed") < 0.5
        if self._fc_was_armed and not fc_armed:  # disarmed on its own (land detector)
            self.arm_request = False
            if self.mode == FlightMode.LAND:
                self.mode = FlightMode.HOLD
        self._fc_was_armed = fc_armed
        if FC_STATUS.get(fc_status, "mode") == ActiveMode.FAILSAFE_DESCENT:
            self.mode = FlightMode.LAND  # its stale-command failsafe: PX4 reports AUTO.LAND
        # Offboard loss is decided two flight-controller periods before COM_OF_LOSS_T (its stale
        # timeout): PX4's action, not the emulation's own descent, follows the loss.
        if self.mode == FlightMode.OFFBOARD \
                and not self.stream_fresh(now, 2.0 * self.command_period):
            self._offboard_lost(airborne)
        if self.mode in HOLDING and airborne and not self.position_valid():
            self.mode = FlightMode.LAND
            self.notices.append("Failsafe: no local position, landing")
        arm = float(self.arm_request)
        if self.mode in HOLDING and airborne:
            q_WD, thrust = self.hold.command(LOCAL_POSITION.get(self.local_position, "p_WB"),
                                             LOCAL_POSITION.get(self.local_position, "v_WB"),
                                             self.command_period)
            self._output = FC_COMMAND.pack(stamp=now, mode=CommandMode.ATTITUDE_THRUST,
                                           q_WD=q_WD, w_D=np.zeros(3), thrust=thrust, arm=arm)
        elif self.mode in HOLDING:  # on the ground: idle at the current heading
            self._output = FC_COMMAND.pack(stamp=now, mode=CommandMode.ATTITUDE_THRUST,
                                           q_WD=heading_quaternion(self._heading),
                                           w_D=np.zeros(3), thrust=0.0, arm=arm)
        elif self.mode == FlightMode.OFFBOARD and self.setpoint is not None:
            s = self.setpoint
            self._output = FC_COMMAND.pack(stamp=self.setpoint_stamp, mode=s.mode, q_WD=s.q_WD,
                                           w_D=s.w_D, thrust=s.thrust, arm=arm)
        # AUTO.LAND: nothing new; the flight controller's stale timeout starts its descent.
        return self._output

    def _offboard_lost(self, airborne: bool) -> None:
        """COM_OF_LOSS_T passed without a setpoint in OFFBOARD: COM_OBL_RC_ACT's action in the
        air when the local position allows it, else AUTO.LAND; Hold on the ground."""
        if not airborne:
            self.mode = FlightMode.HOLD  # PX4 leaves OFFBOARD when the setpoints stop
            return
        action = OFFBOARD_LOSS_ACTIONS[self.params.com_obl_rc_act]
        if action in HOLDING and self.position_valid():
            self._start_hold()
            self.mode = action
            self.notices.append(f"Failsafe: offboard lost, {action.name.lower()}")
        else:
            self.mode = FlightMode.LAND
            self.notices.append("Failsafe: offboard lost, landing")

    def _start_hold(self) -> None:
        """Hold the current local position at the current heading."""
        self.hold.reset(LOCAL_POSITION.get(self.local_position, "p_WB"), self._heading)

    def heartbeat(self, fc_status: np.ndarray) -> tuple[int, int, int]:
        """(base_mode, custom_mode, system_status) for HEARTBEAT."""
        armed = FC_STATUS.get(fc_status, "armed") > 0.5
        base_mode = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED \
            | (mavlink.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0)
        if FC_STATUS.get(fc_status, "mode") == ActiveMode.FAILSAFE_DESCENT:
            status = mavlink.MAV_STATE_CRITICAL
        else:
            status = mavlink.MAV_STATE_ACTIVE if armed else mavlink.MAV_STATE_STANDBY
        return base_mode, self.mode.value, status
