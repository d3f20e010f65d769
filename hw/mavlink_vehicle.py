"""The MAVLink vehicle: a Diagram with exactly the vehicle-boundary ports of DESIGN.md (as the
simulated vehicle, without the simulation-only `ground_truth`), backed by a PX4 flight controller
over MAVLink (hw/link.py), plus the hardware-only `link_status` diagnostics.

- `imu`: every IMU sample from the link once, with its own time mapped to the onboard clock;
- `fc_attitude`, `fc_status`: the autopilot's estimate and state (PX4 mode, armed, landed);
- `range`: the downward rangefinder's DISTANCE_SENSOR, stamped on the onboard clock (not valid
  until one arrives: a vehicle without a rangefinder);
- `fc_command`: checked as the simulated flight controller checks it (a refused command is not
  sent, the previous valid one holds, the refusal shows on `fc_status`), streamed as
  SET_ATTITUDE_TARGET every `command_period` while it is fresh. A command older than
  `stale_timeout` is not streamed: PX4's offboard-loss failsafe then takes over, as the simulated
  flight controller's does. A rising arm flag starts OFFBOARD then ARM, a falling one DISARM
  (COMMAND_LONG, acknowledged, in a worker thread so the diagram never blocks);
- `rgbd`, `down_image`: frames from a real camera (hw/opencv_camera.py) or from the local frame
  channel of a simulated autopilot (hw/frame_channel.py), if any;
- `odometry`: the onboard state estimate sent to PX4 as external vision (ODOMETRY,
  hw/external_vision.py) at `odometry_rate`, each new valid estimate once, stamped on the
  autopilot's clock (TIMESYNC); its reset_counter counts the estimator's frame switches. Left
  unconnected (a stack without a position estimate), nothing is sent.
"""
import dataclasses as dc
import math
import threading
import time

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import Diagram, DiagramBuilder, LeafSystem
from pydrake.systems.primitives import ConstantValueSource

from alight.hw.channel_odometry import ChannelOdometryParams
from alight.hw.endpoint import LOG
from alight.hw.external_vision import estimator_type, odometry_message, quality
from alight.hw.frame_channel import FrameSubscriber
from alight.hw.link import CommandDenied, LinkParams, LinkTimeout, MavlinkLink
from alight.models import model_path
from alight.systems.autopilot.commander import CommanderParams, check_command
from alight.systems.boundary import (FC_ATTITUDE, FC_COMMAND, FC_STATUS, NO_COMMAND_STAMP,
                                     RANGE, STATE_ESTIMATE, ActiveMode, CameraFrame, CommandMode,
                                     ImuSamples, Refusal, VectorLayout)
from alight.systems.params import bounded, load_params

CAMERAS = ("rgbd", "down_image")


@dc.dataclass
class MavlinkVehicleParams:
    """models/mavlink_vehicle.yaml."""
    link: LinkParams = dc.field(default_factory=LinkParams)
    command_period: float = bounded(0.01, 0.001, 0.5, "s")  # SET_ATTITUDE_TARGET stream (PX4: >2 Hz)
    stale_timeout: float = bounded(0.5, 0.01, 10.0, "s")    # as the simulated FC's
    max_body_rate: float = bounded(6.0, 0.1, 50.0, "rad/s")  # larger commanded rates are refused
    min_stream_before_offboard: float = bounded(0.3, 0.0, 5.0, "s")
    imu_period: float = bounded(0.002, 0.0005, 0.1, "s")    # how often `imu` takes new samples
    imu_buffer_length: int = bounded(100, 2, 100000)         # samples kept on `imu`
    telemetry_period: float = bounded(0.004, 0.001, 0.1, "s")
    camera_period: float = bounded(0.01, 0.001, 1.0, "s")
    # the frame channel's mocap, the odometry against a simulated autopilot (`alight hil`)
    channel_odometry: ChannelOdometryParams = dc.field(default_factory=ChannelOdometryParams)
    # External vision out (ODOMETRY): PX4 wants 30-50 Hz; 0: not sent
    odometry_rate: float = bounded(30.0, 0.0, 200.0, "Hz")
    odometry_estimator: str = "vision"   # ODOMETRY estimator_type: vision or vio (PX4 fuses both)
    odometry_worst_std: float = bounded(1.0, 0.01, 100.0, "m")  # quality 1 at this position std
    landing_target_rate: float = bounded(20.0, 0.1, 100.0, "Hz")  # LANDING_TARGET (`alight hil`)

    def __post_init__(self):
        estimator_type(self.odometry_estimator)  # a clear error for an unknown type


