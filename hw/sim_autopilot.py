"""The simulated autopilot (`alight sim-autopilot`): the simulated vehicle (plant, flight-controller
emulation, sensors) run in real time behind a PX4-flavoured MAVLink endpoint, so that the
companion side (`alight hil`, or any MAVLink client such as MAVSDK) flies it as a real Pixhawk.

It speaks: HEARTBEAT (PX4 autopilot, hexarotor, PX4 custom modes), HIGHRES_IMU / SCALED_IMU (each
IMU sample once, stamped with the simulation's clock), ATTITUDE_QUATERNION, ATTITUDE,
EXTENDED_SYS_STATE, SYS_STATUS, DISTANCE_SENSOR (the downward rangefinder), AUTOPILOT_VERSION,
TIMESYNC answers, COMMAND_ACK and STATUSTEXT;
it obeys SET_ATTITUDE_TARGET (attitude+thrust and rates+thrust), MAV_CMD_COMPONENT_ARM_DISARM,
MAV_CMD_DO_SET_MODE, MAV_CMD_NAV_LAND, MAV_CMD_SET_MESSAGE_INTERVAL, MAV_CMD_REQUEST_MESSAGE and
MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, with the PX4 rules of hw/autopilot_rules.py; it answers a
ground station's parameter and mission requests (hw/ground_station.py). Camera
frames and the simulated world's mocap estimate (the `mocap` sensor model of DESIGN.md: true pose
plus noise and latency) go to the onboard side over the local frame channel (hw/frame_channel.py).
External vision (ODOMETRY, as PX4's receiver filters it, hw/external_vision.py) goes to the
simulated flight controller's `odometry` input, whose EKF2 emulation
(systems/autopilot/ev_fusion.py) makes the local position sent as LOCAL_POSITION_NED and
ODOMETRY (PX4's own, MAV_FRAME_LOCAL_NED) and held by Hold, Position and the offboard-loss
failsafe; LANDING_TARGET messages PX4 would use
are logged in the run folder (`landing_target`), with the local position (`local_position`).
The world is the vehicle config's: with a landing scenario's (diagrams/scenario.py
`vehicle_config`), the moving target, the down camera and the wind.

Like PX4 SITL, it can run two MAVLink instances (`--listen`, the offboard/companion link, PX4's
udp 14540; `--gcs`, the ground-station link, PX4's udp 14550): each link is its own endpoint with
its own peer, MAVLink version (hw/endpoint.py) and stream rates (SET_MESSAGE_INTERVAL and
REQUEST_MESSAGE act on the link they came on, as on PX4's per-instance streams); both get the
telemetry, HEARTBEAT and STATUSTEXT; a command, parameter or mission request is answered on the
link it came from; both links' commands and setpoints go to the same flight controller.
"""
import collections
import dataclasses as dc
import json
import math
import queue
import threading
import time
from pathlib import Path

import numpy as np
from pydrake.common.eigen_geometry import Quaternion
from pydrake.common.value import AbstractValue
from pydrake.math import RollPitchYaw, RotationMatrix
from pydrake.systems.framework import DiagramBuilder, LeafSystem
from pymavlink.dialects.v20 import common as mavlink

from alight.diagrams.onboard.mocap import add_mocap
from alight.diagrams.running.paths import default_run_dir
from alight.diagrams.running.run_log import add_run_logging, open_run_folder, write_run_folder
from alight.diagrams.world.sim_vehicle import make_sim_vehicle
from alight.diagrams.world.visualization import (add_vehicle_flight_view, start_recording,
                                                 write_recording)
from alight.hw.autopilot_rules import (ACCEPTED, UNSUPPORTED, Answer, AutopilotRules,
                                      Px4RulesParams)
from alight.hw.connection import open_connection
from alight.hw.endpoint import LOG, MavlinkEndpoint, addressed_to
from alight.hw.external_vision import (LANDING_TARGET_RECEIVED, decode_landing_target,
                                      decode_odometry, odometry_message)
from alight.hw.frame_channel import EstimateSample, FramePublisher
from alight.hw.ground_station import GroundStationService, emulated_parameters
from alight.hw.frames import b_to_frd, q_wb_to_nf, w_to_ned
from alight.hw.link import MILLI_G
from alight.models import model_path
from alight.systems.boundary import (FC_ATTITUDE, FC_COMMAND, FC_STATUS, RANGE, STATE_ESTIMATE,
                                     ActiveMode, CameraFrame, ImuSamples)
from alight.systems.autopilot.ev_fusion import LOCAL_POSITION
from alight.systems.params import bounded, load_params
from alight.systems.sensors.mocap import MocapParams

