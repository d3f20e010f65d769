"""The `alight` command line."""
import argparse
import sys

COMMANDS = {
    "hover": "arm, take off on a scripted attitude/thrust profile, hover, land (no position "
             "controller)",
}


def _add_common(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--seed", type=int, default=0, help="seed of every random source")
    parser.add_argument("--config", default="sim_vehicle.yaml",
                        help="simulated vehicle YAML (a path, or a file name in models/)")
    parser.add_argument("--wind", type=float, metavar="KMH",
                        help="mean wind speed in km/h (overrides the config)")
    parser.add_argument("--wind-direction", type=float, metavar="DEG",
                        help="direction the wind blows toward, degrees from x_W, counter-clockwise")
    parser.add_argument("--gusts", type=float, metavar="M_S",
                        help="gust standard deviation in m/s (horizontal)")
    parser.add_argument("--meshcat", action="store_true",
                        help="show the flight live in Meshcat (prints the URL); runs in real time")
    parser.add_argument("--record", metavar="FILE.html",
                        help="write a self-contained Meshcat replay")
    parser.add_argument("--run-dir", help="run folder to write (default runs/<time>-<cmd>-s<seed>)")


def _vehicle_config(args):
    from alight.diagrams.sim_vehicle import load_sim_vehicle_config
    from alight.systems.params import validate
    config = load_sim_vehicle_config(args.config)
    if args.wind is not None:
        config.wind.mean_speed = args.wind / 3.6
    if args.wind_direction is not None:
        config.wind.direction = args.wind_direction
    if args.gusts is not None:
        config.wind.gust_std = args.gusts
    validate(config, "command line")
    return config


def _hover(args) -> int:
    from alight.diagrams.hover import load_pilot_profile, run_hover
    from alight.diagrams.simulation import make_meshcat
    config = _vehicle_config(args)
    profile = load_pilot_profile(args.profile)
    meshcat = make_meshcat(args.meshcat, args.record)
    summary = run_hover(config, profile, seed=args.seed, run_dir=args.run_dir, meshcat=meshcat,
                        record=args.record, realtime_rate=1.0 if args.meshcat else 0.0)
    print("\n".join(summary.lines()))
    _keep_meshcat_open(args)
    return 0


def _keep_meshcat_open(args) -> None:
    """The Meshcat server lives in this process: keep it up until the user is done looking."""
    if args.meshcat and sys.stdin.isatty():
        input("Meshcat stays up for browsing the scene; press Enter to exit. ")


def make_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="alight", description="GPS-free multirotor autonomy as Drake diagrams.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="commands:\n" + "\n".join(f"  {name:10s}{text}" for name, text in COMMANDS.items()))
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    hover = sub.add_parser("hover", help=COMMANDS["hover"], description=COMMANDS["hover"])
    _add_common(hover)
    hover.add_argument("--profile", default="hover_profile.yaml",
                       help="pilot profile YAML (a path, or a file name in models/)")
    hover.set_defaults(run=_hover)
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
