"""Hardware in the loop (`alight hil`): the onboard diagram against the MAVLink vehicle, in real
time, with the real-time runner's overrun reports and final safe command.

The onboard side is a mission: one function per `--mission` that adds its systems to the builder
on the vehicle's boundary ports and connects its command to the vehicle. They are the very onboard
functions the simulation uses (diagrams/onboard/pilot.py `add_pilot_onboard`,
diagrams/onboard/waypoints.py `add_waypoint_onboard`, diagrams/onboard/landing.py
`add_landing_onboard`); `fly` and `land` take the
channel mocap (hw/channel_odometry.py) as their odometry; `hover` flies an open-loop
attitude/thrust profile and needs no position estimate.
"""
import dataclasses as dc
from pathlib import Path
from typing import Callable

import numpy as np
from pydrake.systems.framework import DiagramBuilder

from alight.diagrams.onboard.landing import add_landing_onboard
from alight.diagrams.onboard.pilot import add_pilot_onboard, load_pilot_profile, pilot_model
from alight.diagrams.onboard.waypoints import add_waypoint_onboard, mission_duration
from alight.diagrams.running.paths import default_run_dir
from alight.diagrams.running.run_log import RunLoggers, write_run_folder
from alight.hw.channel_odometry import channel_odometry
from alight.hw.endpoint import LOG
from alight.hw.frame_channel import FrameSubscriber
from alight.hw.link import MavlinkLink
from alight.hw.mavlink_vehicle import (LINK_STATUS, MavlinkVehicleParams, command_sender,
                                       make_mavlink_vehicle)
from alight.hw.realtime import RealtimeReport, WallClock, run_realtime


@dc.dataclass
class MissionOptions:
    """What a mission may need: the vehicle model the onboard side assumes (a SimVehicleConfig:
    its airframe file), the pilot profile of `hover`, the waypoints of `fly` (rows x, y, z) and
    the landing scenario of `land` (its mission, MPC tuning, camera blackouts, time limits)."""
    vehicle_config: object
    profile: str = "hover_profile.yaml"
    waypoints: np.ndarray | None = None
    scenario: object | None = None


@dc.dataclass
class Mission:
    loggers: RunLoggers
    duration: float | None              # s, None: until Ctrl-C
    finished: Callable | None = None    # stop condition on the root context (mission done)
    metadata: dict = dc.field(default_factory=dict)


def hover_mission(builder: DiagramBuilder, vehicle, options: MissionOptions,
                  odometry=None) -> Mission:
    """`alight hover`'s onboard side: the scripted pilot (open-loop attitude/thrust profile)."""
    profile = load_pilot_profile(options.profile)
    return Mission(add_pilot_onboard(builder, vehicle, profile,
                                     pilot_model(options.vehicle_config)),
                   profile.duration, metadata={"profile": options.profile})


def fly_mission(builder: DiagramBuilder, vehicle, options: MissionOptions,
                odometry=None) -> Mission:
    """`alight fly`'s onboard side: the waypoints with the linear MPC, then land and disarm."""
    if options.waypoints is None:
        raise MissionUnavailable("mission 'fly' needs waypoints (--waypoints '0,0,2; 3,0,2')")
    onboard = add_waypoint_onboard(builder, vehicle, options.waypoints, odometry=odometry)
    return Mission(onboard.loggers, mission_duration(options.waypoints, 300.0),
                   onboard.finished(rest=1.0), {"waypoints": options.waypoints})


def land_mission(builder: DiagramBuilder, vehicle, options: MissionOptions,
                 odometry=None) -> Mission:
    """`alight land`'s onboard side: find the target, follow it and land on it (L Sec. 6)."""
    scenario = options.scenario
    if scenario is None:
        raise MissionUnavailable("mission 'land' needs a landing scenario (--scenario)")
    onboard = add_landing_onboard(builder, scenario, vehicle, odometry)
    return Mission(onboard.loggers, scenario.max_duration,
                   onboard.finished(scenario.settle_time), {"scenario": scenario})


class MissionUnavailable(RuntimeError):
    pass


MISSIONS: dict[str, Callable[..., Mission]] = {
    "hover": hover_mission, "fly": fly_mission, "land": land_mission}
NEEDS_ODOMETRY = {"fly", "land"}


def check_mission(mission: str, frame_address: str | None) -> None:
    """Raises MissionUnavailable for an unknown mission, or one that needs a position estimate
    without the frame channel that carries the simulated autopilot's mocap (`frame_address`
    None: no channel)."""
    if mission not in MISSIONS:
        raise MissionUnavailable(f"unknown mission '{mission}'; one of {sorted(MISSIONS)}")
    if mission in NEEDS_ODOMETRY and frame_address is None:
        raise MissionUnavailable(
            f"mission '{mission}' needs a position estimate: against `alight sim-autopilot` it "
            f"reads the simulated mocap from the frame channel (do not pass --frames none); on a "
            f"real flight controller no onboard position source runs in real time yet (VIO "
            f"does not keep up, docs/vio.md); use --mission hover")