# Telemetry streams and their default rates [Hz] (PX4's "onboard" MAVLink mode, roughly).
STREAMS = {
    "HIGHRES_IMU": 50.0, "SCALED_IMU": 0.0, "ATTITUDE_QUATERNION": 50.0, "ATTITUDE": 50.0,
    "EXTENDED_SYS_STATE": 5.0, "SYS_STATUS": 1.0, "LOCAL_POSITION_NED": 30.0, "ODOMETRY": 30.0,
    "DISTANCE_SENSOR": 50.0,
}
_STREAM_IDS = {mavlink.mavlink_map[i].msgname: i for i in mavlink.mavlink_map
               if mavlink.mavlink_map[i].msgname in STREAMS}
_ONE_SHOT = {"AUTOPILOT_VERSION", "ATTITUDE_QUATERNION", "ATTITUDE", "EXTENDED_SYS_STATE",
             "SYS_STATUS"}
_CAPABILITIES = (mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
                 | mavlink.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET
                 | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
                 | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT
                 | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE)


@dc.dataclass
class SimAutopilotParams:
    """models/sim_autopilot.yaml."""
    system_id: int = bounded(1, 1, 255)
    component_id: int = bounded(1, 1, 255)        # MAV_COMP_ID_AUTOPILOT1
    period: float = bounded(0.002, 0.0005, 0.05, "s")  # bridge tick: link <-> simulation
    heartbeat_period: float = bounded(1.0, 0.1, 10.0, "s")
    # A client silent this long may be replaced by another address (hw/endpoint.py, the peer rule)
    peer_timeout: float = bounded(3.0, 0.1, 60.0, "s")
    highres_imu_rate: float = bounded(STREAMS["HIGHRES_IMU"], 0.0, 4000.0, "Hz")  # 0: off
    scaled_imu_rate: float = bounded(STREAMS["SCALED_IMU"], 0.0, 4000.0, "Hz")
    attitude_quaternion_rate: float = bounded(STREAMS["ATTITUDE_QUATERNION"], 0.0, 1000.0, "Hz")
    attitude_rate: float = bounded(STREAMS["ATTITUDE"], 0.0, 1000.0, "Hz")
    extended_sys_state_rate: float = bounded(STREAMS["EXTENDED_SYS_STATE"], 0.0, 100.0, "Hz")
    sys_status_rate: float = bounded(STREAMS["SYS_STATUS"], 0.0, 100.0, "Hz")
    # the local position (sent only while valid, as PX4)
    local_position_ned_rate: float = bounded(STREAMS["LOCAL_POSITION_NED"], 0.0, 1000.0, "Hz")
    odometry_rate: float = bounded(STREAMS["ODOMETRY"], 0.0, 1000.0, "Hz")
    distance_sensor_rate: float = bounded(STREAMS["DISTANCE_SENSOR"], 0.0, 1000.0, "Hz")
    # PX4 commander/position-control parameters of the rules (COM_OBL_RC_ACT, MPC_*)
    rules: Px4RulesParams = dc.field(default_factory=Px4RulesParams)

    def default_rates(self) -> dict[str, float]:
        return {name: getattr(self, f"{name.lower()}_rate") for name in STREAMS}


def load_sim_autopilot_params(filename: str = "sim_autopilot.yaml") -> SimAutopilotParams:
    return load_params(SimAutopilotParams, model_path(filename))


class SimClock:
    """The autopilot's clock (the simulation's time) as seen from other threads: the time of the
    last bridge tick plus the wall time since, times the real-time rate (1 unless slowed); None
    before the first tick (the simulation has not started: TIMESYNC is not answered)."""

    def __init__(self, rate: float = 1.0):
        self._t, self._wall = None, time.monotonic()
        self._rate = rate
        self._lock = threading.Lock()

    def tick(self, t: float) -> None:
        with self._lock:
            self._t, self._wall = t, time.monotonic()

    def now(self) -> float | None:
        with self._lock:
            if self._t is None:
                return None
            return self._t + (time.monotonic() - self._wall) * self._rate


