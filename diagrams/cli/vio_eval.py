"""`alight vio-eval`: its options and what it runs (`HELP` says what it does)."""
import argparse
import sys

from alight.diagrams.cli.options import VEHICLE_FLAGS, add_common, args_scenario

NAME = "vio-eval"
HELP = ("fly waypoints with the visual-inertial odometry (in the loop or beside mocap) and "
        "report ATE, RPE per metre and processing time; TUM files for evo")


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(NAME, help=HELP, description=HELP)
    add_common(parser, flags=(*VEHICLE_FLAGS, "rgbd_camera"))
    parser.add_argument("--waypoints", default="0,0,2; 6,0,2; 6,6,3; 0,0,2",
                        metavar="'X,Y,Z; ...'", help="waypoints in E [m]")
    parser.add_argument("--open-loop", action="store_true", help="mocap flies, the VIO runs beside")
    parser.set_defaults(run=run)
    return parser


def run(args) -> int:
    from alight.diagrams.onboard.waypoints import parse_waypoints
    from alight.diagrams.running.paths import default_run_dir
    from alight.diagrams.analysis.vio import evaluate_vio
    from alight.diagrams.running.flights import fly_vio
    try:
        waypoints = parse_waypoints(args.waypoints)
    except ValueError as e:
        print(f"alight vio-eval: {e}", file=sys.stderr)
        return 2
    # The forward camera of models/rgbd_camera.yaml unless --rgbd-camera or --set name another.
    scenario = args_scenario(args, [] if args.rgbd_camera else ["vehicle.rgbd_camera: "
                                                                 "rgbd_camera.yaml"])
    run = fly_vio(scenario.vehicle, waypoints, scenario.random_seed,
                  args.run_dir or default_run_dir("vio-eval", scenario.random_seed),
                  closed_loop=not args.open_loop, camera=scenario.vehicle.rgbd_camera)
    for key, value in evaluate_vio(run).items():
        print(f"{key:16s}{value:.4g}" if isinstance(value, float) else f"{key:16s}{value}")
    return 0