def make_hil_diagram(link: MavlinkLink, params: MavlinkVehicleParams, mission: str,
                     options: MissionOptions, frames: FrameSubscriber | None = None,
                     cameras: dict | None = None):
    """(diagram, mission): the MAVLink vehicle driven by `mission`, with its run loggers plus the
    link's `link_status`."""
    check_mission(mission, frames.address if frames is not None else None)
    builder = DiagramBuilder()
    vehicle = builder.AddNamedSystem("vehicle", make_mavlink_vehicle(link, params, frames,
                                                                     cameras))
    odometry = channel_odometry(frames, link) if frames is not None else None
    onboard = MISSIONS[mission](builder, vehicle, options, odometry)
    onboard.loggers.add(builder, "link_status", vehicle.GetOutputPort("link_status"),
                        LINK_STATUS)
    diagram = builder.Build()
    diagram.set_name(f"hil_{mission}")
    return diagram, onboard


@dc.dataclass
class HilResult:
    report: RealtimeReport
    run_dir: Path
    link_rates: dict

    def lines(self) -> list[str]:
        return self.report.lines() + [f"run folder        {self.run_dir}"]


def run_hil(connect: str, mission: str, options: MissionOptions, params: MavlinkVehicleParams,
            duration: float | None = None, seed: int = 0, run_dir=None,
            frame_address: str | None = None, wait: float = 10.0,
            realtime_rate: float = 1.0, follow_autopilot_clock: bool = False,
            down_camera: str | None = None) -> HilResult:
    """Connects, waits for the autopilot (heartbeat and TIMESYNC), asks for the telemetry rates,
    flies `mission` in real time and writes the run folder. `realtime_rate` below 1 only
    against a simulated autopilot slowed to the same rate. `follow_autopilot_clock` (simulated
    autopilots only) paces the onboard diagram on the autopilot's clock as well as the wall
    clock, so that a simulation that falls behind real time slows the onboard side with it.
    `down_camera` (an OpenCV device, e.g. "/dev/video0") feeds `down_image` from a real camera
    calibrated by models/down_camera.yaml."""
    check_mission(mission, frame_address)
    clock = WallClock(realtime_rate)
    cameras = {"down_image": _down_camera(down_camera, clock)} if down_camera else {}
    link = MavlinkLink.open(connect, params.link, clock)
    frames = FrameSubscriber(frame_address) if frame_address else None
    try:
        # Built before the autopilot answers, so that the mission starts as soon as it does (a
        # simulated autopilot's world, e.g. the landing target, runs from its own start).
        diagram, onboard = make_hil_diagram(link, params, mission, options, frames, cameras)
        sender = command_sender(diagram.GetSubsystemByName("vehicle"))
        LOG.info("hil: %s mission built; waiting for the autopilot on %s", mission, connect)
        link.wait_for_autopilot(wait)
        rates = link.request_message_rates()
        if follow_autopilot_clock:
            link.follow_autopilot_clock()

        def safe_stop() -> str:
            sender.wait_idle()
            return link.safe_stop()
        simulator, report = run_realtime(
            diagram, duration or onboard.duration, clock, seed=seed, safe_stop=safe_stop,
            pace=link.autopilot_time if follow_autopilot_clock else None,
            stop_when=onboard.finished)
        run_dir = Path(run_dir) if run_dir is not None else default_run_dir(f"hil-{mission}",
                                                                             seed)
        write_run_folder(run_dir, onboard.loggers, simulator, {
            "command": "hil", "mission": mission, "connect": connect, "seed": seed,
            "duration": simulator.get_context().get_time(), "vehicle": params,
            **onboard.metadata, "message_rates": rates, "realtime_rate": realtime_rate,
            "follow_autopilot_clock": follow_autopilot_clock,
            "realtime": dc.asdict(report), "link": dc.asdict(link.counters_snapshot()),
            "frames": dc.asdict(frames.counters) if frames is not None else None,
            "autopilot_clock_offset": -link.to_local(0.0),
            "mission_finished": onboard.finished is not None
            and onboard.finished.at is not None, "arming_errors": sender.last_error})
        return HilResult(report, run_dir, rates)
    finally:
        link.close()
        if frames is not None:
            frames.close()
        for camera in cameras.values():
            camera.close()


def _down_camera(device: str, clock: WallClock):
    from alight.hw.opencv_camera import OpenCvCamera, OpenCvCameraParams
    from alight.models import model_path
    from alight.systems.params import load_params
    from alight.systems.sensors.down_camera import DownCameraParams
    camera = load_params(DownCameraParams, model_path("down_camera.yaml"))
    return OpenCvCamera("down_image", OpenCvCameraParams(device=device, latency=camera.latency),
                        camera.lens().calibration(), clock)