@dc.dataclass
class LinkStatistics:
    """What the autopilot measured of its peer: setpoint arrival times and, when the peer echoes
    an IMU sample's gyro back as its body-rate setpoint (bench/mavlink_loop.py), the round trip
    from that IMU message leaving to the command computed from it arriving."""
    setpoint_arrivals: collections.deque = dc.field(
        default_factory=lambda: collections.deque(maxlen=200000))
    round_trips: list = dc.field(default_factory=list)
    _gyro_sent: collections.OrderedDict = dc.field(default_factory=collections.OrderedDict)

    def imu_sent(self, gyro_frd, wall: float) -> None:
        self._gyro_sent[tuple(np.float32(gyro_frd))] = wall
        while len(self._gyro_sent) > 4000:
            self._gyro_sent.popitem(last=False)

    def setpoint_arrived(self, message, wall: float) -> None:
        self.setpoint_arrivals.append(wall)
        if message.type_mask & mavlink.ATTITUDE_TARGET_TYPEMASK_ATTITUDE_IGNORE:
            key = tuple(np.float32([message.body_roll_rate, message.body_pitch_rate,
                                    message.body_yaw_rate]))
            sent = self._gyro_sent.pop(key, None)
            if sent is not None:
                self.round_trips.append(wall - sent)

    def summary(self) -> dict:
        arrivals = np.array(self.setpoint_arrivals)
        intervals = np.diff(arrivals)
        summary = {"setpoints": int(len(arrivals))}
        if len(intervals):
            summary.update(setpoint_rate=float(1.0 / np.mean(intervals)),
                           interval_mean=float(np.mean(intervals)),
                           interval_std=float(np.std(intervals)),
                           interval_p99=float(np.percentile(intervals, 99)),
                           interval_max=float(np.max(intervals)))
        if self.round_trips:
            trips = np.array(self.round_trips)
            summary.update(round_trips=int(len(trips)), round_trip_median=float(np.median(trips)),
                           round_trip_p99=float(np.percentile(trips, 99)),
                           round_trip_max=float(np.max(trips)))
        return summary


class AutopilotEndpoint(MavlinkEndpoint):
    """The autopilot's end of the link: takes what is addressed to it, answers TIMESYNC at once
    with the simulation's clock, and queues the rest for the bridge's next tick."""

    def __init__(self, transport, params: SimAutopilotParams, clock: SimClock, datagrams: bool):
        super().__init__(transport, params.system_id, params.component_id, datagrams,
                         params.peer_timeout)
        self.clock = clock
        self.inbox: queue.SimpleQueue = queue.SimpleQueue()
        self.statistics = LinkStatistics()
        self.peer_heartbeat = -math.inf

    @classmethod
    def open(cls, url: str, params: SimAutopilotParams, clock: SimClock) -> "AutopilotEndpoint":
        transport = open_connection(url, "listen")
        return cls(transport, params, clock,
                   datagrams=url.split(":", 1)[0] in ("udp", "udpin", "udpout")).start()

    def clock_ns(self) -> int | None:
        now = self.clock.now()
        return None if now is None else int(now * 1e9)

    def _accepts(self, message) -> bool:
        header = message.get_header()
        return (header.srcSystem, header.srcComponent) != (self.system_id, self.component_id) \
            and addressed_to(message, self.system_id, self.component_id)

    def _handle(self, message, now: float) -> bool:
        kind = message.get_type()
        if kind == "HEARTBEAT":
            self.peer_heartbeat = now
        elif kind == "SET_ATTITUDE_TARGET":
            self.statistics.setpoint_arrived(message, now)
            self.inbox.put(message)
        elif kind in ("ODOMETRY", "LANDING_TARGET"):
            self.inbox.put(message)
        elif kind in ("COMMAND_LONG", "COMMAND_INT") or kind in GroundStationService.KINDS:
            self.inbox.put(message)
        return True

    def count_rejected(self) -> None:
        with self._counter_lock:
            self.counters.rejected += 1


class AutopilotLink:
    """One MAVLink instance of the autopilot: its endpoint and its own telemetry streams (rates,
    next send times, one-shot requests), as each of PX4's MAVLink instances has."""

    def __init__(self, endpoint: AutopilotEndpoint, default_rates: dict[str, float]):
        self.endpoint = endpoint
        self._default_rates = default_rates
        self.intervals = {name: _interval(rate) for name, rate in default_rates.items()}
        self.next_send = {name: 0.0 for name in STREAMS}
        self.one_shots: set[str] = set()
        self.last_imu_sent = {"HIGHRES_IMU": -math.inf, "SCALED_IMU": -math.inf}

    def due(self, name: str, now: float) -> bool:
        """A stream message is due on this link (or was requested once)."""
        interval = self.intervals[name]
        if name in self.one_shots:
            return True
        if interval is None or now < self.next_send[name]:
            return False
        self.next_send[name] = max(self.next_send[name] + interval, now)
        return True

    def imu_due(self, name: str, t: float) -> bool:
        """The IMU sample at `t` goes out as `name` on this link (each sample at most once)."""
        interval = self.intervals[name]
        if interval is None or t - self.last_imu_sent[name] < interval - 1e-4:
            return False
        self.last_imu_sent[name] = t
        return True

    def set_interval(self, params) -> Answer:
        """MAV_CMD_SET_MESSAGE_INTERVAL: 0 restores the default rate, < 0 stops the stream."""
        message_id, interval_us = params[0], params[1]
        entry = mavlink.mavlink_map.get(int(message_id)) if math.isfinite(message_id) else None
        if entry is None or entry.msgname not in STREAMS or not math.isfinite(interval_us):
            return Answer(UNSUPPORTED)
        name = entry.msgname
        if interval_us == 0:
            self.intervals[name] = _interval(self._default_rates[name])
        elif interval_us < 0:
            self.intervals[name] = None
        else:
            self.intervals[name] = interval_us * 1e-6
        return Answer(ACCEPTED)


