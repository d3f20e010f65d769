"""`alight hover`: its options and what it runs (`HELP` says what it does)."""
import argparse

from alight.diagrams.cli.options import add_common, keep_meshcat_open, sim_vehicle_config

NAME = "hover"
HELP = ("arm, take off on a scripted attitude/thrust profile, hover, land (no position "
        "controller)")


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(NAME, help=HELP, description=HELP)
    add_common(parser)
    parser.add_argument("--profile", default="hover_profile.yaml",
                        help="pilot profile YAML (a path, or a file name in models/)")
    parser.set_defaults(run=run)
    return parser


def run(args) -> int:
    from alight.diagrams.onboard.pilot import load_pilot_profile
    from alight.diagrams.running.flights import run_hover
    from alight.diagrams.running.simulation import make_meshcat
    config = sim_vehicle_config(args)
    profile = load_pilot_profile(args.profile)
    meshcat = make_meshcat(args.meshcat, args.record)
    summary = run_hover(config, profile, seed=args.seed, run_dir=args.run_dir, meshcat=meshcat,
                        record=args.record, realtime_rate=1.0 if args.meshcat else 0.0)
    print("\n".join(summary.lines()))
    keep_meshcat_open(args)
    return 0
