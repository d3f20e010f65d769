"""The companion computer's MAVLink link to a PX4 flight controller.

A background reader (hw/endpoint.py) turns the autopilot's telemetry into thread-safe buffers
that the MAVLink vehicle's ports read: IMU samples (HIGHRES_IMU or SCALED_IMU, each kept once, in
the autopilot's time order), the attitude estimate (ATTITUDE_QUATERNION), armed state and PX4
mode (HEARTBEAT), landed state (EXTENDED_SYS_STATE), the downward rangefinder (DISTANCE_SENSOR),
command acknowledgements and status texts.
A keep-alive thread sends the companion heartbeat (1 Hz) and TIMESYNC requests; the autopilot's
clock is mapped to ours from the TIMESYNC round trip with the smallest delay in a sliding window.
Commands go out as COMMAND_LONG with acknowledgement, retries (confirmation counter) and a clear
`CommandDenied` on refusal. Values cross into DESIGN.md frames here (hw/frames.py).
"""
import collections
import dataclasses as dc
import math
import threading
import time

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from alight.hw import px4
from alight.hw.connection import open_connection
from alight.hw.endpoint import LOG, MavlinkEndpoint, addressed_to
from alight.hw.frames import b_to_frd, frd_to_b, q_nf_to_wb, q_wb_to_nf
from alight.hw.realtime import WallClock
from alight.systems.boundary import FC_COMMAND, CommandMode
from alight.systems.params import bounded, choice

MILLI_G = 9.80665e-3  # SCALED_IMU acceleration unit [m/s^2]
_MAX_ACCEL = 2000.0   # m/s^2: beyond any IMU range; larger values are corrupt
_MAX_RATE = 200.0     # rad/s


@dc.dataclass
class LinkParams:
    """The companion computer's link settings (models/mavlink_vehicle.yaml `link`)."""
    system_id: int = bounded(1, 1, 255)            # ours: the vehicle's system (PX4 companions)
    component_id: int = bounded(191, 1, 255)       # MAV_COMP_ID_ONBOARD_COMPUTER
    target_system: int = bounded(1, 1, 255)        # the autopilot
    target_component: int = bounded(1, 1, 255)     # MAV_COMP_ID_AUTOPILOT1
    heartbeat_period: float = bounded(1.0, 0.05, 10.0, "s")
    heartbeat_timeout: float = bounded(3.0, 0.1, 60.0, "s")  # no autopilot HEARTBEAT -> link lost
    link_timeout: float = bounded(0.5, 0.02, 60.0, "s")      # no autopilot message -> link lost
    timesync_period: float = bounded(0.2, 0.01, 10.0, "s")
    timesync_window: int = bounded(10, 1, 1000)    # round trips the offset is chosen from
    command_timeout: float = bounded(0.3, 0.01, 10.0, "s")  # wait for an ack before resending
    command_attempts: int = bounded(5, 1, 50)
    imu_message: str = choice("HIGHRES_IMU", "SCALED_IMU")
    imu_rate: float = bounded(250.0, 1.0, 4000.0, "Hz")
    attitude_rate: float = bounded(100.0, 1.0, 1000.0, "Hz")
    status_rate: float = bounded(10.0, 0.2, 100.0, "Hz")
    range_rate: float = bounded(50.0, 1.0, 1000.0, "Hz")   # DISTANCE_SENSOR (downward)
    imu_queue: int = bounded(4000, 10, 1000000)    # samples held until the IMU port takes them


class LinkTimeout(TimeoutError):
    """The autopilot did not answer in time."""


class CommandDenied(RuntimeError):
    """The autopilot refused a command (its COMMAND_ACK result and its last status text)."""

    def __init__(self, command: int, result: int, text: str = ""):
        self.command, self.result, self.text = command, result, text
        super().__init__(f"{px4.command_name(command)} refused by the flight controller: "
                         f"{px4.result_name(result)}" + (f" ({text})" if text else ""))


@dc.dataclass(frozen=True)
class ImuSample:
    t_fc: float         # s, the autopilot's clock
    accel: np.ndarray   # specific force in B [m/s^2]
    gyro: np.ndarray    # angular velocity of B in B [rad/s]