def load_mavlink_vehicle_params(filename: str = "mavlink_vehicle.yaml") -> MavlinkVehicleParams:
    return load_params(MavlinkVehicleParams, model_path(filename))


# Output `link_status` (hardware only, never read onboard): link health and what was dropped.
# Ages are -1 before the first message; counters as hw/endpoint.py LinkCounters.
LINK_STATUS = VectorLayout("link_status", [
    ("stamp", 1), ("heartbeat_age", 1), ("message_age", 1), ("timesync_locked", 1),
    ("timesync_offset", 1), ("timesync_rtt", 1), ("bytes_received", 1), ("messages", 1),
    ("malformed", 1), ("unknown", 1), ("foreign", 1), ("out_of_order", 1), ("rejected", 1),
    ("lost", 1), ("imu_out_of_order", 1), ("imu_overflow", 1), ("setpoints_sent", 1),
    ("commands_denied", 1), ("px4_custom_mode", 1), ("landed_state", 1)])
HW_ONLY_OUTPUTS = {"link_status": LINK_STATUS}

# Output `command_status` of the command sender, read by the telemetry system.
COMMAND_STATUS = VectorLayout("command_status", [
    ("last_sent_stamp", 1), ("refused", 1), ("last_refusal", 1), ("mode", 1), ("streaming", 1),
    ("denied", 1)])


