"""`alight sysid`: its options and what it runs (`HELP` says what it does)."""
import argparse
import sys

from alight.diagrams.cli.options import add_common, args_scenario

NAME = "sysid"
HELP = "identify the linear model L(11)-(12) from excitation flights or a PX4 log"


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(NAME, help=HELP, description=HELP)
    add_common(parser)
    parser.add_argument("--ulog", metavar="FILE.ulg",
                        help="identify the attitude model L(12) from a PX4 log instead")
    parser.add_argument("--output", metavar="FILE.yaml",
                        help="write the identified model (the MPC reads models/linear_model.yaml)")
    parser.set_defaults(run=run)
    return parser


def run(args) -> int:
    from pathlib import Path
    from alight.diagrams.running.paths import default_run_dir
    from alight.diagrams.analysis.sysid import identify_from_ulog
    from alight.diagrams.running.sysid import run_sysid
    from alight.systems.control.identification import IdentificationError
    scenario = args_scenario(args)
    run_dir = Path(args.run_dir) if args.run_dir else default_run_dir("sysid",
                                                                      scenario.random_seed)
    try:
        if args.ulog:
            report = identify_from_ulog(Path(args.ulog), plot=run_dir / "ulog_validation.png")
        else:
            report = run_sysid(scenario.vehicle, seed=scenario.random_seed, run_dir=run_dir,
                               output=args.output)
    except IdentificationError as e:
        print(f"alight sysid: cannot identify: {e}", file=sys.stderr)
        return 2
    print("\n".join(report.lines()))
    print(f"plot and flights in {run_dir}" + (f"; model written to {args.output}"
                                             if args.output and not args.ulog else ""))
    return 0
