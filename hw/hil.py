"""Hardware in the loop (`alight hil`): the onboard diagram against the MAVLink vehicle, in real
time, with the real-time runner's overrun reports and final safe command.

The onboard side is the scenario's stack, built by the very function simulation uses
(diagrams/stacks.py `add_onboard`) on the MAVLink vehicle's boundary ports; the stacks that fly
on a position estimate (landing, waypoints) take the channel mocap (hw/channel_odometry.py) as
their odometry; `hover` flies an open-loop attitude/thrust profile and needs no position
estimate. The estimate the stack flies on also goes to the vehicle's `odometry` input: PX4 gets it
as external vision (ODOMETRY); a landing stack's target estimate goes out as LANDING_TARGET
(hw/landing_target.py).
"""
import dataclasses as dc
from pathlib import Path

from pydrake.systems.framework import DiagramBuilder

from alight.diagrams.running.paths import default_run_dir
from alight.diagrams.running.run_log import open_run_folder, write_run_folder
from alight.diagrams.scenario import Scenario, write_scenario
from alight.diagrams.stacks import NEEDS_ODOMETRY, OnboardStack, add_onboard
from alight.hw.channel_odometry import channel_odometry
from alight.hw.endpoint import LOG
from alight.hw.frame_channel import FrameSubscriber
from alight.hw.landing_target import LandingTargetSender
from alight.hw.link import MavlinkLink
from alight.hw.mavlink_vehicle import (LINK_STATUS, MavlinkVehicleParams, command_sender,
                                       make_mavlink_vehicle)
from alight.hw.realtime import RealtimeReport, WallClock, run_realtime


class MissionUnavailable(RuntimeError):
    pass


def check_mission(scenario: Scenario, frame_address: str | None) -> None:
    """Raises MissionUnavailable for a stack that needs a position estimate without the frame
    channel that carries the simulated autopilot's mocap (`frame_address` None: no channel)."""
    stack = scenario.onboard.stack
    if stack in NEEDS_ODOMETRY and frame_address is None:
        raise MissionUnavailable(
            f"the '{stack}' stack needs a position estimate: against `alight sim-autopilot` it "
            f"reads the simulated mocap from the frame channel (do not pass --frames none); on a "
            f"real flight controller no onboard position source runs in real time yet (VIO "
            f"does not keep up, docs/vio.md); use --mission hover")


def make_hil_diagram(link: MavlinkLink, params: MavlinkVehicleParams, scenario: Scenario,
                     frames: FrameSubscriber | None = None, cameras: dict | None = None
                     ) -> tuple[object, OnboardStack]:
    """(diagram, onboard): the MAVLink vehicle driven by the scenario's onboard stack, with its
    run loggers plus the link's `link_status`."""
    check_mission(scenario, frames.address if frames is not None else None)
    builder = DiagramBuilder()
    vehicle = builder.AddNamedSystem("vehicle", make_mavlink_vehicle(link, params, frames,
                                                                     cameras))
    odometry = forwarded(channel_odometry(frames, link, params.channel_odometry)) \
        if frames is not None else None
    onboard = add_onboard(builder, scenario, vehicle, odometry)
    add_landing_target(builder, link, params, onboard)
    onboard.loggers.add(builder, "link_status", vehicle.GetOutputPort("link_status"),
                        LINK_STATUS)
    diagram = builder.Build()
    diagram.set_name(f"hil_{scenario.onboard.stack}")
    return diagram, onboard


def forwarded(odometry):
    """The odometry hook `odometry` whose estimate also feeds the vehicle's `odometry` input (the
    MAVLink vehicle sends it to PX4 as external vision)."""
    def hook(builder, vehicle):
        port = odometry(builder, vehicle)
        builder.Connect(port, vehicle.GetInputPort("odometry"))
        return port
    return hook


def add_landing_target(builder, link: MavlinkLink, params: MavlinkVehicleParams,
                       onboard: OnboardStack) -> LandingTargetSender | None:
    """LANDING_TARGET from a landing stack's target EKF (its `perception` and state estimate);
    None for a stack without a target."""
    parts = onboard.parts
    perception = getattr(parts, "perception", None)
    estimate = getattr(getattr(parts, "loop", None), "state_estimate_port", None) \
        or getattr(parts, "state_estimate", None)
    if perception is None or estimate is None:
        return None
    sender = builder.AddNamedSystem("landing_target", LandingTargetSender(
        link, 1.0 / params.landing_target_rate))
    builder.Connect(perception.target_estimate, sender.GetInputPort("target_estimate"))
    builder.Connect(estimate, sender.GetInputPort("state_estimate"))
    return sender


