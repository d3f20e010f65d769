"""`alight hover`: its options and what it runs (`HELP` says what it does)."""
import argparse

from alight.diagrams.cli.options import add_common, args_scenario, keep_meshcat_open

NAME = "hover"
HELP = ("arm, take off on a scripted attitude/thrust profile, hover, land (no position "
        "controller)")


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(NAME, help=HELP, description=HELP)
    add_common(parser, "hover")
    parser.add_argument("--profile", metavar="FILE.yaml",
                        help="pilot profile YAML (a path, or a file name in models/; sets "
                             "mission; default the scenario's, models/hover_profile.yaml)")
    parser.set_defaults(run=run)
    return parser


def run(args) -> int:
    from alight.diagrams.analysis.flight import summarize_hover
    from alight.diagrams.running.runner import run as run_scenario
    from alight.diagrams.running.simulation import make_meshcat
    scenario = args_scenario(args, [f"mission: {args.profile}"] if args.profile else [])
    meshcat = make_meshcat(args.meshcat, args.record)
    run = run_scenario(scenario, run_dir=args.run_dir, meshcat=meshcat, record=args.record,
                       realtime_rate=1.0 if args.meshcat else 0.0, command="hover")
    print("\n".join(summarize_hover(run, scenario.mission).lines()))
    keep_meshcat_open(args)
    return 0