class MavlinkImu(LeafSystem):
    """Output `imu` ImuSamples: the link's IMU samples, each once, stamped on the onboard clock
    (autopilot time mapped through TIMESYNC; samples wait in the link until the clock is locked).
    At most half the buffer is taken per update so that no sample leaves the buffer unseen."""

    def __init__(self, link: MavlinkLink, period: float, capacity: int):
        super().__init__()
        self._link = link
        self._capacity = capacity
        self._samples = self.DeclareAbstractState(AbstractValue.Make(ImuSamples.empty()))
        self.DeclarePeriodicUnrestrictedUpdateEvent(period, 0.0, self._update)
        self.DeclareStateOutputPort("imu", self._samples)

    def _update(self, context, state):
        if not self._link.timesync.locked:
            return
        new = self._link.take_imu(max_count=max(1, self._capacity // 2))
        if not new:
            return
        samples = context.get_abstract_state(self._samples).get_value()
        seq0 = int(samples.seq[-1]) + 1 if len(samples) else 0
        t_last = float(samples.t[-1]) if len(samples) else -math.inf
        times = []
        for sample in new:  # keep onboard stamps increasing when the clock offset is refined
            t_last = max(self._link.to_local(sample.t_fc), t_last + 1e-6)
            times.append(t_last)
        keep = slice(-self._capacity, None)
        state.get_mutable_abstract_state(self._samples).set_value(ImuSamples(
            np.concatenate([samples.seq, seq0 + np.arange(len(new))])[keep],
            np.concatenate([samples.t, times])[keep],
            np.vstack([samples.accel, [s.accel for s in new]])[keep],
            np.vstack([samples.gyro, [s.gyro for s in new]])[keep]))


# Command sender state: last raw input seen, last accepted command, then flags.
_SENDER_STATE = VectorLayout("sender_state", [
    ("seen", FC_COMMAND.size), ("held", FC_COMMAND.size), ("accepted_once", 1), ("refused", 1),
    ("last_refusal", 1), ("arm_requested", 1), ("last_sent_stamp", 1), ("streaming", 1)])


class MavlinkCommandSender(LeafSystem):
    """Input  `fc_command`     FC_COMMAND from the onboard diagram
    Output `command_status` COMMAND_STATUS (for `fc_status`)
    Every `period`: checks a new command (alight.systems.autopilot.commander.check_command),
    streams the held one as SET_ATTITUDE_TARGET while it is fresh, and turns arm-flag edges into
    OFFBOARD+ARM or DISARM sequences on a worker thread (a refusal is logged and counted)."""

    def __init__(self, link: MavlinkLink, params: MavlinkVehicleParams):
        super().__init__()
        self._link = link
        self._params = params
        self._check = CommanderParams(stale_timeout=params.stale_timeout,
                                      max_body_rate=params.max_body_rate)
        self._command = self.DeclareVectorInputPort("fc_command", FC_COMMAND.size)
        initial = np.zeros(_SENDER_STATE.size)
        initial[_SENDER_STATE.slice("seen")] = np.nan
        initial[_SENDER_STATE.slice("held")] = FC_COMMAND.pack(
            stamp=-np.inf, mode=CommandMode.ATTITUDE_THRUST, q_WD=[1, 0, 0, 0], w_D=np.zeros(3),
            thrust=0.0, arm=0.0)
        initial[_SENDER_STATE.slice("last_sent_stamp")] = NO_COMMAND_STAMP
        self._xd = self.DeclareDiscreteState(initial)
        self.DeclarePeriodicDiscreteUpdateEvent(params.command_period, 0.0, self._update)
        self.DeclareVectorOutputPort("command_status", COMMAND_STATUS.size, self._status,
                                     prerequisites_of_calc={self.xd_ticket()})
        self._worker: threading.Thread | None = None
        self.denied = 0
        self.last_error = ""

    def _update(self, context, discrete_state):
        L = _SENDER_STATE
        x = context.get_discrete_state(self._xd).get_value().copy()
        now = context.get_time()
        command = self._command.Eval(context)
        held = x[L.slice("held")]
        if not np.array_equal(command, x[L.slice("seen")], equal_nan=True):
            x[L.slice("seen")] = command
            refusal = check_command(command, self._check, FC_COMMAND.get(held, "stamp"), now)
            if refusal == Refusal.NONE:
                held = command.copy()
                x[L.slice("held")] = held
                x[L.slice("accepted_once")] = 1.0
            else:
                x[L.slice("refused")] += 1.0
                x[L.slice("last_refusal")] = refusal
        fresh = x[L.slice("accepted_once")][0] > 0.5 \
            and now - FC_COMMAND.get(held, "stamp") <= self._params.stale_timeout
        x[L.slice("streaming")] = float(fresh)
        if fresh:
            self._link.send_attitude_target(held)
            x[L.slice("last_sent_stamp")] = FC_COMMAND.get(held, "stamp")
            arm = FC_COMMAND.get(held, "arm") > 0.5
            if arm != (x[L.slice("arm_requested")][0] > 0.5):
                x[L.slice("arm_requested")] = float(arm)
                self._start(self._arm if arm else self._disarm)
        discrete_state.set_value(self._xd, x)

    def _status(self, context, output):
        x = context.get_discrete_state(self._xd).get_value()
        L = _SENDER_STATE
        output.SetFromVector(COMMAND_STATUS.pack(
            last_sent_stamp=L.get(x, "last_sent_stamp"), refused=L.get(x, "refused"),
            last_refusal=L.get(x, "last_refusal"), mode=FC_COMMAND.get(L.get(x, "held"), "mode"),
            streaming=L.get(x, "streaming"), denied=self.denied))

    def _arm(self):
        if not self._link.state().armed:
            self._link.start_offboard_and_arm(self._params.min_stream_before_offboard)

    def _disarm(self):
        if self._link.state().armed:
            self._link.disarm()

    def _start(self, sequence):
        """Runs one arm/disarm sequence at a time on a worker thread (the diagram never waits)."""
        if self._worker is not None and self._worker.is_alive():
            self._worker.join(timeout=5.0)  # rare: an edge while the previous one still works

        def run():
            try:
                sequence()
            except (CommandDenied, LinkTimeout) as e:
                self.denied += 1
                self.last_error = str(e)
                LOG.error("%s", e)
        self._worker = threading.Thread(target=run, name="mavlink-arming", daemon=True)
        self._worker.start()

    def wait_idle(self, timeout: float = 5.0) -> None:
        """Waits for a running arm/disarm sequence (tests, shutdown)."""
        if self._worker is not None:
            self._worker.join(timeout)


# MavlinkTelemetry's discrete state: its outputs, one after the other.
_TELEMETRY = VectorLayout("mavlink_telemetry", [
    ("fc_attitude", FC_ATTITUDE.size), ("fc_status", FC_STATUS.size), ("range", RANGE.size),
    ("link_status", LINK_STATUS.size)])


class MavlinkTelemetry(LeafSystem):
    """Input  `command_status` COMMAND_STATUS from the command sender
    Output `fc_attitude`    FC_ATTITUDE: the autopilot's estimate in W/B, stamped on our clock
    Output `fc_status`      FC_STATUS: armed, mode, link alive, last sent command, refusals, landed
    Output `range`          RANGE: the last downward DISTANCE_SENSOR, stamped on our clock
    Output `link_status`    LINK_STATUS
    Sampled every `period` from the link into state."""

    def __init__(self, link: MavlinkLink, period: float):
        super().__init__()
        self._link = link
        self._command_status = self.DeclareVectorInputPort("command_status", COMMAND_STATUS.size)
        initial = _TELEMETRY.pack(
            fc_attitude=FC_ATTITUDE.pack(stamp=0.0, q_WB=[1, 0, 0, 0], w_B=np.zeros(3)),
            fc_status=FC_STATUS.pack(stamp=0.0, armed=0, mode=ActiveMode.DISARMED, link_alive=0,
                                     last_command_stamp=NO_COMMAND_STAMP, refused=0,
                                     last_refusal=Refusal.NONE, landed=1),
            range=RANGE.pack(stamp=0.0, range=0.0, var=1.0, valid=0.0),
            link_status=np.zeros(LINK_STATUS.size))
        self._xd = self.DeclareDiscreteState(initial)
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._update)
        for name, size in _TELEMETRY.fields:
            self.DeclareVectorOutputPort(
                name, size, lambda c, o, s=_TELEMETRY.slice(name): o.SetFromVector(
                    c.get_discrete_state(self._xd).get_value()[s]),
                prerequisites_of_calc={self.xd_ticket()})

    def _update(self, context, discrete_state):
        x = context.get_discrete_state(self._xd).get_value().copy()
        now = context.get_time()
        link = self._link
        state = link.state()
        sent = self._command_status.Eval(context)
        attitude = _TELEMETRY.get(x, "fc_attitude")
        t_attitude = link.to_local(state.attitude_t_fc)
        if state.attitude_valid and math.isfinite(t_attitude):
            attitude = FC_ATTITUDE.pack(stamp=t_attitude, q_WB=state.q_WB, w_B=state.w_B)
        distance = _TELEMETRY.get(x, "range")
        t_range = link.to_local(state.range_t_fc)
        if math.isfinite(t_range) and math.isfinite(state.range):
            distance = RANGE.pack(stamp=t_range, range=state.range, var=state.range_var,
                                  valid=float(state.range_valid))
        if not state.armed:
            mode = ActiveMode.DISARMED
        elif state.offboard:
            mode = ActiveMode.RATES_THRUST if COMMAND_STATUS.get(sent, "mode") == \
                CommandMode.RATES_THRUST else ActiveMode.ATTITUDE_THRUST
        else:  # armed, flying on its own (AUTO.LAND, failsafe): not following our commands
            mode = ActiveMode.FAILSAFE_DESCENT
        monotonic = time.monotonic()
        status = FC_STATUS.pack(
            stamp=now, armed=float(state.armed), mode=mode,
            link_alive=float(link.link_alive(monotonic)),
            last_command_stamp=COMMAND_STATUS.get(sent, "last_sent_stamp"),
            refused=COMMAND_STATUS.get(sent, "refused"),
            last_refusal=COMMAND_STATUS.get(sent, "last_refusal"),
            landed=float(not state.armed or state.landed))
        counters = link.counters_snapshot()
        sync = link.timesync

        def age(t):
            return monotonic - t if math.isfinite(t) else -1.0
        diagnostics = LINK_STATUS.pack(
            stamp=now, heartbeat_age=age(state.heartbeat_time),
            message_age=age(state.message_time), timesync_locked=float(sync.locked),
            timesync_offset=(sync.offset_ns or 0) * 1e-9,
            timesync_rtt=sync.rtt_ns * 1e-9 if sync.rtt_ns is not None else -1.0,
            bytes_received=counters.bytes_received, messages=counters.messages,
            malformed=counters.malformed, unknown=counters.unknown, foreign=counters.foreign,
            out_of_order=counters.out_of_order, rejected=counters.rejected, lost=counters.lost,
            imu_out_of_order=link.imu_out_of_order, imu_overflow=link.imu_overflow,
            setpoints_sent=link.setpoints_sent, commands_denied=COMMAND_STATUS.get(sent, "denied"),
            px4_custom_mode=state.custom_mode, landed_state=state.landed_state)
        discrete_state.set_value(self._xd, _TELEMETRY.pack(
            fc_attitude=attitude, fc_status=status, range=distance, link_status=diagnostics))


def autopilot_time(link: MavlinkLink, t_local: float) -> float:
    """An onboard time [s] on the autopilot's clock: the inverse of `link.to_local` (an affine
    map); NaN until TIMESYNC locks."""
    t0, t1 = link.to_local(0.0), link.to_local(1.0)
    return (t_local - t0) / (t1 - t0)


class MavlinkOdometrySender(LeafSystem):
    """Input `odometry` STATE_ESTIMATE (may be unconnected: nothing is sent)
    Every 1 / `odometry_rate`: a new valid estimate goes to the autopilot as ODOMETRY (external
    vision), stamped on its clock; reset_counter is incremented when the estimate's
    frame_counter changes (an estimator frame switch). `sent` counts the messages."""

    def __init__(self, link: MavlinkLink, params: MavlinkVehicleParams):
        super().__init__()
        self._link, self._params = link, params
        self._source = estimator_type(params.odometry_estimator)
        self._odometry = self.DeclareVectorInputPort("odometry", STATE_ESTIMATE.size)
        if params.odometry_rate > 0:  # a publish event (output to the world), after updates
            self.DeclarePeriodicPublishEvent(1.0 / params.odometry_rate, 0.0, self._publish)
        # What was sent (not simulation state): last stamp, last frame_counter, reset_counter
        self._last_stamp, self._last_frame, self._resets = -math.inf, math.nan, 0
        self.sent = 0

    def _publish(self, context):
        if not self._odometry.HasValue(context):
            return
        estimate = self._odometry.Eval(context)
        stamp = STATE_ESTIMATE.get(estimate, "stamp")
        valid = STATE_ESTIMATE.get(estimate, "valid") > 0.5 and np.all(np.isfinite(estimate))
        t_fc = autopilot_time(self._link, stamp)
        if not (valid and stamp > self._last_stamp and math.isfinite(t_fc)):
            return
        frame = STATE_ESTIMATE.get(estimate, "frame_counter")
        if math.isfinite(self._last_frame) and frame != self._last_frame:
            self._resets += 1
        self._link.send(odometry_message(
            self._link.mav, estimate, int(round(max(t_fc, 0.0) * 1e6)), self._resets,
            self._source, quality(estimate, self._params.odometry_worst_std)))
        self.sent += 1
        self._last_stamp, self._last_frame = stamp, frame


class ChannelCamera(LeafSystem):
    """Output `<camera>` CameraFrame: the newest frame of `camera` from the frame channel, its
    stamp mapped from the autopilot's clock to ours."""

    def __init__(self, subscriber: FrameSubscriber, camera: str, link: MavlinkLink,
                 period: float):
        super().__init__()
        self._subscriber, self._camera, self._link = subscriber, camera, link
        self._frame = self.DeclareAbstractState(AbstractValue.Make(CameraFrame()))
        self._last_stamp = -math.inf
        self.DeclarePeriodicUnrestrictedUpdateEvent(period, 0.0, self._update)
        self.DeclareStateOutputPort(camera, self._frame)

    def _update(self, context, state):
        frame = self._subscriber.latest(self._camera)
        if frame is None or not frame.valid or frame.stamp <= self._last_stamp:
            return
        stamp = self._link.to_local(frame.stamp)
        if not math.isfinite(stamp):
            return
        self._last_stamp = frame.stamp
        state.get_mutable_abstract_state(self._frame).set_value(dc.replace(frame, stamp=stamp))


def make_mavlink_vehicle(link: MavlinkLink, params: MavlinkVehicleParams,
                         frames: FrameSubscriber | None = None,
                         cameras: dict[str, LeafSystem] | None = None) -> Diagram:
    """The MAVLink vehicle diagram on an open link. Inputs `fc_command`, `odometry`; outputs `imu`,
    `fc_attitude`, `fc_status`, `range`, `rgbd`, `down_image` and the hardware-only
    `link_status`.
    A camera port reads `cameras[name]` (a system with that one output, e.g. a real camera,
    hw/opencv_camera.py) if given, else the frame channel `frames`, else an empty frame."""
    builder = DiagramBuilder()
    imu = builder.AddNamedSystem("imu", MavlinkImu(link, params.imu_period,
                                                   params.imu_buffer_length))
    sender = builder.AddNamedSystem("command_sender", MavlinkCommandSender(link, params))
    telemetry = builder.AddNamedSystem("telemetry", MavlinkTelemetry(link,
                                                                     params.telemetry_period))
    builder.Connect(sender.GetOutputPort("command_status"),
                    telemetry.GetInputPort("command_status"))
    builder.ExportInput(sender.GetInputPort("fc_command"), "fc_command")
    odometry = builder.AddNamedSystem("odometry_sender", MavlinkOdometrySender(link, params))
    builder.ExportInput(odometry.GetInputPort("odometry"), "odometry")
    builder.ExportOutput(imu.GetOutputPort("imu"), "imu")
    builder.ExportOutput(telemetry.GetOutputPort("fc_attitude"), "fc_attitude")
    builder.ExportOutput(telemetry.GetOutputPort("fc_status"), "fc_status")
    builder.ExportOutput(telemetry.GetOutputPort("range"), "range")
    cameras = cameras or {}
    unknown = set(cameras) - set(CAMERAS)
    if unknown:
        raise ValueError(f"no camera port named {sorted(unknown)}; the ports are {CAMERAS}")
    for camera in CAMERAS:
        if camera in cameras:
            source = builder.AddNamedSystem(f"{camera}_camera", cameras[camera])
        elif frames is not None:
            source = builder.AddNamedSystem(f"{camera}_camera", ChannelCamera(
                frames, camera, link, params.camera_period))
        else:  # no camera fitted: an empty frame, as the simulated vehicle without cameras
            source = builder.AddNamedSystem(f"{camera}_camera", ConstantValueSource(
                AbstractValue.Make(CameraFrame())))
        builder.ExportOutput(source.get_output_port(), camera)
    builder.ExportOutput(telemetry.GetOutputPort("link_status"), "link_status")
    diagram = builder.Build()
    diagram.set_name("mavlink_vehicle")
    return diagram


def command_sender(vehicle: Diagram) -> MavlinkCommandSender:
    return vehicle.GetSubsystemByName("command_sender")