def _interval(rate: float) -> float | None:
    return 1.0 / rate if rate > 0 else None


class AutopilotBridge(LeafSystem):
    """Input  `imu`, `fc_attitude`, `fc_status`, `range`, `rgbd`, `down_image` from the simulated
           vehicle
    Input  `mocap` STATE_ESTIMATE of the world's mocap system (published on the frame channel)
    Output `fc_command` FC_COMMAND to the simulated vehicle
    Every `period`: handles what the links received (rules of hw/autopilot_rules.py), updates
    `fc_command`, sends each link the telemetry that is due on it (each new IMU sample once) and
    publishes new camera frames and mocap samples on the frame channel, if any. `endpoints`: the
    companion link first (its clock is the autopilot's), then a ground-station link, if any."""

    def __init__(self, endpoints: list[AutopilotEndpoint], params: SimAutopilotParams,
                 rules: AutopilotRules, command_period: float, imu_period: float,
                 frames: FramePublisher | None = None,
                 ground_station: GroundStationService | None = None, max_range: float = 40.0):
        super().__init__()
        self._endpoint, self._params, self._rules, self._frames = endpoints[0], params, rules, \
            frames
        self._max_range_cm = int(round(max_range * 100))  # the rangefinder's, DISTANCE_SENSOR
        self._links = [AutopilotLink(e, params.default_rates()) for e in endpoints]
        self._ground_station = ground_station
        self._command_period, self._imu_period = command_period, imu_period
        self._imu = self.DeclareAbstractInputPort("imu", AbstractValue.Make(ImuSamples.empty()))
        self._attitude = self.DeclareVectorInputPort("fc_attitude", FC_ATTITUDE.size)
        self._status = self.DeclareVectorInputPort("fc_status", FC_STATUS.size)
        self._range = self.DeclareVectorInputPort("range", RANGE.size)
        self._cameras = {name: self.DeclareAbstractInputPort(
            name, AbstractValue.Make(CameraFrame())) for name in ("rgbd", "down_image")}
        self._mocap = self.DeclareVectorInputPort("mocap", STATE_ESTIMATE.size)
        self._local_position = self.DeclareVectorInputPort("local_position",
                                                           LOCAL_POSITION.size)
        # External vision received (W, autopilot clock) for the FC; LANDING_TARGETs PX4 uses.
        self._odometry = self.DeclareDiscreteState(STATE_ESTIMATE.vector(valid=0.0))
        self.DeclareStateOutputPort("odometry", self._odometry)
        self._landing_target = self.DeclareDiscreteState(
            LANDING_TARGET_RECEIVED.vector(stamp=-1.0, sent=-1.0))
        self.DeclareStateOutputPort("landing_target", self._landing_target)
        self._received: dict[str, np.ndarray] = {}
        initial = FC_COMMAND.pack(stamp=0.0, mode=1, q_WD=[1, 0, 0, 0], w_D=np.zeros(3),
                                  thrust=0.0, arm=0.0)
        self._command = self.DeclareDiscreteState(initial)
        self.DeclarePeriodicDiscreteUpdateEvent(params.period, 0.0, self._update)
        self.DeclareStateOutputPort("fc_command", self._command)
        self._next_heartbeat = self._next_command = self._next_imu = 0.0
        self._last_heartbeat = None
        self._next_heartbeat_wall = 0.0
        self._next_frames = 0.0
        self._last_imu_seq = -1
        self._frame_stamps = {name: -math.inf for name in self._cameras}
        self._mocap_stamp = -math.inf

    def _update(self, context, discrete_state):
        """Cheap when nothing is due: this runs every `period` (2 ms) in real time."""
        now = context.get_time()
        self._endpoint.clock.tick(now)
        received = any(not link.endpoint.inbox.empty() for link in self._links)
        if received or now >= self._next_command:  # the flight controller's rate, or at once
            status = self._status.Eval(context)
            if received:
                self._handle_inbox(now, status)
                self._store_received(context, discrete_state, now)
            discrete_state.set_value(self._command, self._rules.fc_command(
                now, status, self._attitude.Eval(context), self._local_position.Eval(context)))
            for text in self._rules.notices:  # the failsafe actions, told as PX4 tells them
                self._broadcast(self._endpoint.mav.statustext_encode(
                    mavlink.MAV_SEVERITY_CRITICAL, text.encode()[:50]))
            self._rules.notices.clear()
            if self._rules.heartbeat(status) != self._last_heartbeat:
                self._next_heartbeat = now  # armed or mode changed: tell the client at once
            self._next_command = now + self._command_period - 1e-9
        self._send_telemetry(context, now)
        if self._frames is not None:
            self._publish_mocap(context)
            if now >= self._next_frames:
                self._publish_frames(context)
                self._next_frames = now + 0.005

    # --- link -> simulation ----------------------------------------------------------------
    def _handle_inbox(self, now, status):
        for link in self._links:
            self._handle_link_inbox(link, now, status)

    def _handle_link_inbox(self, link: AutopilotLink, now, status):
        """What `link` received; answers go back on it, STATUSTEXT to every link (PX4's log)."""
        endpoint, mav = link.endpoint, link.endpoint.mav
        while True:
            try:
                message = endpoint.inbox.get_nowait()
            except queue.Empty:
                return
            if message.get_type() == "SET_ATTITUDE_TARGET":
                if not self._rules.setpoint_received(message, now):
                    endpoint.count_rejected()
                continue
            if message.get_type() in GroundStationService.KINDS:
                for reply in (self._ground_station.answer(message) if self._ground_station
                              else None) or []:
                    endpoint.send(reply)
                continue
            if message.get_type() in ("ODOMETRY", "LANDING_TARGET"):
                decoded = (decode_odometry if message.get_type() == "ODOMETRY"
                           else decode_landing_target)(message)
                if decoded is None:  # PX4 would not use it (frame, source)
                    endpoint.count_rejected()
                else:
                    self._received[message.get_type()] = (decoded, message)
                continue
            params = [message.param1, message.param2, message.param3, message.param4]
            if message.get_type() == "COMMAND_LONG":
                params += [message.param5, message.param6, message.param7]
            answer = self._command_answer(link, message.command, params, now, status)
            header = message.get_header()
            if answer.text:
                severity = mavlink.MAV_SEVERITY_INFO if answer.result == ACCEPTED \
                    else mavlink.MAV_SEVERITY_CRITICAL
                self._broadcast(mav.statustext_encode(severity, answer.text.encode()[:50]))
            endpoint.send(mav.command_ack_encode(message.command, answer.result, 0, 0,
                                                 header.srcSystem, header.srcComponent))

    def _store_received(self, context, discrete_state, now):
        """The newest external vision and landing target of this tick into state."""
        if "ODOMETRY" in self._received:
            discrete_state.set_value(self._odometry, self._received["ODOMETRY"][0])
        if "LANDING_TARGET" in self._received:
            p_WT, message = self._received["LANDING_TARGET"]
            count = LANDING_TARGET_RECEIVED.get(
                context.get_discrete_state(self._landing_target).get_value(), "count")
            discrete_state.set_value(self._landing_target, LANDING_TARGET_RECEIVED.vector(
                stamp=now, sent=message.time_usec * 1e-6, p_WT=p_WT, count=count + 1))
        self._received.clear()

    def _command_answer(self, link: AutopilotLink, command, params, now, status):
        if command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
            return link.set_interval(params)
        if command in (mavlink.MAV_CMD_REQUEST_MESSAGE,
                       mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES):
            message_id = 148 if command == mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES \
                else int(params[0]) if math.isfinite(params[0]) else -1
            entry = mavlink.mavlink_map.get(message_id)
            if entry is None or entry.msgname not in _ONE_SHOT:
                return Answer(UNSUPPORTED)
            link.one_shots.add(entry.msgname)
            return Answer(ACCEPTED)
        return self._rules.command(command, params, now, status)

    # --- simulation -> link ----------------------------------------------------------------
    def _broadcast(self, message) -> None:
        """`message` on every link (each in its peer's MAVLink version, its own sequence)."""
        for link in self._links:
            link.endpoint.send(message)

    def _send_telemetry(self, context, now):
        mav = self._endpoint.mav
        wall = time.monotonic()
        if now >= self._next_heartbeat or wall >= self._next_heartbeat_wall:
            self._last_heartbeat = self._rules.heartbeat(self._status.Eval(context))
            base_mode, custom_mode, system_status = self._last_heartbeat
            # HIL_ENABLED: the vehicle is simulated (PX4 sets it with SYS_HITL = 1); a companion
            # then follows this clock (hw/hil.py)
            self._broadcast(mav.heartbeat_encode(mavlink.MAV_TYPE_HEXAROTOR,
                                                 mavlink.MAV_AUTOPILOT_PX4,
                                                 base_mode | mavlink.MAV_MODE_FLAG_HIL_ENABLED,
                                                 custom_mode, system_status))
            self._next_heartbeat = now + self._params.heartbeat_period
            # Also by the wall clock: a simulation running behind real time still shows it lives.
            self._next_heartbeat_wall = wall + self._params.heartbeat_period
        if now >= self._next_imu:  # a new sample is due (the IMU updates every imu_period)
            new = self._imu.Eval(context).newer_than(self._last_imu_seq)
            if len(new):
                self._send_imu(new)
                self._next_imu = float(new.t[-1]) + self._imu_period
        built = {}  # this tick's messages, built once for every link they are due on
        for link in self._links:
            for name in ("ATTITUDE_QUATERNION", "ATTITUDE", "EXTENDED_SYS_STATE", "SYS_STATUS",
                         "LOCAL_POSITION_NED", "ODOMETRY", "DISTANCE_SENSOR"):
                if link.due(name, now):
                    if name not in built:
                        built[name] = self._stream_message(name, context)
                    if built[name] is not None:
                        link.endpoint.send(built[name])
            if "AUTOPILOT_VERSION" in link.one_shots:
                link.endpoint.send(mav.autopilot_version_encode(
                    _CAPABILITIES, 0, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, 0))
            link.one_shots.clear()

    def _stream_message(self, name: str, context):
        """The stream message `name` now (None: nothing to send, e.g. no valid position)."""
        mav = self._endpoint.mav
        if name in ("LOCAL_POSITION_NED", "ODOMETRY"):
            return self._local_position_message(name, context)
        if name == "DISTANCE_SENSOR":
            return self._distance_sensor_message(context)
        if name == "EXTENDED_SYS_STATE":
            return mav.extended_sys_state_encode(mavlink.MAV_VTOL_STATE_UNDEFINED,
                                                 _landed_state(self._status.Eval(context)))
        if name == "SYS_STATUS":
            sensors = (mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO
                       | mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL
                       | mavlink.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
                       | mavlink.MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL
                       | mavlink.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS)
            return mav.sys_status_encode(sensors, sensors, sensors, 0, 65535, -1, -1,
                                         0, 0, 0, 0, 0, 0)
        attitude = self._attitude.Eval(context)
        q_NF = q_wb_to_nf(FC_ATTITUDE.get(attitude, "q_WB"))
        w_F = b_to_frd(FC_ATTITUDE.get(attitude, "w_B"))
        time_ms = int(FC_ATTITUDE.get(attitude, "stamp") * 1e3)
        if name == "ATTITUDE_QUATERNION":
            return mav.attitude_quaternion_encode(time_ms, *q_NF, *w_F)
        rpy = RollPitchYaw(RotationMatrix(Quaternion(q_NF / np.linalg.norm(q_NF))))
        return mav.attitude_encode(time_ms, *rpy.vector(), *w_F)

    def _distance_sensor_message(self, context):
        """The rangefinder's last measurement as PX4 sends it: cm, downward (PITCH_270), its
        range limits [min 1 cm, max_range]; out of range or too tilted: quality 1 (invalid).
        None before the first measurement."""
        distance = self._range.Eval(context)
        stamp = RANGE.get(distance, "stamp")
        if stamp <= 0.0:
            return None
        valid = RANGE.get(distance, "valid") > 0.5
        centimetres = int(min(max(round(RANGE.get(distance, "range") * 100), 0), 65535))
        covariance = int(min(round(RANGE.get(distance, "var") * 1e4), 254))
        return self._endpoint.mav.distance_sensor_encode(
            int(stamp * 1e3), 1, self._max_range_cm, centimetres,
            mavlink.MAV_DISTANCE_SENSOR_LASER, 0, mavlink.MAV_SENSOR_ROTATION_PITCH_270,
            covariance, signal_quality=100 if valid else 1)

    def _local_position_message(self, name: str, context):
        """PX4's vehicle_local_position as LOCAL_POSITION_NED or ODOMETRY (LOCAL_NED), only
        while it is valid (else None)."""
        position = self._local_position.Eval(context)
        if LOCAL_POSITION.get(position, "valid") < 0.5:
            return None
        mav, L = self._endpoint.mav, LOCAL_POSITION
        stamp = L.get(position, "stamp")
        if name == "LOCAL_POSITION_NED":
            return mav.local_position_ned_encode(
                int(stamp * 1e3), *[float(v) for v in w_to_ned(L.get(position, "p_WB"))],
                *[float(v) for v in w_to_ned(L.get(position, "v_WB"))])
        attitude = self._attitude.Eval(context)
        estimate = STATE_ESTIMATE.vector(
            stamp=stamp, p_EB=L.get(position, "p_WB"), v_EB=L.get(position, "v_WB"),
            q_EB=FC_ATTITUDE.get(attitude, "q_WB"),
            var_pv=np.concatenate([L.get(position, "var_p"), L.get(position, "var_v")]))
        return odometry_message(mav, estimate, int(stamp * 1e6),
                                int(L.get(position, "reset_counter")),
                                mavlink.MAV_ESTIMATOR_TYPE_AUTOPILOT, 100,
                                frame=mavlink.MAV_FRAME_LOCAL_NED)

    def _send_imu(self, new: ImuSamples):
        if not len(new):
            return
        self._last_imu_seq = int(new.seq[-1])
        mav = self._endpoint.mav
        for t, accel, gyro in zip(new.t, new.accel, new.gyro):
            accel_F, gyro_F = b_to_frd(accel), b_to_frd(gyro)
            for link in self._links:
                if link.imu_due("HIGHRES_IMU", t):
                    link.endpoint.statistics.imu_sent(gyro_F, time.monotonic())
                    link.endpoint.send(mav.highres_imu_encode(
                        int(round(t * 1e6)), *accel_F, *gyro_F, 0, 0, 0, 0, 0, 0, 25.0,
                        0b111111))
                if link.imu_due("SCALED_IMU", t):
                    link.endpoint.send(mav.scaled_imu_encode(
                        int(round(t * 1e3)), *_int16(accel_F / MILLI_G), *_int16(gyro_F * 1e3),
                        0, 0, 0))

    def _publish_frames(self, context):
        for name, port in self._cameras.items():
            frame = port.Eval(context)
            if frame.valid and frame.stamp > self._frame_stamps[name]:
                self._frame_stamps[name] = frame.stamp
                self._frames.publish(name, frame)


    def _publish_mocap(self, context):
        value = self._mocap.Eval(context)
        stamp = STATE_ESTIMATE.get(value, "stamp")
        if not stamp > self._mocap_stamp:  # cheap when nothing is new (this runs every tick)
            return
        self._mocap_stamp = stamp
        sample = EstimateSample(np.array(value))
        if sample.valid:
            self._frames.publish("mocap", sample)


