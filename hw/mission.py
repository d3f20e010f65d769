"""The mission API (alight.diagrams.uav.Mission) on a MAVLink flight controller: the same managed
stack (UAV manager, control manager, trackers, controllers) on the MAVLink vehicle's boundary
ports, advanced against the wall clock.

    from alight.hw.mission import mavlink_mission
    with mavlink_mission("udp:127.0.0.1:14540", frame_address=...) as mission:
        mission.takeoff(1.5)
        mission.goto([2.0, 0.0, 1.5])
        mission.land()

Between calls the diagram does not advance, so a script should chain its calls (the flight
controller keeps the last setpoint stream only while the diagram runs: a pause longer than its
offboard timeout is an offboard loss, and PX4 fails safe). `close` (or leaving the `with` block)
sends the final safe command of the real-time runner (disarm on the ground, failsafe descent in
the air), closes the link and writes the run folder.
"""
from pathlib import Path

from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from alight.diagrams.running.paths import default_run_dir
from alight.diagrams.running.simulation import start_simulation
from alight.diagrams.uav import Mission, add_managed_onboard
from alight.hw.channel_odometry import channel_odometry
from alight.hw.frame_channel import FrameSubscriber
from alight.hw.hil import MissionUnavailable
from alight.hw.link import MavlinkLink
from alight.hw.mavlink_vehicle import (LINK_STATUS, MavlinkVehicleParams, command_sender,
                                       load_mavlink_vehicle_params, make_mavlink_vehicle)
from alight.hw.realtime import Pacer, WallClock


def mavlink_mission(connect: str, frame_address: str | None = None,
                    params: MavlinkVehicleParams | None = None, wait: float = 10.0,
                    realtime_rate: float = 1.0, follow_autopilot_clock: bool = False,
                    seed: int = 0, run_dir=None, strict: bool = True, tick: float = 0.01,
                    **stack) -> Mission:
    """Connects (as `alight hil`: heartbeat, TIMESYNC, message rates), builds the managed stack on
    the MAVLink vehicle and returns the Mission. The state estimate is `stack["odometry"]`, or
    the simulated autopilot's mocap on the frame channel at `frame_address`.
    `follow_autopilot_clock` (simulated autopilots only) also paces each `tick` on the autopilot's
    clock, as `alight hil --follow-autopilot-clock`."""
    params = params or load_mavlink_vehicle_params()
    clock = WallClock(realtime_rate)
    link = MavlinkLink.open(connect, params.link, clock)
    frames = FrameSubscriber(frame_address) if frame_address else None
    try:
        if "odometry" not in stack:
            if frames is None:
                raise MissionUnavailable("the mission API needs a position estimate: pass "
                                         "odometry=..., or frame_address for the simulated "
                                         "autopilot's mocap")
            stack["odometry"] = channel_odometry(frames, link)
        builder = DiagramBuilder()
        vehicle = builder.AddNamedSystem("vehicle", make_mavlink_vehicle(link, params, frames))
        onboard = add_managed_onboard(builder, vehicle, **stack)
        onboard.loggers.add(builder, "link_status", vehicle.GetOutputPort("link_status"),
                            LINK_STATUS)
        diagram = builder.Build()
        sender = command_sender(diagram.GetSubsystemByName("vehicle"))
        link.wait_for_autopilot(wait)
        rates = link.request_message_rates()
        if follow_autopilot_clock:
            link.follow_autopilot_clock()
        clock.restart()   # onboard time starts with the simulation
        simulator = start_simulation(diagram, seed, realtime_rate=clock.rate)
    except BaseException:
        _close(link, frames)
        raise
    run_dir = Path(run_dir) if run_dir is not None else default_run_dir("mission-mavlink", seed)
    mission = Mission(diagram, onboard, simulator, run_dir, {
        "seed": seed, "connect": connect, "vehicle": params, "message_rates": rates,
        "realtime_rate": realtime_rate, "follow_autopilot_clock": follow_autopilot_clock},
        strict)
    pacer = Pacer(link.autopilot_time, stall=1.0) if follow_autopilot_clock else None
    mission.advance_to = lambda t: _advance(simulator, t, tick, pacer)

    def safe_stop() -> str:
        try:
            sender.wait_idle()
            return link.safe_stop()
        finally:
            _close(link, frames)
    mission.closers.append(safe_stop)
    return mission


def _advance(simulator: Simulator, t_end: float, tick: float, pacer) -> None:
    """AdvanceTo in `tick` steps (the real-time rate paces them), each also waiting for the
    autopilot's clock when `pacer` is given."""
    t = simulator.get_context().get_time()
    while t < t_end - 1e-9:
        t = min(t + tick, t_end)
        if pacer is not None:
            pacer.wait_until(t)
        simulator.AdvanceTo(t)


def _close(link: MavlinkLink, frames: FrameSubscriber | None) -> None:
    link.close()
    if frames is not None:
        frames.close()
