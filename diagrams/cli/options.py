"""Options and helpers shared by the commands of the command line."""
import argparse
import dataclasses as dc
import sys
from typing import Callable

import yaml


@dc.dataclass(frozen=True)
class Flag:
    """A convenience flag: an override of one scenario key, declared once for every command
    that takes it (same name, unit and meaning everywhere)."""
    flag: str
    key: str
    help: str
    type: Callable = float
    metavar: str | None = None
    choices: tuple | None = None
    to_value: Callable = lambda value: value    # the flag's unit -> the key's
    also: tuple[str, ...] = ()                   # further keys set to the same value

    def add(self, parser: argparse.ArgumentParser) -> None:
        keys = ", ".join((self.key, *self.also))
        parser.add_argument(self.flag, type=self.type, metavar=self.metavar,
                            choices=self.choices, help=f"{self.help} (sets {keys})")

    def overrides(self, value) -> list[str]:
        return [yaml.safe_dump({key: self.to_value(value)}, default_flow_style=True).strip()[1:-1]
                for key in (self.key, *self.also)]


LANDING_STACKS = {"direct": "landing", "managed": "landing_managed"}
FLAGS = {flag.flag.lstrip("-").replace("-", "_"): flag for flag in (
    Flag("--config", "vehicle", "simulated vehicle YAML (a path, or a file name in models/)",
         str, "FILE.yaml"),
    Flag("--target-speed", "target_motion.speed", "target speed in m/s", float, "V"),
    Flag("--wind", "vehicle.wind.mean_speed", "mean wind speed in km/h", float, "KMH",
         to_value=lambda kmh: kmh / 3.6),
    Flag("--wind-direction", "vehicle.wind.direction",
         "direction the wind blows toward, degrees from x_W, counter-clockwise", float, "DEG"),
    Flag("--gusts", "vehicle.wind.gust_std", "gust standard deviation in m/s (horizontal)",
         float, "M_S"),
    Flag("--camera", "vehicle.down_camera.source", "camera images: the sensor models "
         "(geometric) or Drake-rendered images through the image pipelines, for the down camera "
         "and the VIO's forward RGB-D camera alike (rendered: the acceptance mode)", str,
         choices=("geometric", "rendered"), also=("onboard.vio_camera.source",)),
    Flag("--rgbd-camera", "vehicle.rgbd_camera", "forward RGB-D camera YAML (a path, or a file "
         "name in models/; its source geometric or rendered)", str, "FILE.yaml"),
    Flag("--estimator", "onboard.estimator", "odometry: mocap, vio (L Sec. 5.1, the forward "
         "RGB-D camera), bank or a filter of the estimator bank", str, "NAME"),
    Flag("--stack", "onboard.stack", "direct: the mission drives the linear MPC; managed: the "
         "control manager with the landoff, MPC and target trackers", str,
         choices=tuple(LANDING_STACKS), to_value=LANDING_STACKS.get),
    Flag("--controller", "onboard.controller", "with --stack managed: the control manager's "
         "controller that flies (linear_mpc, mpc, se3)", str, "NAME"))}
VEHICLE_FLAGS = ("config", "wind", "wind_direction", "gusts")
LANDING_FLAGS = ("target_speed", "wind", "wind_direction", "gusts", "camera", "estimator",
                 "stack", "controller")


def add_scenario_options(parser: argparse.ArgumentParser, scenario: str | None,
                         flags=VEHICLE_FLAGS, scenario_help: str | None = None) -> None:
    """--scenario (default `scenario`), the convenience `flags` of FLAGS, --set and --seed."""
    parser.add_argument("--scenario", default=scenario, help=scenario_help or (
        "scenario: a name (field, mbzirc, field_hil, waypoints, hover), a scenario YAML, or a "
        "run folder's scenario.yaml to fly it again" + (f" (default {scenario})"
                                                        if scenario else "")))
    for name in flags:
        FLAGS[name].add(parser)
    parser.set_defaults(scenario_flags=tuple(flags))
    parser.add_argument("--set", action="append", default=[], metavar="'KEY.SUB: VALUE'",
                        help="override one scenario key with a YAML value (repeatable, applied "
                             "after the flags), e.g. --set 'vehicle.wind.gust_std: 0.8'")
    parser.add_argument("--seed", type=int,
                        help="seed of every random source (sets random_seed; default the "
                             "scenario's)")


def add_common(parser: argparse.ArgumentParser, scenario: str = "waypoints",
               flags=VEHICLE_FLAGS) -> None:
    """The simulated vehicle's scenario options, a live view and the run folder."""
    add_scenario_options(parser, scenario, flags)
    parser.add_argument("--meshcat", action="store_true",
                        help="show the flight live in Meshcat (prints the URL); runs in real time")
    parser.add_argument("--record", metavar="FILE.html",
                        help="write a self-contained Meshcat replay")
    parser.add_argument("--run-dir", help="run folder to write (default runs/<time>-<cmd>-s<seed>)")


def scenario_overrides(args, extra=()) -> list[str]:
    """The command line's overrides: its flags, `extra`, the seed, then every --set."""
    overrides = [override for name in args.scenario_flags if getattr(args, name) is not None
                 for override in FLAGS[name].overrides(getattr(args, name))]
    if getattr(args, "seed", None) is not None:
        overrides.append(f"random_seed: {args.seed}")
    return [*overrides, *extra, *args.set]


def args_scenario(args, extra=(), scenario: str | None = None):
    """The scenario the command line names, with its overrides (ConfigError if bad)."""
    from alight.diagrams.scenario import load_scenario
    return load_scenario(scenario or args.scenario, overrides=scenario_overrides(args, extra))


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