@dc.dataclass(frozen=True)
class AutopilotState:
    """The latest telemetry, in DESIGN.md frames; times are `time.monotonic()` of reception."""
    heartbeat_time: float = -math.inf
    message_time: float = -math.inf
    base_mode: int = 0
    custom_mode: int = 0
    system_status: int = 0
    landed_state: int = mavlink.MAV_LANDED_STATE_UNDEFINED
    attitude_t_fc: float = math.nan    # s, autopilot clock
    q_WB: tuple = (1.0, 0.0, 0.0, 0.0)
    w_B: tuple = (0.0, 0.0, 0.0)
    attitude_valid: bool = False
    # the downward DISTANCE_SENSOR (orientation PITCH_270): its time on the autopilot clock [s],
    # distance [m], variance [m^2] and whether it lies within the sensor's range
    range_t_fc: float = math.nan
    range: float = math.nan
    range_var: float = math.nan
    range_valid: bool = False

    @property
    def armed(self) -> bool:
        return bool(self.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)

    @property
    def offboard(self) -> bool:
        return self.custom_mode == px4.OFFBOARD

    @property
    def simulated(self) -> bool:
        """HEARTBEAT's MAV_MODE_FLAG_HIL_ENABLED: the vehicle is simulated (PX4 with SYS_HITL = 1,
        `alight sim-autopilot`)."""
        return bool(self.base_mode & mavlink.MAV_MODE_FLAG_HIL_ENABLED)

    @property
    def landed(self) -> bool:
        return self.landed_state == mavlink.MAV_LANDED_STATE_ON_GROUND


