"""Hardware in the loop (`alight hil`): the onboard diagram against the MAVLink vehicle, in real
time, with the real-time runner's overrun reports and final safe command.

The onboard side is a mission: one function per `--mission` that adds its systems to the builder,
connects them to the vehicle's ports and returns its `fc_command` port and its duration. Today
`hover` flies the scripted hover profile (diagrams/hover.py); `fly` (the position MPC of
diagrams/fly.py) and `land` plug in here as one entry each of MISSIONS once an onboard position
estimate (VIO, the estimator bank) exists: over MAVLink there is no ground truth for mocap.
"""
import dataclasses as dc
from pathlib import Path
from typing import Callable

from pydrake.systems.framework import DiagramBuilder, OutputPort

from alight.diagrams.run_log import RunLoggers, add_run_logging, write_run_folder
from alight.hw.frame_channel import FrameSubscriber
from alight.hw.link import MavlinkLink
from alight.hw.mavlink_vehicle import (LINK_STATUS, MavlinkVehicleParams, command_sender,
                                       make_mavlink_vehicle)
from alight.hw.realtime import RealtimeReport, WallClock, run_realtime


@dc.dataclass
class MissionOptions:
    """What a mission may need: the vehicle model the onboard side assumes (a SimVehicleConfig:
    its airframe file), and the pilot profile for `hover`."""
    vehicle_config: object
    profile: str = "hover_profile.yaml"


@dc.dataclass
class Mission:
    fc_command: OutputPort
    duration: float | None  # s, None: until Ctrl-C


def hover_mission(builder: DiagramBuilder, vehicle, options: MissionOptions) -> Mission:
    """The scripted hover pilot (open-loop attitude/thrust profile: take off, hover, land)."""
    from alight.diagrams.hover import load_pilot_profile, pilot_model
    from alight.systems.control.scripted_pilot import ScriptedPilot
    profile = load_pilot_profile(options.profile)
    pilot = builder.AddNamedSystem("pilot", ScriptedPilot(profile,
                                                          pilot_model(options.vehicle_config)))
    return Mission(pilot.GetOutputPort("fc_command"), profile.duration)


class MissionUnavailable(RuntimeError):
    pass


def _unavailable(name: str, what: str) -> Callable:
    message = f"mission '{name}' is not available over MAVLink yet: it needs {what} " \
              f"(the simulation's mocap stand-in reads ground truth, which a MAVLink vehicle " \
              f"does not have); use --mission hover"

    def mission(builder, vehicle, options):
        raise MissionUnavailable(message)
    mission.unavailable = message
    return mission


MISSIONS: dict[str, Callable[[DiagramBuilder, object, MissionOptions], Mission]] = {
    "hover": hover_mission,
    "fly": _unavailable("fly", "an onboard position estimate for the position MPC of "
                               "diagrams/fly.py (VIO or the estimator bank)"),
    "land": _unavailable("land", "the landing mission (target detection, EKF, landing MPC) and "
                                 "an onboard position estimate"),
}


def check_mission(mission: str) -> None:
    """Raises MissionUnavailable for an unknown mission or one that is not built yet."""
    if mission not in MISSIONS:
        raise MissionUnavailable(f"unknown mission '{mission}'; one of {sorted(MISSIONS)}")
    if hasattr(MISSIONS[mission], "unavailable"):
        raise MissionUnavailable(MISSIONS[mission].unavailable)


def make_hil_diagram(link: MavlinkLink, params: MavlinkVehicleParams, mission: str,
                     options: MissionOptions, frames: FrameSubscriber | None = None,
                     cameras: dict | None = None):
    """(diagram, run loggers, mission duration): the MAVLink vehicle driven by `mission`."""
    check_mission(mission)
    builder = DiagramBuilder()
    vehicle = builder.AddNamedSystem("vehicle", make_mavlink_vehicle(link, params, frames,
                                                                     cameras))
    onboard = MISSIONS[mission](builder, vehicle, options)
    builder.Connect(onboard.fc_command, vehicle.GetInputPort("fc_command"))
    loggers = add_run_logging(builder, vehicle, onboard.fc_command)
    from pydrake.systems.primitives import VectorLogSink
    sink = builder.AddNamedSystem("log_link_status", VectorLogSink(LINK_STATUS.size, 0.01))
    builder.Connect(vehicle.GetOutputPort("link_status"), sink.get_input_port())
    loggers = RunLoggers({**loggers.vector_sinks, "link_status": (sink, LINK_STATUS)},
                         loggers.imu_sink)
    diagram = builder.Build()
    diagram.set_name(f"hil_{mission}")
    return diagram, loggers, onboard.duration


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
    from alight.diagrams.hover import default_run_dir
    check_mission(mission)
    clock = WallClock(realtime_rate)
    cameras = {"down_image": _down_camera(down_camera, clock)} if down_camera else {}
    link = MavlinkLink.open(connect, params.link, clock)
    frames = FrameSubscriber(frame_address) if frame_address else None
    try:
        link.wait_for_autopilot(wait)
        rates = link.request_message_rates()
        if follow_autopilot_clock:
            link.follow_autopilot_clock()
        diagram, loggers, mission_duration = make_hil_diagram(link, params, mission, options,
                                                              frames, cameras)
        sender = command_sender(diagram.GetSubsystemByName("vehicle"))

        def safe_stop() -> str:
            sender.wait_idle()
            return link.safe_stop()
        simulator, report = run_realtime(
            diagram, duration or mission_duration, clock, seed=seed, safe_stop=safe_stop,
            pace=link.autopilot_time if follow_autopilot_clock else None)
        run_dir = Path(run_dir) if run_dir is not None else default_run_dir(f"hil-{mission}",
                                                                             seed)
        write_run_folder(run_dir, loggers, simulator.get_context(), {
            "command": "hil", "mission": mission, "connect": connect, "seed": seed,
            "duration": simulator.get_context().get_time(), "vehicle": params,
            "profile": options.profile, "message_rates": rates, "realtime_rate": realtime_rate,
            "follow_autopilot_clock": follow_autopilot_clock,
            "realtime": dc.asdict(report), "link": dc.asdict(link.counters_snapshot()),
            "arming_errors": sender.last_error})
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
