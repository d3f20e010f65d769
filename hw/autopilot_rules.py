"""The PX4 rules the simulated autopilot enforces on top of the simulated flight controller.

The simulated flight controller (systems/autopilot) already checks commands, arms on a rising arm
flag, runs the offboard-loss failsafe descent and the land detector. These rules add what a PX4
commander decides over MAVLink, and turn it into the simulated controller's `fc_command`:

- modes: AUTO.LOITER ("Hold", at boot), OFFBOARD and AUTO.LAND; no RC and no position estimate, so
  no other mode is available, and Hold is refused in the air;
- OFFBOARD is refused without a recent SET_ATTITUDE_TARGET stream (newer than the flight
  controller's stale timeout, PX4's COM_OF_LOSS_T); in OFFBOARD every new setpoint is forwarded
  stamped with its time of reception; when the stream stops, nothing new is forwarded and the
  flight controller's own failsafe descent takes over (reported as AUTO.LAND);
- arming is refused while landing, in the air, in OFFBOARD without a recent setpoint, or with a
  setpoint thrust above the flight controller's arming limit; disarming is refused in the air
  unless forced (param2 = 21196), as PX4;
- AUTO.LAND (MAV_CMD_NAV_LAND or DO_SET_MODE) stops forwarding: the failsafe descent lands and
  disarms.
"""
import dataclasses as dc
import enum
import math

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from alight.hw import px4
from alight.hw.frames import frd_to_b, q_nf_to_wb
from alight.systems.boundary import FC_ATTITUDE, FC_COMMAND, FC_STATUS, ActiveMode, CommandMode
from alight.systems.rotations import heading, heading_quaternion, rotation_matrix

ACCEPTED = mavlink.MAV_RESULT_ACCEPTED
TEMPORARILY_REJECTED = mavlink.MAV_RESULT_TEMPORARILY_REJECTED
DENIED = mavlink.MAV_RESULT_DENIED
UNSUPPORTED = mavlink.MAV_RESULT_UNSUPPORTED

_RATE_IGNORE = (mavlink.ATTITUDE_TARGET_TYPEMASK_BODY_ROLL_RATE_IGNORE
                | mavlink.ATTITUDE_TARGET_TYPEMASK_BODY_PITCH_RATE_IGNORE
                | mavlink.ATTITUDE_TARGET_TYPEMASK_BODY_YAW_RATE_IGNORE)


class FlightMode(enum.Enum):
    HOLD = px4.HOLD
    OFFBOARD = px4.OFFBOARD
    LAND = px4.LAND


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

    def __init__(self, stale_timeout: float, max_arm_thrust: float):
        self.stale_timeout = stale_timeout     # the flight controller's, = PX4 COM_OF_LOSS_T here
        self.max_arm_thrust = max_arm_thrust
        self.mode = FlightMode.HOLD
        self.arm_request = False
        self.setpoint: Setpoint | None = None
        self.setpoint_stamp = -math.inf       # sim time the setpoint was received (or re-stamped)
        self._fc_was_armed = False
        self._output = FC_COMMAND.pack(stamp=0.0, mode=CommandMode.ATTITUDE_THRUST,
                                       q_WD=[1, 0, 0, 0], w_D=np.zeros(3), thrust=0.0, arm=0.0)

    # --- inputs from the link ----------------------------------------------------------------
    def setpoint_received(self, message, now: float) -> bool:
        setpoint = decode_attitude_target(message, self.setpoint)
        if setpoint is None:
            return False
        self.setpoint, self.setpoint_stamp = setpoint, now
        return True

    def stream_fresh(self, now: float) -> bool:
        return self.setpoint is not None and now - self.setpoint_stamp <= self.stale_timeout

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
        if mode == px4.HOLD:
            if airborne:
                return Answer(TEMPORARILY_REJECTED, "Hold not available: no position estimate")
            self.mode = FlightMode.HOLD
            return Answer(ACCEPTED)
        return Answer(DENIED, f"{px4.mode_name(mode)} not available: no RC/position")

    # --- every tick --------------------------------------------------------------------------
    def fc_command(self, now: float, fc_status: np.ndarray, fc_attitude: np.ndarray
                   ) -> np.ndarray:
        """The simulated flight controller's `fc_command` for this tick (mode bookkeeping too)."""
        fc_armed = FC_STATUS.get(fc_status, "armed") > 0.5
        if self._fc_was_armed and not fc_armed:  # disarmed on its own (land detector)
            self.arm_request = False
            if self.mode == FlightMode.LAND:
                self.mode = FlightMode.HOLD
        self._fc_was_armed = fc_armed
        if FC_STATUS.get(fc_status, "mode") == ActiveMode.FAILSAFE_DESCENT:
            self.mode = FlightMode.LAND  # its offboard-loss failsafe: PX4 reports AUTO.LAND
        if self.mode == FlightMode.OFFBOARD and not fc_armed and not self.stream_fresh(now):
            self.mode = FlightMode.HOLD  # PX4 leaves OFFBOARD when the setpoints stop
        arm = float(self.arm_request)
        if self.mode == FlightMode.HOLD:
            eta = heading(rotation_matrix(FC_ATTITUDE.get(fc_attitude, "q_WB")))
            self._output = FC_COMMAND.pack(stamp=now, mode=CommandMode.ATTITUDE_THRUST,
                                           q_WD=heading_quaternion(eta), w_D=np.zeros(3),
                                           thrust=0.0, arm=arm)
        elif self.mode == FlightMode.OFFBOARD and self.setpoint is not None:
            s = self.setpoint
            self._output = FC_COMMAND.pack(stamp=self.setpoint_stamp, mode=s.mode, q_WD=s.q_WD,
                                           w_D=s.w_D, thrust=s.thrust, arm=arm)
        # AUTO.LAND: nothing new; the flight controller's stale timeout starts its descent.
        return self._output

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
