"""`alight land`: its options and what it runs (`HELP` says what it does)."""
import argparse
import sys

from alight.diagrams.cli.options import (LANDING_FLAGS, add_scenario_options, args_scenario,
                                         keep_meshcat_open)

NAME = "land"
HELP = ("take off, find the moving car with the down camera, follow it and land on it (the "
        "landing paper's mission); prints its L Table 1 row")


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(NAME, help=HELP, description=HELP)
    add_scenario_options(parser, "field", LANDING_FLAGS)
    parser.add_argument("--meshcat", action="store_true",
                        help="show the flight live in Meshcat (prints the URL); runs in real time")
    parser.add_argument("--record", metavar="FILE.html", help="write a self-contained replay")
    parser.add_argument("--run-dir", help="run folder to write (default runs/<time>-land-s<seed>)")
    parser.set_defaults(run=run)
    return parser


def run(args) -> int:
    import time
    from alight.diagrams.analysis.landing import (mission_transitions, score_landing,
                                                  tracker_switches)
    from alight.diagrams.analysis.landing_plots import plot_mission, plot_paths
    from alight.diagrams.running.runner import run as run_scenario
    from alight.diagrams.running.simulation import make_meshcat
    from alight.diagrams.scenario import vehicle_config
    from alight.systems.params import ConfigError
    try:
        scenario = args_scenario(args)
    except ConfigError as e:
        print(f"alight land: {e}", file=sys.stderr)
        return 2
    meshcat = make_meshcat(args.meshcat, args.record)
    start = time.perf_counter()
    run = run_scenario(scenario, run_dir=args.run_dir, meshcat=meshcat, record=args.record,
                       realtime_rate=1.0 if args.meshcat else 0.0, command="land")
    wall = time.perf_counter() - start
    impact = scenario.scoring.impact
    score = score_landing(run, impact.vertical_speed, impact.horizontal_speed)
    for at, mode, reason in mission_transitions(run):
        print(f"  {at:6.2f} s  {mode.name:11s} ({reason.name.lower().replace('_', ' ')})")
    if scenario.onboard.stack == "landing_managed":
        print(f"  control manager ({scenario.onboard.controller}): tracker " + ", ".join(
            f"{name} at {at:.2f} s" for at, name in tracker_switches(run)))
    flown = vehicle_config(scenario)      # the RGB-D camera the VIO flies on, if it does
    cameras = flown.down_camera.source, flown.rgbd_camera.source
    print(f"{scenario.name} scenario, {' / '.join(cameras)} down / RGB-D camera, "
          f"{scenario.onboard.estimator} odometry, {scenario.onboard.stack} stack, seed "
          f"{scenario.random_seed}:")
    print("  " + score.row())
    print(f"  plots {plot_mission(run, run.path / 'mission.png')}, "
          f"{plot_paths(run, run.path / 'paths.png')}")
    print(f"  simulated {run.metadata['duration']:.1f} s in {wall:.1f} s of wall time (real-time "
          f"factor {run.metadata['duration'] / wall:.2f}, including set-up)")
    print(f"  run folder {run.path} (fly it again: alight land --scenario "
          f"{run.path / 'scenario.yaml'})" + (f"; replay {args.record}" if args.record else ""))
    keep_meshcat_open(args)
    return 0 if score.success else 1