def _int16(values) -> list[int]:
    return [int(v) for v in np.clip(np.round(values), -32768, 32767)]


def _landed_state(status) -> int:
    if FC_STATUS.get(status, "mode") == ActiveMode.FAILSAFE_DESCENT:
        return mavlink.MAV_LANDED_STATE_LANDING
    if FC_STATUS.get(status, "landed") > 0.5:
        return mavlink.MAV_LANDED_STATE_ON_GROUND
    return mavlink.MAV_LANDED_STATE_IN_AIR


def make_sim_autopilot(vehicle_config, endpoints: list[AutopilotEndpoint],
                       params: SimAutopilotParams, mocap: MocapParams,
                       frames: FramePublisher | None = None, meshcat=None):
    """The simulated vehicle with the autopilot bridge (on `endpoints`: the companion link, then
    a ground-station link if any) closing its `fc_command` loop and the world's mocap system
    (`mocap`, as the simulation's `mocap_odometry`) feeding the frame channel; returns (diagram,
    run loggers)."""
    builder = DiagramBuilder()
    vehicle = builder.AddNamedSystem("vehicle", make_sim_vehicle(vehicle_config, meshcat,
                                                                 autopilot_outputs=True))
    commander = vehicle_config.flight_controller.commander
    rules = AutopilotRules(commander.stale_timeout, commander.max_arm_thrust,
                           commander.hover_thrust, vehicle_config.flight_controller.period,
                           params.rules)
    ground_station = GroundStationService(emulated_parameters(
        vehicle_config.flight_controller, rules, params.system_id, params.component_id),
        endpoints[0].mav)
    bridge = builder.AddNamedSystem("autopilot_bridge", AutopilotBridge(
        endpoints, params, rules, vehicle_config.flight_controller.period,
        vehicle_config.imu.period, frames, ground_station, vehicle_config.rangefinder.max_range))
    for name in ("imu", "fc_attitude", "fc_status", "range", "rgbd", "down_image"):
        builder.Connect(vehicle.GetOutputPort(name), bridge.GetInputPort(name))
    builder.Connect(add_mocap(builder, vehicle.GetOutputPort("ground_truth"), mocap),
                    bridge.GetInputPort("mocap"))
    builder.Connect(bridge.GetOutputPort("fc_command"), vehicle.GetInputPort("fc_command"))
    builder.Connect(bridge.GetOutputPort("odometry"), vehicle.GetInputPort("odometry"))
    builder.Connect(vehicle.GetOutputPort("local_position"),
                    bridge.GetInputPort("local_position"))
    if meshcat is not None:  # framed on the vehicle, its path drawn, the FC's mode shown
        add_vehicle_flight_view(builder, meshcat, vehicle)
    loggers = add_run_logging(builder, vehicle, bridge.GetOutputPort("fc_command"))
    loggers.add(builder, "local_position", vehicle.GetOutputPort("local_position"),
                LOCAL_POSITION)
    loggers.add(builder, "landing_target", bridge.GetOutputPort("landing_target"),
                LANDING_TARGET_RECEIVED)
    diagram = builder.Build()
    diagram.set_name("sim_autopilot")
    return diagram, loggers


