"""`alight thrust-curve`: its options and what it runs (`HELP` says what it does)."""
import argparse
import sys

from alight.diagrams.cli.options import add_common, args_scenario

NAME = "thrust-curve"
HELP = "hover the simulated vehicle at several masses and fit the thrust curve M(32)"


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(NAME, help=HELP, description=HELP)
    add_common(parser)
    parser.add_argument("--masses", default="2.0,2.5,3.0,3.5", metavar="KG,KG,...",
                        help="simulated vehicle masses to hover with")
    parser.set_defaults(run=run)
    return parser


def run(args) -> int:
    from pathlib import Path
    from alight.diagrams.running.paths import default_run_dir
    from alight.diagrams.running.thrust_curve import run_thrust_curve
    from alight.systems.thrust_curve import ThrustCurve
    masses = [float(m) for m in args.masses.split(",")]
    if len(masses) < 2 or min(masses) <= 0:
        print("alight thrust-curve: give at least two positive masses, e.g. 2.0,2.5,3.0",
              file=sys.stderr)
        return 2
    scenario = args_scenario(args)
    config, seed = scenario.vehicle, scenario.random_seed
    run_dir = Path(args.run_dir) if args.run_dir else default_run_dir("thrust-curve", seed)
    fit = run_thrust_curve(config, masses, seed, run_dir)
    rotors = config.airframe
    print("\n".join(fit.lines(ThrustCurve.from_rotors(len(rotors.rotors), rotors.max_thrust,
                                                      rotors.idle))))
    print(f"run folders           {run_dir}")
    return 0
