"""The `alight` command line: one module per command (`NAME`, `HELP`, `add_parser(subparsers)`,
`run(args)`), the options they share in options.py. The commands import what they run inside
`run`, so that `alight --help` starts fast."""
import argparse
import sys

from alight.diagrams.cli import (campaign, export, fly, hil, hover, land, sim_autopilot,
                                 sysid, thrust_curve, track, vio_eval)

PARSERS = (hover, fly, sysid, sim_autopilot, track, thrust_curve, hil, land, campaign, vio_eval,
           export)
COMMANDS = {command.NAME: command.HELP for command in (land, campaign, hover, fly, sysid,
                                                       sim_autopilot, hil, track, thrust_curve,
                                                       vio_eval, export)}


def make_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="alight", description="GPS-free multirotor autonomy as Drake diagrams.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="commands:\n" + "\n".join(f"  {name:15s}{text}" for name, text in COMMANDS.items()))
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for command in PARSERS:
        command.add_parser(subparsers)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = make_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 0
    from alight.systems.params import ConfigError
    try:
        return args.run(args)
    except ConfigError as e:
        print(f"alight: configuration error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