def run_sim_autopilot(listen: str, vehicle_config, params: SimAutopilotParams,
                      duration: float | None = None, seed: int = 0, run_dir=None,
                      frame_address: str | None = None, stats_file=None, meshcat=None,
                      record=None, ready=None, realtime_rate: float = 1.0,
                      wait_for_client: bool = True, gcs: str | None = None):
    """Serves the simulated vehicle on `listen` (the companion link) and, if given, `gcs` (a
    second MAVLink instance for a ground station) in real time until `duration` or
    Ctrl-C/SIGTERM; writes the run folder (with ground truth) and, if asked, the link statistics
    (JSON). `wait_for_client`: the simulation (the world, e.g. a landing target's drive, and the
    autopilot's clock) starts at the first valid MAVLink frame from a client on either link, not
    at launch.
    `realtime_rate` below 1 slows the simulation (and the autopilot's clock) for a loaded machine;
    the companion must run at the same rate (`alight hil --realtime-rate`)."""
    from alight.hw.realtime import WallClock, run_realtime
    wall_clock = WallClock(realtime_rate)  # checks the rate before anything opens
    clock = SimClock(realtime_rate)
    endpoints = [AutopilotEndpoint.open(listen, params, clock)]
    frames = None
    try:
        if gcs is not None:
            endpoints.append(AutopilotEndpoint.open(gcs, params, clock))
        frames = FramePublisher(frame_address) if frame_address else None
        # The world's mocap: MocapParams' defaults, as a scenario's `onboard.mocap`.
        diagram, loggers = make_sim_autopilot(vehicle_config, endpoints, params, MocapParams(),
                                              frames, meshcat)
        run_dir = Path(run_dir) if run_dir is not None else default_run_dir("sim-autopilot",
                                                                             seed)
        metadata = {"command": "sim-autopilot", "seed": seed, "listen": listen, "gcs": gcs,
                    "config": vehicle_config, "autopilot": params, "realtime_rate": realtime_rate}
        open_run_folder(run_dir, loggers, diagram, metadata)  # written as it flies
        if meshcat is not None and record is not None:
            start_recording(meshcat)
        if ready is not None:
            ready()
        simulator, report = run_realtime(
            diagram, duration, wall_clock, seed=seed,
            safe_stop=lambda: "simulated vehicle: stops with the process",
            start_when=(lambda: any(e.counters.messages > 0 for e in endpoints))
            if wait_for_client else None)
        if meshcat is not None and record is not None:
            write_recording(meshcat, record)
    finally:
        for endpoint in endpoints:
            endpoint.close()
        if frames is not None:
            frames.close()
    write_run_folder(run_dir, loggers, simulator, {
        **metadata, "duration": simulator.get_context().get_time(),
        "realtime": dc.asdict(report)})
    statistics = {"realtime": dc.asdict(report),
                  "link": dc.asdict(endpoints[0].counters_snapshot()),
                  **endpoints[0].statistics.summary()}
    if gcs is not None:
        statistics["gcs_link"] = dc.asdict(endpoints[1].counters_snapshot())
    if stats_file is not None:
        Path(stats_file).write_text(json.dumps(statistics, indent=2))
    LOG.info("sim-autopilot: %s", report.lines()[0])
    return report, run_dir, statistics
