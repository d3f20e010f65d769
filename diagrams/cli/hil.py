"""`alight hil`: its options and what it runs (`HELP` says what it does)."""
import argparse
import contextlib
import sys

from alight.diagrams.cli.options import add_scenario_options, args_scenario, frame_address

NAME = "hil"
HELP = "fly the onboard diagram against a MAVLink flight controller (real or simulated)"


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(NAME, help=HELP, description=HELP)
    where = parser.add_mutually_exclusive_group(required=True)
    where.add_argument("--connect",
                       help="udp:HOST:PORT, udpin:HOST:PORT, serial:/dev/ttyACM0:921600, ...")
    where.add_argument("--local", action="store_true",
                       help="start `alight sim-autopilot` with this scenario's world on a free "
                            "local port and fly against it (a HIL demo in one command)")
    parser.add_argument("--gcs", metavar="URL",
                        help="with --local: the sim-autopilot's ground-station link (its "
                             "--gcs, e.g. udp:127.0.0.1:14550) for a ground station or MAVSDK "
                             "client beside the flight")
    parser.add_argument("--mission", default="hover", choices=["hover", "fly", "land"],
                        help="hover: scripted attitude/thrust profile; fly: --waypoints with the "
                             "linear MPC; land: the landing mission of --scenario (fly and land "
                             "read the simulated autopilot's mocap from the frame channel)")
    parser.add_argument("--waypoints", metavar="'X,Y,Z; ...'",
                        help="waypoints of --mission fly in W [m] (sets mission.waypoints; "
                             "default the scenario's, '0,0,2; 3,0,2')")
    parser.add_argument("--profile", metavar="FILE.yaml",
                        help="pilot profile of --mission hover (sets mission; a path, or a file "
                             "name in models/)")
    add_scenario_options(parser, None, ("config", "target_speed"), scenario_help=(
        "the scenario whose onboard stack flies (default by --mission: hover, waypoints, "
        "field; land: the same as the simulated autopilot's --scenario): its mission, "
        "tunings, time limits"))
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
    parser.add_argument("--follow-autopilot-clock", action=argparse.BooleanOptionalAction,
                        help="also pace on the autopilot's clock, so that a simulation falling "
                             "behind real time slows the onboard side with it (default: when "
                             "its HEARTBEAT says the vehicle is simulated, MAV_MODE_FLAG_HIL_"
                             "ENABLED, as alight sim-autopilot and PX4 with SYS_HITL 1 do)")
    parser.add_argument("--down-camera", metavar="DEVICE",
                        help="a real down camera through OpenCV (0, /dev/video0, a pipeline, a "
                             "video file), calibrated by models/down_camera.yaml")
    parser.add_argument("--run-dir", help="run folder to write (default runs/<time>-hil-<mission>)")
    parser.set_defaults(run=run)
    return parser


# --mission: its default scenario and the stacks that fly it.
MISSIONS = {"hover": ("hover", ("hover",)), "fly": ("waypoints", ("waypoints",)),
            "land": ("field", ("landing", "landing_managed"))}


