"""`alight sim-autopilot`: its options and what it runs (`HELP` says what it does)."""
import argparse
import sys

from alight.diagrams.cli.options import VEHICLE_FLAGS, add_common, args_scenario, frame_address

NAME = "sim-autopilot"
HELP = "serve the simulated vehicle in real time as a PX4 autopilot over MAVLink"


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(NAME, help=HELP, description=HELP)
    add_common(parser, flags=(*VEHICLE_FLAGS, "target_speed"))
    parser.add_argument("--listen", default="udp:127.0.0.1:14540",
                        help="MAVLink endpoint (udp:HOST:PORT binds it; see docs/hardware.md)")
    parser.add_argument("--gcs", metavar="URL",
                        help="a second MAVLink instance for a ground station (as PX4 SITL's "
                             "udp 14550 beside the offboard link 14540), e.g. "
                             "udp:127.0.0.1:14550: its own peer, telemetry, commands, "
                             "parameters, mission requests")
    parser.add_argument("--autopilot", default="sim_autopilot.yaml",
                        help="MAVLink endpoint YAML (a path, or a file name in models/)")
    parser.add_argument("--duration", type=float, metavar="S",
                        help="stop after S seconds (default: run until Ctrl-C)")
    parser.add_argument("--frames", metavar="SOCKET",
                        help="camera frame channel socket, or 'none' (default: from the port)")
    parser.add_argument("--stats", metavar="FILE.json",
                        help="write the link statistics (setpoint rate, latency) at exit")
    parser.add_argument("--wait-for-client", action=argparse.BooleanOptionalAction, default=True,
                        help="start the simulation (its world, e.g. a landing target's drive, "
                             "and the autopilot's clock) at the first valid MAVLink frame from a "
                             "client, not at launch (default yes)")
    parser.add_argument("--realtime-rate", type=float, default=1.0, metavar="R",
                        help="slow the simulation to R x real time, R in (0, 1] (a loaded "
                             "machine; run `alight hil` with the same R)")
    parser.set_defaults(run=run)
    return parser


def run(args) -> int:
    import logging
    from alight.diagrams.running.simulation import make_meshcat
    from alight.hw.connection import MavlinkConnectionError
    from alight.hw.sim_autopilot import load_sim_autopilot_params, run_sim_autopilot
    logging.basicConfig(level=logging.INFO, format="%(name)s: %(message)s")
    from alight.diagrams.scenario import vehicle_config
    from alight.systems.params import ConfigError
    try:   # a landing scenario's world: its target, down camera, wind (`alight hil --mission land`)
        scenario = args_scenario(args)
    except ConfigError as e:
        print(f"alight sim-autopilot: {e}", file=sys.stderr)
        return 2
    # the onboard side flies on the frame channel's mocap (hw/hil.py): no VIO camera here
    config = vehicle_config(scenario, vio_camera=False)
    params = load_sim_autopilot_params(args.autopilot)
    frames = frame_address(args.frames, args.listen)
    meshcat = make_meshcat(args.meshcat, args.record)
    try:
        report, run_dir, stats = run_sim_autopilot(
            args.listen, config, params, duration=args.duration, seed=scenario.random_seed,
            run_dir=args.run_dir, frame_address=frames, stats_file=args.stats, meshcat=meshcat,
            record=args.record, realtime_rate=args.realtime_rate,
            wait_for_client=args.wait_for_client, gcs=args.gcs, ready=lambda: print(
                f"sim-autopilot: ready on {args.listen}"
                + (f", ground station on {args.gcs}" if args.gcs else "")
                + (f", camera frames on {frames}" if frames else ""), flush=True))
    except (MavlinkConnectionError, ValueError) as e:
        print(f"alight sim-autopilot: {e}", file=sys.stderr)
        return 2
    print("\n".join(report.lines() + [f"run folder        {run_dir}"]))
    return 0
