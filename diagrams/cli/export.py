"""`alight export`: its options and what it runs (`HELP` says what it does)."""
import argparse
import sys

NAME = "export"
HELP = ("write a run folder for other tools: --mcap, an MCAP file with Foxglove schemas "
        "(Foxglove, PlotJuggler)")


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(NAME, help=HELP, description=HELP)
    parser.add_argument("run_dir", metavar="RUN_DIR", help="the run folder to export")
    parser.add_argument("--mcap", metavar="OUT", nargs="?", const="", default=None,
                        help="write an MCAP file (default RUN_DIR/<RUN_DIR's name>.mcap): "
                             "every stream as JSON for plots, the poses and transforms of "
                             "the vehicle, the target and the estimates, the mission's modes")
    parser.set_defaults(run=run)
    return parser


def run(args) -> int:
    if args.mcap is None:
        print("alight export: choose a format (--mcap)", file=sys.stderr)
        return 2
    from alight.diagrams.analysis.mcap_export import export_mcap
    from alight.diagrams.running.run_log import RunFolderError
    try:
        out = export_mcap(args.run_dir, args.mcap or None)
    except RunFolderError as e:
        print(f"alight export: {e}", file=sys.stderr)
        return 1
    print(f"wrote {out} (open it in Foxglove or PlotJuggler)")
    return 0