@dc.dataclass
class HilResult:
    report: RealtimeReport
    run_dir: Path
    link_rates: dict
    finished: bool | None = None  # the mission ended the flight; None: a stack without an end

    def lines(self) -> list[str]:
        return self.report.lines() + (["mission           did not finish"]
                                      if self.finished is False else []) \
            + [f"run folder        {self.run_dir}"]


def run_hil(connect: str, scenario: Scenario, params: MavlinkVehicleParams,
            duration: float | None = None, run_dir=None,
            frame_address: str | None = None, wait: float = 10.0,
            realtime_rate: float = 1.0, follow_autopilot_clock: bool | None = None,
            down_camera: str | None = None) -> HilResult:
    """Connects, waits for the autopilot (heartbeat and TIMESYNC), asks for the telemetry rates,
    flies the scenario's onboard stack in real time (seeded by its `random_seed`) and writes
    the run folder (with the scenario's scenario.yaml). `realtime_rate` below 1 only
    against a simulated autopilot slowed to the same rate. `follow_autopilot_clock` (simulated
    autopilots only) paces the onboard diagram on the autopilot's clock as well as the wall
    clock, so that a simulation that falls behind real time slows the onboard side with it;
    None (default): when the autopilot says its vehicle is simulated (HEARTBEAT's
    MAV_MODE_FLAG_HIL_ENABLED, `AutopilotState.simulated`).
    `down_camera` (an OpenCV device, e.g. "/dev/video0") feeds `down_image` from a real camera
    calibrated as the scenario's `vehicle.down_camera`."""
    check_mission(scenario, frame_address)
    stack, seed = scenario.onboard.stack, scenario.random_seed
    clock = WallClock(realtime_rate)
    cameras = {"down_image": _down_camera(down_camera, scenario.vehicle.down_camera, clock)
               } if down_camera else {}
    link = MavlinkLink.open(connect, params.link, clock)
    frames = FrameSubscriber(frame_address) if frame_address else None
    try:
        # Built before the autopilot answers, so that the mission starts as soon as it does (a
        # simulated autopilot's world, e.g. the landing target, runs from its own start).
        diagram, onboard = make_hil_diagram(link, params, scenario, frames, cameras)
        sender = command_sender(diagram.GetSubsystemByName("vehicle"))
        run_dir = Path(run_dir) if run_dir is not None else default_run_dir(f"hil-{stack}",
                                                                             seed)
        metadata = {"command": "hil", "scenario_name": scenario.name, "connect": connect,
                    "seed": seed, "vehicle": params, **onboard.metadata,
                    "realtime_rate": realtime_rate,
                    "follow_autopilot_clock": follow_autopilot_clock}
        open_run_folder(run_dir, onboard.loggers, diagram, metadata)  # written as it flies
        write_scenario(run_dir, scenario)
        LOG.info("hil: %s stack built; waiting for the autopilot on %s", stack, connect)
        autopilot = link.wait_for_autopilot(wait)
        rates = link.request_message_rates()
        if follow_autopilot_clock is None:
            follow_autopilot_clock = autopilot.simulated
            LOG.info("hil: the autopilot's vehicle is %s: %s", "simulated" if
                     follow_autopilot_clock else "real", "following its clock"
                     if follow_autopilot_clock else "on the wall clock alone")
        metadata["follow_autopilot_clock"] = follow_autopilot_clock
        if follow_autopilot_clock:
            link.follow_autopilot_clock()

        def safe_stop() -> str:
            sender.wait_idle()
            return link.safe_stop()
        simulator, report = run_realtime(
            diagram, duration or onboard.duration, clock, seed=seed, safe_stop=safe_stop,
            pace=link.autopilot_time if follow_autopilot_clock else None,
            stop_when=onboard.finished)
        write_run_folder(run_dir, onboard.loggers, simulator, {
            **metadata, "duration": simulator.get_context().get_time(),
            "message_rates": rates, "realtime": dc.asdict(report),
            "link": dc.asdict(link.counters_snapshot()),
            "frames": dc.asdict(frames.counters) if frames is not None else None,
            "autopilot_clock_offset": -link.to_local(0.0),
            "mission_finished": onboard.finished is not None
            and onboard.finished.at is not None, "arming_errors": sender.last_error})
        return HilResult(report, run_dir, rates, None if onboard.finished is None
                         else onboard.finished.at is not None)
    finally:
        link.close()
        if frames is not None:
            frames.close()
        for camera in cameras.values():
            camera.close()


def _down_camera(device: str, camera, clock: WallClock):
    """The real down camera `device` with the calibration of `camera` (DownCameraParams)."""
    from alight.hw.opencv_camera import OpenCvCamera, OpenCvCameraParams
    return OpenCvCamera("down_image", OpenCvCameraParams(device=device, latency=camera.latency),
                        camera.lens().calibration(), clock)
