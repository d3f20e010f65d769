"""`alight hil`: its options and what it runs (`HELP` says what it does)."""
import argparse
import sys

from alight.diagrams.cli.options import frame_address, land_scenario

NAME = "hil"
HELP = "fly the onboard diagram against a MAVLink flight controller (real or simulated)"


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(NAME, help=HELP, description=HELP)
    parser.add_argument("--connect", required=True,
                        help="udp:HOST:PORT, udpin:HOST:PORT, serial:/dev/ttyACM0:921600, ...")
    parser.add_argument("--mission", default="hover", choices=["hover", "fly", "land"],
                        help="hover: scripted attitude/thrust profile; fly: --waypoints with the "
                             "linear MPC; land: the landing mission of --scenario (fly and land "
                             "read the simulated autopilot's mocap from the frame channel)")
    parser.add_argument("--waypoints", default="0,0,2; 3,0,2", metavar="'X,Y,Z; ...'",
                        help="waypoints of --mission fly in W [m]")
    parser.add_argument("--scenario", default="field",
                        help="landing scenario of --mission land (the same as the simulated "
                             "autopilot's --scenario): its mission, MPC tuning, time limits")
    parser.add_argument("--target-speed", type=float, metavar="V",
                        help="with --mission land: the scenario's target speed in m/s")
    parser.add_argument("--profile", default="hover_profile.yaml",
                        help="pilot profile of --mission hover (a path, or a file name in models/)")
    parser.add_argument("--config", default="sim_vehicle.yaml",
                        help="the vehicle model the onboard side assumes (its airframe file)")
    parser.add_argument("--link-config", default="mavlink_vehicle.yaml",
                        help="MAVLink vehicle YAML (a path, or a file name in models/)")
    parser.add_argument("--duration", type=float, metavar="S",
                        help="stop after S seconds (default: the mission's duration)")
    parser.add_argument("--frames", metavar="SOCKET",
                        help="camera frame channel socket, or 'none' (default: from the port)")
    parser.add_argument("--wait", type=float, default=10.0, metavar="S",
                        help="how long to wait for the flight controller (default 10 s)")
    parser.add_argument("--realtime-rate", type=float, default=1.0, metavar="R",
                        help="only against `alight sim-autopilot --realtime-rate R`: run slowed")
    parser.add_argument("--follow-autopilot-clock", action="store_true",
                        help="simulated autopilot only: also pace on its clock, so that a "
                             "simulation falling behind real time slows the onboard side with it")
    parser.add_argument("--down-camera", metavar="DEVICE",
                        help="a real down camera through OpenCV (0, /dev/video0, a pipeline, a "
                             "video file), calibrated by models/down_camera.yaml")
    parser.add_argument("--seed", type=int, default=0, help="seed of every random source")
    parser.add_argument("--run-dir", help="run folder to write (default runs/<time>-hil-<mission>)")
    parser.set_defaults(run=run)
    return parser


def run(args) -> int:
    import logging
    from alight.diagrams.world.sim_vehicle import load_sim_vehicle_config
    from alight.hw.connection import MavlinkConnectionError
    from alight.hw.hil import MissionOptions, MissionUnavailable, run_hil
    from alight.hw.link import LinkTimeout
    from alight.hw.mavlink_vehicle import load_mavlink_vehicle_params
    from alight.hw.opencv_camera import CameraError
    logging.basicConfig(level=logging.INFO, format="%(name)s: %(message)s")
    params = load_mavlink_vehicle_params(args.link_config)
    try:
        options = MissionOptions(vehicle_config=load_sim_vehicle_config(args.config),
                                 profile=args.profile, **_hil_mission_options(args))
    except (ValueError, FileNotFoundError) as e:  # ConfigError is a ValueError
        print(f"alight hil: {e}", file=sys.stderr)
        return 2
    try:
        result = run_hil(args.connect, args.mission, options, params, duration=args.duration,
                         seed=args.seed, run_dir=args.run_dir,
                         frame_address=frame_address(args.frames, args.connect),
                         wait=args.wait, realtime_rate=args.realtime_rate,
                         follow_autopilot_clock=args.follow_autopilot_clock,
                         down_camera=args.down_camera)
    except (MavlinkConnectionError, LinkTimeout, MissionUnavailable, ValueError,
            CameraError) as e:
        print(f"alight hil: {e}", file=sys.stderr)
        return 2
    print("\n".join(result.lines()))
    if args.mission == "land":
        from alight.diagrams.analysis.landing import mission_transitions
        from alight.diagrams.running.run_log import RunLog
        for at, mode, reason in mission_transitions(RunLog(result.run_dir)):
            print(f"  {at:6.2f} s  {mode.name:11s} ({reason.name.lower().replace('_', ' ')})")
    return 1 if result.report.error else 0


def _hil_mission_options(args) -> dict:
    """The waypoints of --mission fly, the landing scenario of --mission land."""
    if args.mission == "fly":
        from alight.diagrams.onboard.waypoints import parse_waypoints
        return {"waypoints": parse_waypoints(args.waypoints)}
    if args.mission == "land":
        return {"scenario": land_scenario(args)}
    return {}
