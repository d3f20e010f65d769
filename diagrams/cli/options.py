"""Options and helpers shared by the commands of the command line."""
import argparse
import sys


def add_common(parser: argparse.ArgumentParser) -> None:
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


def sim_vehicle_config(args, config=None):
    """`config` (default: the --config file) with the command line's wind overrides."""
    from alight.diagrams.world.sim_vehicle import load_sim_vehicle_config
    from alight.systems.params import validate
    config = config or load_sim_vehicle_config(args.config)
    if args.wind is not None:
        config.wind.mean_speed = args.wind / 3.6
    if args.wind_direction is not None:
        config.wind.direction = args.wind_direction
    if args.gusts is not None:
        config.wind.gust_std = args.gusts
    validate(config, "command line")
    return config


def keep_meshcat_open(args) -> None:
    """The Meshcat server lives in this process: keep it up until the user is done looking."""
    if args.meshcat and sys.stdin.isatty():
        input("Meshcat stays up for browsing the scene; press Enter to exit. ")


def frame_address(value: str | None, url: str) -> str | None:
    """--frames: 'none', a socket path, or by default one derived from the MAVLink port."""
    from alight.hw.frame_channel import default_frame_address
    if value == "none" or (value is None and url.startswith("serial:")):
        return None
    return value or default_frame_address(url.rsplit(":", 1)[-1])


def land_scenario(args):
    from alight.diagrams.running.campaign import CampaignJob, scenario_for
    return scenario_for(CampaignJob(args.scenario, args.target_speed, args.seed, "",
                                    getattr(args, "wind", None), getattr(args, "gusts", None),
                                    getattr(args, "camera", None),
                                    estimator=getattr(args, "estimator", None)))


def check_landing_stack(args) -> None:
    """--stack / --controller: raises ConfigError naming the allowed controllers."""
    from alight.diagrams.onboard.landing_managed import landing_manager_config
    from alight.systems.params import ConfigError
    if args.stack == "managed":
        landing_manager_config(args.controller)
    elif args.controller != "linear_mpc":
        raise ConfigError(f"--controller {args.controller}: the direct stack flies linear_mpc "
                          f"only (use --stack managed)")


def add_landing_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--scenario", default="field",
                        help="mbzirc, field, or a scenario YAML (a path, or a file in models/)")
    parser.add_argument("--wind", type=float, metavar="KMH", help="mean wind speed in km/h")
    parser.add_argument("--gusts", type=float, metavar="M_S",
                        help="gust standard deviation in m/s")
    parser.add_argument("--camera", choices=["geometric", "rendered"],
                        help="down camera source (default: the scenario's)")
    parser.add_argument("--estimator", metavar="NAME",
                        help="odometry (default: the scenario's): mocap, vio (L Sec. 5.1, the "
                             "forward RGB-D camera), bank or a filter of the estimator bank")
    parser.add_argument("--seed", type=int, default=0, help="seed of every random source")
    parser.add_argument("--stack", choices=["direct", "managed"], default="direct",
                        help="direct: the mission drives the linear MPC (default); managed: the "
                             "control manager with the landoff, MPC and target trackers")
    parser.add_argument("--controller", default="linear_mpc", metavar="NAME",
                        help="with --stack managed: the control manager's controller that flies "
                             "(linear_mpc, mpc, se3)")
