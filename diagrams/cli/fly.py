"""`alight fly`: its options and what it runs (`HELP` says what it does)."""
import argparse
import sys

from alight.diagrams.cli.options import VEHICLE_FLAGS, add_common, args_scenario, keep_meshcat_open

NAME = "fly"
HELP = ("take off, fly a trajectory through waypoints (or from a file) on the flight stack's "
        "trackers and controllers (control manager, UAV manager), land; exits 1 when the flight "
        "failed (a routine refused or timed out, a failsafe, not landed on its legs at rest)")


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(NAME, help=HELP, description=HELP)
    add_common(parser, flags=(*VEHICLE_FLAGS, "estimator"))
    parser.add_argument("--waypoints", metavar="'X,Y,Z; X,Y,Z; ...'",
                        help="waypoints in W [m], e.g. '0,0,5; 10,0,5; 10,10,3': a trajectory "
                             "through them is generated under the constraint group (M Sec. 6)")
    parser.add_argument("--trajectory", metavar="FILE.csv",
                        help="CSV with a header: x,y,z[,heading] waypoints (a trajectory is "
                             "generated), or t,x,y,z[,heading] samples (flown as they are)")
    parser.add_argument("--controller", metavar="NAME",
                        help="the flying controller (models/control_manager.yaml: se3, mpc, "
                             "linear_mpc, ...; default models/uav_manager.yaml)")
    parser.add_argument("--tracker", metavar="NAME",
                        help="the flying tracker (default mpc_tracker)")
    parser.add_argument("--switch-controller-at", action="append", default=[],
                        metavar="T:NAME", help="switch to controller NAME at T s (repeatable)")
    parser.add_argument("--constraints", metavar="GROUP",
                        help="constraint group of the generated trajectory (slow, medium, fast)")
    parser.add_argument("--takeoff-height", type=float, default=2.0, metavar="M",
                        help="take-off height above the start [m] (default 2)")
    parser.add_argument("--bank", metavar="FILE.yaml",
                        help="the estimator bank of --estimator bank (sources, filters, arbiter; a "
                             "path, or a file name in models/; sets onboard.estimator_bank)")
    parser.set_defaults(run=run)
    return parser


def run(args) -> int:
    from alight.diagrams.running.simulation import make_meshcat
    from alight.diagrams.analysis.flight import managed_flight_failures, summarize_managed_flight
    from alight.diagrams.running.flights import fly_plan
    from alight.diagrams.scenario import vehicle_config
    from alight.systems.params import ConfigError
    try:
        plan = _flight_plan(args)
        scenario = args_scenario(args, [f"onboard.estimator_bank: {args.bank}"]
                                 if args.bank else [])
        stack = _fly_stack(args, scenario)
    except (ValueError, ConfigError) as e:
        print(f"alight fly: {e}", file=sys.stderr)
        return 2
    meshcat = make_meshcat(args.meshcat, args.record)
    run = fly_plan(plan, vehicle_config(scenario), seed=scenario.random_seed, run_dir=args.run_dir,
                   meshcat=meshcat,
                   record=args.record, realtime_rate=1.0 if args.meshcat else 0.0,
                   controller=args.controller, tracker=args.tracker, **stack)
    print("\n".join(summarize_managed_flight(run)))
    keep_meshcat_open(args)
    return 1 if managed_flight_failures(run) else 0


def _flight_plan(args):
    """The --waypoints or --trajectory of `alight fly` as a FlightPlan (ValueError if bad)."""
    from alight.diagrams.onboard.waypoints import parse_waypoints
    from alight.diagrams.onboard.uav import FlightPlan, read_trajectory_file
    if (args.waypoints is None) == (args.trajectory is None):
        raise ValueError("give exactly one of --waypoints and --trajectory")
    if not (args.takeoff_height > 0.0):
        raise ValueError(f"--takeoff-height must be > 0 m, got {args.takeoff_height}")
    if args.waypoints is not None:
        return FlightPlan(waypoints=parse_waypoints(args.waypoints),
                          takeoff_height=args.takeoff_height, constraints=args.constraints)
    rows, period = read_trajectory_file(args.trajectory)
    if period is None:
        return FlightPlan(waypoints=rows, takeoff_height=args.takeoff_height,
                          constraints=args.constraints)
    return FlightPlan(samples=rows, sample_period=period, takeoff_height=args.takeoff_height)


def _fly_stack(args, scenario) -> dict:
    """The managed stack's options of `alight fly`: the scenario's control manager, names
    checked against its lists, the scenario's estimator (VIO by default, mocap, the bank), the
    scheduled controller switches."""
    from alight.diagrams.onboard.control_manager import parse_switch
    from alight.diagrams.stacks import scenario_estimator
    from alight.systems.params import ConfigError
    config = scenario.onboard.control_manager
    for option, name, names in (("--controller", args.controller, config.names),
                                ("--tracker", args.tracker, config.tracker_names)):
        if name is not None and name not in names:
            raise ConfigError(f"{option} {name!r} is not one of {names} "
                              f"(onboard.control_manager)")
    stack = {"config": config, "schedule": [parse_switch(text, config.names)
                                            for text in args.switch_controller_at]}
    odometry = scenario_estimator(scenario, anchored=False)
    stack["odometry"] = odometry
    if hasattr(odometry, "log"):  # the VIO's and the bank's own streams
        stack["log"] = odometry.log
    return stack