class TimeSync:
    """Offset of the autopilot's clock from ours (MAVLink TIMESYNC): for a request sent at ts1
    (our clock), answered with tc1 (theirs) and received at t, offset = tc1 - (ts1 + t) / 2; the
    estimate is the sample with the smallest round trip among the last `window`."""

    def __init__(self, window: int):
        self._samples = collections.deque(maxlen=window)
        self._pending = collections.deque(maxlen=64)  # ts1 of requests in flight
        self._lock = threading.Lock()
        self.offset_ns: int | None = None
        self.rtt_ns: int | None = None

    def request(self, ts1: int) -> None:
        with self._lock:
            self._pending.append(ts1)

    def reply(self, tc1: int, ts1: int, now_ns: int) -> bool:
        """False (rejected) for a reply to no request of ours or with an impossible delay."""
        with self._lock:
            if ts1 not in self._pending:
                return False
            self._pending.remove(ts1)
            rtt = now_ns - ts1
            if not 0 <= rtt < 1_000_000_000 or tc1 <= 0:
                return False
            self._samples.append((rtt, tc1 - (ts1 + now_ns) // 2))
            self.rtt_ns, self.offset_ns = min(self._samples)
            return True

    @property
    def locked(self) -> bool:
        return self.offset_ns is not None


class MavlinkLink(MavlinkEndpoint):
    """The companion end of the link. `MavlinkLink.open("udp:127.0.0.1:14540", params, clock)`."""

    def __init__(self, transport, params: LinkParams, clock: WallClock, datagrams: bool,
                 name: str = ""):
        super().__init__(transport, params.system_id, params.component_id, datagrams,
                         peer_timeout=params.heartbeat_timeout)
        self.params = params
        self.clock = clock
        self.name = name
        self.timesync = TimeSync(params.timesync_window)
        self._state = AutopilotState()
        self._state_lock = threading.Lock()
        self._imu = collections.deque()
        self._imu_lock = threading.Lock()
        self._last_imu_t_fc = -math.inf
        self._frozen_offset_ns: int | None = None
        self._imu_backwards = 0
        self.imu_overflow = 0
        self.imu_out_of_order = 0
        self._acks: dict[int, tuple[int, float]] = {}
        self._ack_condition = threading.Condition()
        self.status_texts = collections.deque(maxlen=20)
        self._stream_start = math.inf  # monotonic time the current setpoint stream started
        self._last_setpoint = -math.inf
        self.setpoints_sent = 0
        self._keepalive: threading.Thread | None = None

    @classmethod
    def open(cls, url: str, params: LinkParams, clock: WallClock) -> "MavlinkLink":
        transport = open_connection(url, "connect")
        link = cls(transport, params, clock,
                   datagrams=url.split(":", 1)[0] in ("udp", "udpin", "udpout"), name=url)
        return link.start()

    def start(self):
        super().start()
        self._keepalive = threading.Thread(target=self._keepalive_loop, name="mavlink-keepalive",
                                           daemon=True)
        self._keepalive.start()
        return self

    def close(self):
        self._running = False
        if self._keepalive is not None:
            self._keepalive.join(timeout=2.0)
        super().close()

    def clock_ns(self) -> int:
        return self.clock.scaled_ns()

    # --- keep-alive: heartbeat and TIMESYNC requests --------------------------------------------
    def _keepalive_loop(self):
        next_heartbeat = next_sync = time.monotonic()
        while self._running:
            now = time.monotonic()
            if now >= next_heartbeat:
                self.send(self.mav.heartbeat_encode(
                    mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0, 0,
                    mavlink.MAV_STATE_ACTIVE))
                next_heartbeat = now + self.params.heartbeat_period
            if now >= next_sync:
                ts1 = self.clock.scaled_ns()
                self.timesync.request(ts1)
                self.send(self.mav.timesync_encode(0, ts1))
                # Faster until locked, so the IMU can flow soon after the link opens.
                period = self.params.timesync_period
                next_sync = now + (period if self.timesync.locked else min(period, 0.05))
            time.sleep(max(0.0, min(next_heartbeat, next_sync) - time.monotonic()))

    # --- reception -------------------------------------------------------------------------
    def _accepts(self, message) -> bool:
        header = message.get_header()
        return (header.srcSystem, header.srcComponent) == (self.params.target_system,
                                                           self.params.target_component) \
            and addressed_to(message, self.system_id, self.component_id)

    def _handle(self, message, now: float) -> bool:
        kind = message.get_type()
        with self._state_lock:
            self._state = dc.replace(self._state, message_time=now)
        handler = _HANDLERS.get(kind)
        return True if handler is None else handler(self, message, now)

    def _on_heartbeat(self, message, now) -> bool:
        if message.autopilot == mavlink.MAV_AUTOPILOT_INVALID:
            return False  # not a flight controller's heartbeat
        with self._state_lock:
            self._state = dc.replace(self._state, heartbeat_time=now, base_mode=message.base_mode,
                                     custom_mode=message.custom_mode,
                                     system_status=message.system_status)
        return True

    def _on_attitude(self, message, now) -> bool:
        q = np.array([message.q1, message.q2, message.q3, message.q4])
        w = np.array([message.rollspeed, message.pitchspeed, message.yawspeed])
        norm = np.linalg.norm(q)
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(w)) and abs(norm - 1.0) < 0.1
                and np.max(np.abs(w)) < _MAX_RATE):
            return False
        with self._state_lock:
            self._state = dc.replace(self._state, attitude_t_fc=message.time_boot_ms * 1e-3,
                                     q_WB=tuple(q_nf_to_wb(q / norm)), w_B=tuple(frd_to_b(w)),
                                     attitude_valid=True)
        return True

    def _on_extended_sys_state(self, message, now) -> bool:
        if message.landed_state > mavlink.MAV_LANDED_STATE_LANDING:
            return False
        with self._state_lock:
            self._state = dc.replace(self._state, landed_state=message.landed_state)
        return True

    def _on_distance_sensor(self, message, now) -> bool:
        """The downward rangefinder (DISTANCE_SENSOR, cm); other orientations are not ours.
        Out of the sensor's own [min, max] or of signal quality 1 ('invalid'): not valid.
        Covariance in cm^2, UINT8_MAX unknown (then the sensor's 1 cm resolution)."""
        if message.orientation != mavlink.MAV_SENSOR_ROTATION_PITCH_270:
            return True
        distance = message.current_distance * 1e-2
        if not (math.isfinite(distance) and distance >= 0.0):
            return False
        valid = message.min_distance <= message.current_distance <= message.max_distance \
            and getattr(message, "signal_quality", 0) != 1
        var = message.covariance * 1e-4 if message.covariance != 255 else 1e-4
        with self._state_lock:
            self._state = dc.replace(self._state, range_t_fc=message.time_boot_ms * 1e-3,
                                     range=distance, range_var=var, range_valid=bool(valid))
        return True

    def _on_highres_imu(self, message, now) -> bool:
        if self.params.imu_message != "HIGHRES_IMU":
            return True  # one IMU stream only: two would interleave two clocks' samples
        if message.fields_updated & 0b111111 != 0b111111:
            return True  # not an accelerometer + gyroscope update (e.g. a magnetometer-only one)
        return self._add_imu(message.time_usec * 1e-6,
                             [message.xacc, message.yacc, message.zacc],
                             [message.xgyro, message.ygyro, message.zgyro])

    def _on_scaled_imu(self, message, now) -> bool:
        if self.params.imu_message != "SCALED_IMU":
            return True
        return self._add_imu(message.time_boot_ms * 1e-3,
                             MILLI_G * np.array([message.xacc, message.yacc, message.zacc]),
                             1e-3 * np.array([message.xgyro, message.ygyro, message.zgyro]))

    def _add_imu(self, t_fc: float, accel_F, gyro_F) -> bool:
        accel, gyro = np.asarray(accel_F, float), np.asarray(gyro_F, float)
        if not (math.isfinite(t_fc) and np.all(np.isfinite(accel)) and np.all(np.isfinite(gyro))
                and np.max(np.abs(accel)) < _MAX_ACCEL and np.max(np.abs(gyro)) < _MAX_RATE):
            return False
        with self._imu_lock:
            if t_fc <= self._last_imu_t_fc:  # repeated or late: each sample crosses once
                self._imu_backwards += 1
                self.imu_out_of_order += 1
                if self._imu_backwards < 50:
                    return False
                LOG.warning("autopilot IMU time went back for 50 samples: clock restarted?")
            self._imu_backwards = 0
            self._last_imu_t_fc = t_fc
            if len(self._imu) >= self.params.imu_queue:
                self._imu.popleft()
                self.imu_overflow += 1
            self._imu.append(ImuSample(t_fc, frd_to_b(accel), frd_to_b(gyro)))
        return True

    def _on_command_ack(self, message, now) -> bool:
        with self._ack_condition:
            self._acks[message.command] = (message.result, now)
            self._ack_condition.notify_all()
        return True

    def _on_statustext(self, message, now) -> bool:
        text = message.text.decode("utf-8", "replace") if isinstance(message.text, bytes) \
            else str(message.text)
        text = "".join(c if c.isprintable() else "?" for c in text.strip("\x00"))
        self.status_texts.append((now, message.severity, text.strip("\x00").strip()))
        if message.severity <= mavlink.MAV_SEVERITY_WARNING:
            LOG.warning("flight controller: %s", text)
        return True

    def _timesync_reply(self, message, now: float) -> None:
        if not self.timesync.reply(message.tc1, message.ts1, self.clock.scaled_ns()):
            with self._counter_lock:
                self.counters.rejected += 1

    # --- what the ports read ----------------------------------------------------------------------
    def state(self) -> AutopilotState:
        with self._state_lock:
            return self._state

    def link_alive(self, now: float | None = None) -> bool:
        now = time.monotonic() if now is None else now
        state = self.state()
        return now - state.heartbeat_time <= self.params.heartbeat_timeout \
            and now - state.message_time <= self.params.link_timeout

    def take_imu(self, max_count: int | None = None) -> list[ImuSample]:
        """The IMU samples received and not yet taken, oldest first (each returned once); at
        most `max_count`, the rest wait for the next call."""
        with self._imu_lock:
            count = len(self._imu) if max_count is None else min(max_count, len(self._imu))
            return [self._imu.popleft() for _ in range(count)]

    def to_local(self, t_fc: float) -> float:
        """An autopilot time [s] on our clock (`clock.now()` seconds); NaN until TIMESYNC locks."""
        offset = self._frozen_offset_ns if self._frozen_offset_ns is not None \
            else self.timesync.offset_ns
        if offset is None:
            return math.nan
        return self.clock.from_scaled(t_fc - offset * 1e-9)

    def follow_autopilot_clock(self) -> None:
        """From now on map autopilot times with the current TIMESYNC offset, unrefined: onboard
        time then is the autopilot's time plus a constant, as the runner's `pace` needs when it
        follows a simulated autopilot (`autopilot_time`). Not for a real flight controller."""
        if not self.timesync.locked:
            raise LinkTimeout("no TIMESYNC lock: cannot follow the autopilot's clock")
        self._frozen_offset_ns = self.timesync.offset_ns

    def autopilot_time(self) -> float:
        """The newest IMU time received from the autopilot, on our clock (NaN before one)."""
        return self.to_local(self._last_imu_t_fc) if math.isfinite(self._last_imu_t_fc) \
            else math.nan

    # --- commands --------------------------------------------------------------------------
    def command(self, command: int, *params: float, timeout: float | None = None) -> int:
        """Sends COMMAND_LONG and waits for its COMMAND_ACK, resending (confirmation 1, 2, ...)
        when none comes. Returns MAV_RESULT_ACCEPTED or raises CommandDenied / LinkTimeout."""
        values = [float(p) for p in params] + [0.0] * (7 - len(params))
        timeout = self.params.command_timeout if timeout is None else timeout
        for confirmation in range(self.params.command_attempts):
            sent_at = time.monotonic()
            with self._ack_condition:
                self._acks.pop(command, None)
            self.send(self.mav.command_long_encode(
                self.params.target_system, self.params.target_component, command,
                confirmation, *values))
            deadline = sent_at + timeout
            with self._ack_condition:
                while True:
                    ack = self._acks.get(command)
                    if ack is not None and ack[0] == mavlink.MAV_RESULT_IN_PROGRESS:
                        deadline = time.monotonic() + timeout  # keep waiting while it works
                        self._acks.pop(command)
                        ack = None
                    if ack is not None:
                        break
                    remaining = deadline - time.monotonic()
                    if remaining <= 0:
                        break
                    self._ack_condition.wait(remaining)
            if ack is None:
                continue
            if ack[0] == mavlink.MAV_RESULT_ACCEPTED:
                return ack[0]
            raise CommandDenied(command, ack[0], self._recent_text(sent_at))
        raise LinkTimeout(f"{px4.command_name(command)}: no acknowledgement from the flight "
                          f"controller after {self.params.command_attempts} attempts "
                          f"({timeout:.2f} s each) on {self.name or 'the link'}")

    def _recent_text(self, since: float) -> str:
        texts = [text for t, _, text in list(self.status_texts) if t >= since - 0.05]
        return texts[-1] if texts else ""

    def arm(self) -> None:
        self.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1.0)

    def disarm(self, force: bool = False) -> None:
        self.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0.0, px4.FORCE_DISARM if force else 0)

    def set_mode(self, custom_mode: int) -> None:
        main, sub = px4.split_custom_mode(custom_mode)
        self.command(mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                     main, sub)

    def land(self) -> None:
        """PX4 AUTO.LAND: the flight controller descends and disarms on its own."""
        self.command(mavlink.MAV_CMD_NAV_LAND, 0, 0, 0, math.nan, math.nan, math.nan, math.nan)

    def request_message_rates(self) -> dict[str, str]:
        """MAV_CMD_SET_MESSAGE_INTERVAL for the IMU, attitude, status and rangefinder streams; the
        answer per
        message ("ok" or the refusal, which is logged, not raised: streams may come anyway)."""
        imu_id = mavlink.MAVLINK_MSG_ID_HIGHRES_IMU if self.params.imu_message == "HIGHRES_IMU" \
            else mavlink.MAVLINK_MSG_ID_SCALED_IMU
        rates = {imu_id: self.params.imu_rate,
                 mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: self.params.attitude_rate,
                 mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: self.params.status_rate,
                 mavlink.MAVLINK_MSG_ID_DISTANCE_SENSOR: self.params.range_rate}
        answers = {}
        for message_id, rate in rates.items():
            name = mavlink.mavlink_map[message_id].msgname
            try:
                self.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, message_id, 1e6 / rate)
                answers[name] = "ok"
            except (CommandDenied, LinkTimeout) as e:
                LOG.warning("%s at %.0f Hz not set: %s", name, rate, e)
                answers[name] = str(e)
        return answers

    def wait_for_autopilot(self, timeout: float = 10.0) -> AutopilotState:
        """Blocks until the autopilot's heartbeat and a TIMESYNC lock; LinkTimeout otherwise."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.state().heartbeat_time > -math.inf and self.timesync.locked:
                return self.state()
            time.sleep(0.01)
        what = "no heartbeat" if self.state().heartbeat_time == -math.inf else "no TIMESYNC reply"
        raise LinkTimeout(f"{what} from the flight controller (system {self.params.target_system}"
                          f", component {self.params.target_component}) on "
                          f"{self.name or 'the link'} within {timeout:.0f} s: is it running, and "
                          f"is the connection string right?")

    # --- setpoints -------------------------------------------------------------------------
    def send_attitude_target(self, command: np.ndarray) -> None:
        """One SET_ATTITUDE_TARGET from a checked FC_COMMAND: attitude+thrust ignores the body
        rates (type mask 7), rates+thrust ignores the attitude (type mask 128)."""
        mode = int(FC_COMMAND.get(command, "mode"))
        if mode == CommandMode.ATTITUDE_THRUST:
            q_WD = FC_COMMAND.get(command, "q_WD")
            q = q_wb_to_nf(q_WD / np.linalg.norm(q_WD))
            rates = np.zeros(3)
            type_mask = (mavlink.ATTITUDE_TARGET_TYPEMASK_BODY_ROLL_RATE_IGNORE
                         | mavlink.ATTITUDE_TARGET_TYPEMASK_BODY_PITCH_RATE_IGNORE
                         | mavlink.ATTITUDE_TARGET_TYPEMASK_BODY_YAW_RATE_IGNORE)
        else:
            q = np.array([1.0, 0.0, 0.0, 0.0])
            rates = b_to_frd(FC_COMMAND.get(command, "w_D"))
            type_mask = mavlink.ATTITUDE_TARGET_TYPEMASK_ATTITUDE_IGNORE
        stamp_ms = int(max(0.0, FC_COMMAND.get(command, "stamp")) * 1e3) & 0xFFFFFFFF
        self.send(self.mav.set_attitude_target_encode(
            stamp_ms, self.params.target_system, self.params.target_component, type_mask,
            [float(v) for v in q], *[float(v) for v in rates],
            float(FC_COMMAND.get(command, "thrust"))))
        now = time.monotonic()
        if now - self._last_setpoint > 0.5:
            self._stream_start = now
        self._last_setpoint = now
        self.setpoints_sent += 1

    def stream_age(self) -> float:
        """How long the current setpoint stream has run [s] (0 when none is running)."""
        now = time.monotonic()
        return now - self._stream_start if now - self._last_setpoint <= 0.5 else 0.0

    def start_offboard_and_arm(self, min_stream: float = 0.3, wait: float = 2.0) -> None:
        """PX4's order: a running setpoint stream, then OFFBOARD, then arm."""
        deadline = time.monotonic() + wait
        while self.stream_age() < min_stream:
            if time.monotonic() > deadline:
                raise LinkTimeout(f"no setpoint stream for {min_stream:.1f} s: PX4 refuses "
                                  f"OFFBOARD without one")
            time.sleep(0.01)
        if not self.state().offboard:
            self.set_mode(px4.OFFBOARD)
        self.arm()

    def safe_stop(self) -> str:
        """The final safe command: nothing when disarmed, disarm on the ground, land in the air."""
        state = self.state()
        if not self.link_alive():
            return "link lost: the flight controller's own failsafe applies"
        if not state.armed:
            return "disarmed: nothing to do"
        try:
            if state.landed:
                self.disarm()
                return "on the ground: disarmed"
            self.land()
            return "in the air: AUTO.LAND (failsafe descent) accepted"
        except (CommandDenied, LinkTimeout) as e:
            return f"final command refused ({e}); setpoints stop, PX4's offboard-loss " \
                   f"failsafe applies"


_HANDLERS = {
    "HEARTBEAT": MavlinkLink._on_heartbeat,
    "ATTITUDE_QUATERNION": MavlinkLink._on_attitude,
    "EXTENDED_SYS_STATE": MavlinkLink._on_extended_sys_state,
    "HIGHRES_IMU": MavlinkLink._on_highres_imu,
    "SCALED_IMU": MavlinkLink._on_scaled_imu,
    "DISTANCE_SENSOR": MavlinkLink._on_distance_sensor,
    "COMMAND_ACK": MavlinkLink._on_command_ack,
    "STATUSTEXT": MavlinkLink._on_statustext,
}
