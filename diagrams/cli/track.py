"""`alight track`: its options and what it runs (`HELP` says what it does)."""
import argparse
import sys

from alight.diagrams.cli.options import add_common, keep_meshcat_open, args_scenario

NAME = "track"
HELP = ("fly the flight-stack paper's experiments (steps, 5 m circle, estimator noise or "
        "jump) with the SE(3) or MPC force-feedback controller")


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(NAME, help=HELP, description=HELP)
    add_common(parser)
    parser.add_argument("--trajectory", choices=["circle", "steps", "hover"], default="circle")
    parser.add_argument("--controller", choices=["se3", "mpc", "linear_mpc"], default="se3",
                        help="linear_mpc: the landing paper's MPC (attitude+thrust), for "
                             "comparison")
    parser.add_argument("--radius", type=float, default=5.0, help="circle radius [m]")
    parser.add_argument("--speed", type=float, default=7.0, help="circle speed [m/s]")
    parser.add_argument("--heading", choices=["center", "constant"], default="center")
    parser.add_argument("--laps", type=float, default=3.0,
                        help="circle laps (the last is scored; the disturbance estimators learn "
                             "the drag on the laps before)")
    parser.add_argument("--estimator-noise", type=float, default=0.0, metavar="SIGMA",
                        help="white noise on the estimated position [m] and velocity [m/s]")
    parser.add_argument("--estimator-jump", type=float, default=0.0, metavar="METRES",
                        help="jump of the estimated position along x, 2 s into the experiment")
    parser.set_defaults(run=run)
    return parser


def run(args) -> int:
    from alight.diagrams.running.simulation import make_meshcat
    from alight.diagrams.analysis.track import score
    from alight.diagrams.running.track import TrackExperiment, fly_track
    try:
        experiment = TrackExperiment(
            trajectory=args.trajectory, controller=args.controller, radius=args.radius,
            speed=args.speed, heading=args.heading, laps=args.laps,
            estimator_noise=args.estimator_noise, estimator_jump=args.estimator_jump)
    except ValueError as e:
        print(f"alight track: {e}", file=sys.stderr)
        return 2
    from alight.systems.params import validate
    validate(experiment, "command line")
    scenario = args_scenario(args)
    meshcat = make_meshcat(args.meshcat, args.record)
    run = fly_track(scenario.vehicle, experiment, seed=scenario.random_seed, run_dir=args.run_dir, meshcat=meshcat,
                    record=args.record, realtime_rate=1.0 if args.meshcat else 0.0)
    print("\n".join(score(run).lines()))
    print(f"run folder            {run.path} (plots: track.png)")
    keep_meshcat_open(args)
    return 0