def run(args) -> int:
    import logging
    from alight.hw.connection import MavlinkConnectionError
    from alight.hw.hil import MissionUnavailable, run_hil
    from alight.hw.link import LinkTimeout
    from alight.hw.mavlink_vehicle import load_mavlink_vehicle_params
    from alight.hw.opencv_camera import CameraError
    logging.basicConfig(level=logging.INFO, format="%(name)s: %(message)s")
    params = load_mavlink_vehicle_params(args.link_config)
    if args.gcs is not None and not args.local:
        print("alight hil: --gcs goes with --local (the simulated autopilot's second link)",
              file=sys.stderr)
        return 2
    try:
        scenario = _hil_scenario(args)
    except ValueError as e:  # ConfigError is a ValueError
        print(f"alight hil: {e}", file=sys.stderr)
        return 2
    try:
        with (local_autopilot(scenario, args.realtime_rate, args.run_dir, args.gcs)
              if args.local
              else contextlib.nullcontext(args.connect)) as connect:
            result = run_hil(connect, scenario, params, duration=args.duration,
                             run_dir=args.run_dir,
                             frame_address=frame_address(args.frames, connect),
                             wait=args.wait, realtime_rate=args.realtime_rate,
                             follow_autopilot_clock=args.follow_autopilot_clock,
                             down_camera=args.down_camera)
    except (MavlinkConnectionError, LinkTimeout, MissionUnavailable, ValueError,
            CameraError, RuntimeError) as e:
        print(f"alight hil: {e}", file=sys.stderr)
        return 2
    print("\n".join(result.lines()))
    if args.mission == "land":
        from alight.diagrams.analysis.landing import mission_transitions
        from alight.diagrams.running.run_log import RunLog
        for at, mode, reason in mission_transitions(RunLog(result.run_dir)):
            print(f"  {at:6.2f} s  {mode.name:11s} ({reason.name.lower().replace('_', ' ')})")
    return 1 if result.report.error or result.finished is False else 0


@contextlib.contextmanager
def local_autopilot(scenario, realtime_rate: float, run_dir: str | None,
                    gcs: str | None = None, ready_timeout=120.0):
    """`alight sim-autopilot` with `scenario`'s world (its resolved YAML) on a free loopback UDP
    port (and its ground-station link on `gcs`, if given), its output prefixed 'sim-autopilot| '
    on stderr; yields the connection string; Ctrl-C (SIGINT) to it at the end, which writes its
    run folder (RUN_DIR-sim-autopilot with --run-dir). RuntimeError if it does not get ready."""
    import signal
    import socket
    import subprocess
    import tempfile
    import threading
    from alight.diagrams.scenario import write_scenario
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        url = f"udp:127.0.0.1:{s.getsockname()[1]}"
    with tempfile.TemporaryDirectory() as folder:
        command = [sys.executable, "-m", "alight.diagrams.cli", "sim-autopilot", "--listen", url,
                   "--scenario", str(write_scenario(folder, scenario)),
                   "--realtime-rate", str(realtime_rate)]
        if gcs is not None:
            command += ["--gcs", gcs]
        if run_dir is not None:
            command += ["--run-dir", f"{run_dir.rstrip('/')}-sim-autopilot"]
        process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                   text=True)
        ready = threading.Event()

        def forward():
            for line in process.stdout:
                print(f"sim-autopilot| {line}", end="", file=sys.stderr, flush=True)
                if line.startswith("sim-autopilot: ready"):
                    ready.set()
        reader = threading.Thread(target=forward, daemon=True)
        reader.start()
        try:
            if not ready.wait(ready_timeout) or process.poll() is not None:
                raise RuntimeError(f"the local sim-autopilot did not start (exit status "
                                   f"{process.poll()})")
            yield url
        finally:
            if process.poll() is None:
                process.send_signal(signal.SIGINT)
            try:
                process.wait(60)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
            reader.join(5)


def _hil_scenario(args):
    """The scenario of --mission (or --scenario) with the waypoints of --mission fly, the
    profile of --mission hover and the overrides; ValueError if they do not fit."""
    from alight.diagrams.onboard.waypoints import parse_waypoints
    default, stacks = MISSIONS[args.mission]
    extra = []
    if args.waypoints is not None:
        if args.mission != "fly":
            raise ValueError("--waypoints goes with --mission fly")
        extra.append(f"mission.waypoints: {parse_waypoints(args.waypoints).tolist()}")
    if args.profile is not None:
        if args.mission != "hover":
            raise ValueError("--profile goes with --mission hover")
        extra.append(f"mission: {args.profile}")
    scenario = args_scenario(args, extra, args.scenario or default)
    if scenario.onboard.stack not in stacks:
        raise ValueError(f"--mission {args.mission} flies the {' or '.join(stacks)} stack; the "
                         f"scenario's onboard.stack is {scenario.onboard.stack!r}")
    return scenario
