"""The `alight` command line."""
import argparse
import sys

COMMANDS = {
    "land": "take off, find the moving car with the down camera, follow it and land on it "
            "(the landing paper's mission); prints its L Table 1 row",
    "campaign": "Monte Carlo landings per target speed (local processes or a Dask cluster), "
                "summarized like L Table 1",
    "hover": "arm, take off on a scripted attitude/thrust profile, hover, land (no position "
             "controller)",
    "fly": "take off, fly a trajectory through waypoints (or from a file) on the flight stack's "
           "trackers and controllers (control manager, UAV manager), land",
    "sysid": "identify the linear model L(11)-(12) from excitation flights or a PX4 log",
    "sim-autopilot": "serve the simulated vehicle in real time as a PX4 autopilot over MAVLink",
    "hil": "fly the onboard diagram against a MAVLink flight controller (real or simulated)",
    "track": "fly the flight-stack paper's experiments (steps, 5 m circle, estimator noise or "
             "jump) with the SE(3) or MPC force-feedback controller",
    "thrust-curve": "hover the simulated vehicle at several masses and fit the thrust curve "
                    "M(32)",
    "vio-eval": "fly waypoints with the visual-inertial odometry (in the loop or beside mocap) "
                "and report ATE, RPE per metre and processing time; TUM files for evo",
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


def _vehicle_config(args, config=None):
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


def _hover(args) -> int:
    from alight.diagrams.onboard.pilot import load_pilot_profile
    from alight.diagrams.running.flights import run_hover
    from alight.diagrams.running.simulation import make_meshcat
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


def _fly(args) -> int:
    from alight.diagrams.running.simulation import make_meshcat
    from alight.diagrams.analysis.flight import summarize_managed_flight
    from alight.diagrams.running.flights import fly_plan
    from alight.systems.params import ConfigError
    try:
        plan = _flight_plan(args)
        stack = _fly_stack(args)
    except (ValueError, ConfigError) as e:
        print(f"alight fly: {e}", file=sys.stderr)
        return 2
    config = _vehicle_config(args)
    meshcat = make_meshcat(args.meshcat, args.record)
    run = fly_plan(plan, config, seed=args.seed, run_dir=args.run_dir, meshcat=meshcat,
                   record=args.record, realtime_rate=1.0 if args.meshcat else 0.0,
                   controller=args.controller, tracker=args.tracker, **stack)
    print("\n".join(summarize_managed_flight(run)))
    _keep_meshcat_open(args)
    return 0


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


def _fly_stack(args) -> dict:
    """The managed stack's options of `alight fly`: names checked against the YAML lists, the
    estimator (mocap or the bank), the scheduled controller switches."""
    from alight.diagrams.onboard.control_manager import load_control_manager_config, parse_switch
    from alight.diagrams.onboard.estimation import scenario_odometry
    from alight.systems.params import ConfigError
    config = load_control_manager_config()
    for option, name, names in (("--controller", args.controller, config.names),
                                ("--tracker", args.tracker, config.tracker_names)):
        if name is not None and name not in names:
            raise ConfigError(f"{option} {name!r} is not one of {names} "
                              f"(models/control_manager.yaml)")
    stack = {"schedule": [parse_switch(text, config.names)
                          for text in args.switch_controller_at]}
    odometry = scenario_odometry(args.estimator, args.bank, "alight fly --estimator",
                                 anchored=False)
    if odometry is not None:
        stack.update(odometry=odometry, log=odometry.log)
    return stack


def _sysid(args) -> int:
    from pathlib import Path
    from alight.diagrams.running.paths import default_run_dir
    from alight.diagrams.analysis.sysid import identify_from_ulog
    from alight.diagrams.running.sysid import run_sysid
    from alight.systems.control.identification import IdentificationError
    run_dir = Path(args.run_dir) if args.run_dir else default_run_dir("sysid", args.seed)
    try:
        if args.ulog:
            report = identify_from_ulog(Path(args.ulog), plot=run_dir / "ulog_validation.png")
        else:
            report = run_sysid(_vehicle_config(args), seed=args.seed, run_dir=run_dir,
                               output=args.output)
    except IdentificationError as e:
        print(f"alight sysid: cannot identify: {e}", file=sys.stderr)
        return 2
    print("\n".join(report.lines()))
    print(f"plot and flights in {run_dir}" + (f"; model written to {args.output}"
                                             if args.output and not args.ulog else ""))
    return 0


def _frame_address(value: str | None, url: str) -> str | None:
    """--frames: 'none', a socket path, or by default one derived from the MAVLink port."""
    from alight.hw.frame_channel import default_frame_address
    if value == "none" or (value is None and url.startswith("serial:")):
        return None
    return value or default_frame_address(url.rsplit(":", 1)[-1])


def _sim_autopilot(args) -> int:
    import logging
    from alight.diagrams.running.simulation import make_meshcat
    from alight.hw.connection import MavlinkConnectionError
    from alight.hw.sim_autopilot import load_sim_autopilot_params, run_sim_autopilot
    logging.basicConfig(level=logging.INFO, format="%(name)s: %(message)s")
    config = None
    if args.scenario:  # the landing scenario's world: target, down camera, wind
        from alight.diagrams.scenario import vehicle_config
        from alight.systems.params import ConfigError
        try:
            config = vehicle_config(_land_scenario(args))
        except (ConfigError, FileNotFoundError) as e:
            print(f"alight sim-autopilot: {e}", file=sys.stderr)
            return 2
    config = _vehicle_config(args, config)
    params = load_sim_autopilot_params(args.autopilot)
    frames = _frame_address(args.frames, args.listen)
    meshcat = make_meshcat(args.meshcat, args.record)
    try:
        report, run_dir, stats = run_sim_autopilot(
            args.listen, config, params, duration=args.duration, seed=args.seed,
            run_dir=args.run_dir, frame_address=frames, stats_file=args.stats, meshcat=meshcat,
            record=args.record, realtime_rate=args.realtime_rate, ready=lambda: print(
                f"sim-autopilot: ready on {args.listen}" + (f", camera frames on {frames}"
                                                            if frames else ""), flush=True))
    except (MavlinkConnectionError, ValueError) as e:
        print(f"alight sim-autopilot: {e}", file=sys.stderr)
        return 2
    print("\n".join(report.lines() + [f"run folder        {run_dir}"]))
    return 0


def _hil(args) -> int:
    import logging
    from alight.diagrams.world.sim_vehicle import load_sim_vehicle_config
    from alight.hw.connection import MavlinkConnectionError
    from alight.hw.hil import MissionOptions, MissionUnavailable, run_hil
    from alight.hw.link import LinkTimeout
    from alight.hw.mavlink_vehicle import load_mavlink_vehicle_params
    from alight.hw.opencv_camera import CameraError
    logging.basicConfig(level=logging.INFO, format="%(name)s: %(message)s")
    params = load_mavlink_vehicle_params(args.link_config)
    try:
        options = MissionOptions(vehicle_config=load_sim_vehicle_config(args.config),
                                 profile=args.profile, **_hil_mission_options(args))
    except (ValueError, FileNotFoundError) as e:  # ConfigError is a ValueError
        print(f"alight hil: {e}", file=sys.stderr)
        return 2
    try:
        result = run_hil(args.connect, args.mission, options, params, duration=args.duration,
                         seed=args.seed, run_dir=args.run_dir,
                         frame_address=_frame_address(args.frames, args.connect),
                         wait=args.wait, realtime_rate=args.realtime_rate,
                         follow_autopilot_clock=args.follow_autopilot_clock,
                         down_camera=args.down_camera)
    except (MavlinkConnectionError, LinkTimeout, MissionUnavailable, ValueError,
            CameraError) as e:
        print(f"alight hil: {e}", file=sys.stderr)
        return 2
    print("\n".join(result.lines()))
    if args.mission == "land":
        from alight.diagrams.analysis.landing import mission_transitions
        from alight.diagrams.running.run_log import RunLog
        for at, mode, reason in mission_transitions(RunLog(result.run_dir)):
            print(f"  {at:6.2f} s  {mode.name:11s} ({reason.name.lower().replace('_', ' ')})")
    return 1 if result.report.error else 0


def _hil_mission_options(args) -> dict:
    """The waypoints of --mission fly, the landing scenario of --mission land."""
    if args.mission == "fly":
        from alight.diagrams.onboard.waypoints import parse_waypoints
        return {"waypoints": parse_waypoints(args.waypoints)}
    if args.mission == "land":
        return {"scenario": _land_scenario(args)}
    return {}


def _track(args) -> int:
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
    config = _vehicle_config(args)
    meshcat = make_meshcat(args.meshcat, args.record)
    run = fly_track(config, experiment, seed=args.seed, run_dir=args.run_dir, meshcat=meshcat,
                    record=args.record, realtime_rate=1.0 if args.meshcat else 0.0)
    print("\n".join(score(run).lines()))
    print(f"run folder            {run.path} (plots: track.png)")
    _keep_meshcat_open(args)
    return 0


def _thrust_curve(args) -> int:
    from pathlib import Path
    from alight.diagrams.running.paths import default_run_dir
    from alight.diagrams.running.thrust_curve import run_thrust_curve
    from alight.systems.plant.hexacopter import load_hexacopter_params
    from alight.systems.thrust_curve import ThrustCurve
    masses = [float(m) for m in args.masses.split(",")]
    if len(masses) < 2 or min(masses) <= 0:
        print("alight thrust-curve: give at least two positive masses, e.g. 2.0,2.5,3.0",
              file=sys.stderr)
        return 2
    config = _vehicle_config(args)
    run_dir = Path(args.run_dir) if args.run_dir else default_run_dir("thrust-curve", args.seed)
    fit = run_thrust_curve(config, masses, args.seed, run_dir)
    rotors = load_hexacopter_params(config.vehicle)
    print("\n".join(fit.lines(ThrustCurve.from_rotors(len(rotors.rotors), rotors.max_thrust,
                                                      rotors.idle))))
    print(f"run folders           {run_dir}")
    return 0


def _land_scenario(args):
    from alight.diagrams.running.campaign import CampaignJob, scenario_for
    return scenario_for(CampaignJob(args.scenario, args.target_speed, args.seed, "",
                                    getattr(args, "wind", None), getattr(args, "gusts", None),
                                    getattr(args, "camera", None),
                                    estimator=getattr(args, "estimator", None)))


def _check_landing_stack(args) -> None:
    """--stack / --controller: raises ConfigError naming the allowed controllers."""
    from alight.diagrams.onboard.landing_managed import landing_manager_config
    from alight.systems.params import ConfigError
    if args.stack == "managed":
        landing_manager_config(args.controller)
    elif args.controller != "linear_mpc":
        raise ConfigError(f"--controller {args.controller}: the direct stack flies linear_mpc "
                          f"only (use --stack managed)")


def _land(args) -> int:
    from alight.diagrams.running.paths import default_run_dir
    from alight.diagrams.analysis.landing import mission_transitions
    from alight.diagrams.running.landing import run_landing
    from alight.diagrams.analysis.landing_plots import plot_mission, plot_paths
    from alight.diagrams.analysis.landing import score_landing
    from alight.diagrams.running.simulation import make_meshcat
    from alight.systems.params import ConfigError
    from alight.diagrams.analysis.landing import tracker_switches
    try:
        scenario = _land_scenario(args)
        _check_landing_stack(args)
    except (ConfigError, FileNotFoundError) as e:
        print(f"alight land: {e}", file=sys.stderr)
        return 2
    meshcat = make_meshcat(args.meshcat, args.record)
    run_dir = args.run_dir or default_run_dir("land", args.seed)
    import time
    start = time.perf_counter()
    run = run_landing(scenario, seed=args.seed, run_dir=run_dir, meshcat=meshcat,
                      record=args.record, realtime_rate=1.0 if args.meshcat else 0.0,
                      stack=args.stack, controller=args.controller)
    wall = time.perf_counter() - start
    score = score_landing(run, scenario.impact.vertical_speed, scenario.impact.horizontal_speed)
    for at, mode, reason in mission_transitions(run):
        print(f"  {at:6.2f} s  {mode.name:11s} ({reason.name.lower().replace('_', ' ')})")
    if args.stack == "managed":
        print(f"  control manager ({args.controller}): tracker " + ", ".join(
            f"{name} at {at:.2f} s" for at, name in tracker_switches(run)))
    print(f"{scenario.name} scenario, {scenario.camera} camera, {args.stack} stack, seed "
          f"{args.seed}:")
    print("  " + score.row())
    print(f"  plots {plot_mission(run, run.path / 'mission.png')}, "
          f"{plot_paths(run, run.path / 'paths.png')}")
    print(f"  simulated {run.metadata['duration']:.1f} s in {wall:.1f} s of wall time (real-time "
          f"factor {run.metadata['duration'] / wall:.2f}, including set-up)")
    print(f"  run folder {run.path}" + (f"; replay {args.record}" if args.record else ""))
    _keep_meshcat_open(args)
    return 0 if score.success else 1


def _campaign(args) -> int:
    from pathlib import Path
    from alight.diagrams.running.campaign import (campaign_jobs, run_campaign, scenario_for,
                                                  write_summary)
    from alight.systems.params import ConfigError
    try:
        speeds = [float(v) for v in args.target_speeds.split(",") if v.strip()]
    except ValueError:
        print(f"alight campaign: --target-speeds must be numbers like 1.3,2,3, got "
              f"{args.target_speeds!r}", file=sys.stderr)
        return 2
    if not speeds or args.runs < 1 or any(not 0 <= v <= 20 for v in speeds):
        print("alight campaign: give at least one target speed in [0, 20] m/s and --runs >= 1",
              file=sys.stderr)
        return 2
    out = Path(args.out)
    jobs = campaign_jobs(out, args.scenario, speeds, args.runs, args.seed, wind_kmh=args.wind,
                         gusts=args.gusts, camera=args.camera, stack=args.stack,
                         controller=args.controller, estimator=args.estimator)
    try:
        _check_landing_stack(args)
        scenario_for(jobs[0])          # a bad scenario or override stops here, not in a worker
    except (ConfigError, FileNotFoundError) as e:
        print(f"alight campaign: {e}", file=sys.stderr)
        return 2
    rows = run_campaign(out, jobs, workers=args.workers, scheduler=args.scheduler)
    summary = write_summary(out, rows)
    print(summary.to_string(float_format=lambda v: f"{v:.2f}"))
    print(f"all runs: {out / 'runs.csv'}; summary: {out / 'summary.md'}, {out / 'summary.png'}")
    return 0


def _add_landing_options(parser: argparse.ArgumentParser) -> None:
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


def make_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="alight", description="GPS-free multirotor autonomy as Drake diagrams.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="commands:\n" + "\n".join(f"  {name:15s}{text}" for name, text in COMMANDS.items()))
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    hover = sub.add_parser("hover", help=COMMANDS["hover"], description=COMMANDS["hover"])
    _add_common(hover)
    hover.add_argument("--profile", default="hover_profile.yaml",
                       help="pilot profile YAML (a path, or a file name in models/)")
    hover.set_defaults(run=_hover)
    fly = sub.add_parser("fly", help=COMMANDS["fly"], description=COMMANDS["fly"])
    _add_common(fly)
    fly.add_argument("--waypoints", metavar="'X,Y,Z; X,Y,Z; ...'",
                     help="waypoints in W [m], e.g. '0,0,5; 10,0,5; 10,10,3': a trajectory "
                          "through them is generated under the constraint group (M Sec. 6)")
    fly.add_argument("--trajectory", metavar="FILE.csv",
                     help="CSV with a header: x,y,z[,heading] waypoints (a trajectory is "
                          "generated), or t,x,y,z[,heading] samples (flown as they are)")
    fly.add_argument("--controller", metavar="NAME",
                     help="the flying controller (models/control_manager.yaml: se3, mpc, "
                          "linear_mpc, ...; default models/uav_manager.yaml)")
    fly.add_argument("--tracker", metavar="NAME",
                     help="the flying tracker (default mpc_tracker)")
    fly.add_argument("--switch-controller-at", action="append", default=[],
                     metavar="T:NAME", help="switch to controller NAME at T s (repeatable)")
    fly.add_argument("--constraints", metavar="GROUP",
                     help="constraint group of the generated trajectory (slow, medium, fast)")
    fly.add_argument("--takeoff-height", type=float, default=2.0, metavar="M",
                     help="take-off height above the start [m] (default 2)")
    fly.add_argument("--estimator", default="mocap", metavar="NAME",
                     help="state estimate: 'mocap' (default), 'bank' (the arbiter chooses) or a "
                          "filter of the bank (requested; the arbiter falls back if unreliable)")
    fly.add_argument("--bank", default="estimator_bank.yaml", metavar="FILE.yaml",
                     help="the estimator bank: sources, filters, arbiter (a path, or a file "
                          "name in models/)")
    fly.set_defaults(run=_fly)
    sysid = sub.add_parser("sysid", help=COMMANDS["sysid"], description=COMMANDS["sysid"])
    _add_common(sysid)
    sysid.add_argument("--ulog", metavar="FILE.ulg",
                       help="identify the attitude model L(12) from a PX4 log instead")
    sysid.add_argument("--output", metavar="FILE.yaml",
                       help="write the identified model (the MPC reads models/linear_model.yaml)")
    sysid.set_defaults(run=_sysid)
    autopilot = sub.add_parser("sim-autopilot", help=COMMANDS["sim-autopilot"],
                               description=COMMANDS["sim-autopilot"])
    _add_common(autopilot)
    autopilot.add_argument("--listen", default="udp:127.0.0.1:14540",
                           help="MAVLink endpoint (udp:HOST:PORT binds it; see docs/hardware.md)")
    autopilot.add_argument("--autopilot", default="sim_autopilot.yaml",
                           help="MAVLink endpoint YAML (a path, or a file name in models/)")
    autopilot.add_argument("--duration", type=float, metavar="S",
                           help="stop after S seconds (default: run until Ctrl-C)")
    autopilot.add_argument("--frames", metavar="SOCKET",
                           help="camera frame channel socket, or 'none' (default: from the port)")
    autopilot.add_argument("--stats", metavar="FILE.json",
                           help="write the link statistics (setpoint rate, latency) at exit")
    autopilot.add_argument("--realtime-rate", type=float, default=1.0, metavar="R",
                           help="slow the simulation to R x real time, R in (0, 1] (a loaded "
                                "machine; run `alight hil` with the same R)")
    autopilot.add_argument("--scenario", metavar="NAME",
                           help="simulate a landing scenario's world (field, mbzirc, or a YAML): "
                                "its vehicle, moving target, down camera and wind (for `alight "
                                "hil --mission land`); --wind/--gusts override its wind")
    autopilot.add_argument("--target-speed", type=float, metavar="V",
                           help="with --scenario: the target's speed in m/s")
    autopilot.set_defaults(run=_sim_autopilot)
    track = sub.add_parser("track", help=COMMANDS["track"], description=COMMANDS["track"])
    _add_common(track)
    track.add_argument("--trajectory", choices=["circle", "steps", "hover"], default="circle")
    track.add_argument("--controller", choices=["se3", "mpc", "linear_mpc"], default="se3",
                       help="linear_mpc: the landing paper's MPC (attitude+thrust), for comparison")
    track.add_argument("--radius", type=float, default=5.0, help="circle radius [m]")
    track.add_argument("--speed", type=float, default=7.0, help="circle speed [m/s]")
    track.add_argument("--heading", choices=["center", "constant"], default="center")
    track.add_argument("--laps", type=float, default=3.0,
                       help="circle laps (the last is scored; the disturbance estimators learn "
                            "the drag on the laps before)")
    track.add_argument("--estimator-noise", type=float, default=0.0, metavar="SIGMA",
                       help="white noise on the estimated position [m] and velocity [m/s]")
    track.add_argument("--estimator-jump", type=float, default=0.0, metavar="METRES",
                       help="jump of the estimated position along x, 2 s into the experiment")
    track.set_defaults(run=_track)
    thrust = sub.add_parser("thrust-curve", help=COMMANDS["thrust-curve"],
                            description=COMMANDS["thrust-curve"])
    _add_common(thrust)
    thrust.add_argument("--masses", default="2.0,2.5,3.0,3.5", metavar="KG,KG,...",
                        help="simulated vehicle masses to hover with")
    thrust.set_defaults(run=_thrust_curve)
    hil = sub.add_parser("hil", help=COMMANDS["hil"], description=COMMANDS["hil"])
    hil.add_argument("--connect", required=True,
                     help="udp:HOST:PORT, udpin:HOST:PORT, serial:/dev/ttyACM0:921600, ...")
    hil.add_argument("--mission", default="hover", choices=["hover", "fly", "land"],
                     help="hover: scripted attitude/thrust profile; fly: --waypoints with the "
                          "linear MPC; land: the landing mission of --scenario (fly and land "
                          "read the simulated autopilot's mocap from the frame channel)")
    hil.add_argument("--waypoints", default="0,0,2; 3,0,2", metavar="'X,Y,Z; ...'",
                     help="waypoints of --mission fly in W [m]")
    hil.add_argument("--scenario", default="field",
                     help="landing scenario of --mission land (the same as the simulated "
                          "autopilot's --scenario): its mission, MPC tuning, time limits")
    hil.add_argument("--target-speed", type=float, metavar="V",
                     help="with --mission land: the scenario's target speed in m/s")
    hil.add_argument("--profile", default="hover_profile.yaml",
                     help="pilot profile of --mission hover (a path, or a file name in models/)")
    hil.add_argument("--config", default="sim_vehicle.yaml",
                     help="the vehicle model the onboard side assumes (its airframe file)")
    hil.add_argument("--link-config", default="mavlink_vehicle.yaml",
                     help="MAVLink vehicle YAML (a path, or a file name in models/)")
    hil.add_argument("--duration", type=float, metavar="S",
                     help="stop after S seconds (default: the mission's duration)")
    hil.add_argument("--frames", metavar="SOCKET",
                     help="camera frame channel socket, or 'none' (default: from the port)")
    hil.add_argument("--wait", type=float, default=10.0, metavar="S",
                     help="how long to wait for the flight controller (default 10 s)")
    hil.add_argument("--realtime-rate", type=float, default=1.0, metavar="R",
                     help="only against `alight sim-autopilot --realtime-rate R`: run slowed")
    hil.add_argument("--follow-autopilot-clock", action="store_true",
                     help="simulated autopilot only: also pace on its clock, so that a "
                          "simulation falling behind real time slows the onboard side with it")
    hil.add_argument("--down-camera", metavar="DEVICE",
                     help="a real down camera through OpenCV (0, /dev/video0, a pipeline, a "
                          "video file), calibrated by models/down_camera.yaml")
    hil.add_argument("--seed", type=int, default=0, help="seed of every random source")
    hil.add_argument("--run-dir", help="run folder to write (default runs/<time>-hil-<mission>)")
    hil.set_defaults(run=_hil)
    land = sub.add_parser("land", help=COMMANDS["land"], description=COMMANDS["land"])
    _add_landing_options(land)
    land.add_argument("--target-speed", type=float, metavar="V", help="target speed in m/s")
    land.add_argument("--meshcat", action="store_true",
                      help="show the flight live in Meshcat (prints the URL); runs in real time")
    land.add_argument("--record", metavar="FILE.html", help="write a self-contained replay")
    land.add_argument("--run-dir", help="run folder to write (default runs/<time>-land-s<seed>)")
    land.set_defaults(run=_land)
    campaign = sub.add_parser("campaign", help=COMMANDS["campaign"],
                              description=COMMANDS["campaign"])
    _add_landing_options(campaign)
    campaign.add_argument("--target-speeds", default="1.3,2,3,4,5,5.7", metavar="V,V,...")
    campaign.add_argument("--runs", type=int, default=20, help="runs per speed (seeds seed..)")
    campaign.add_argument("--workers", type=int, default=1, help="local worker processes")
    campaign.add_argument("--scheduler", metavar="ADDRESS",
                          help="run on this Dask distributed scheduler instead (tcp://host:8786)")
    campaign.add_argument("--out", default="runs/campaign",
                          help="campaign folder (runs.csv, summary, run folders); rerun resumes")
    campaign.set_defaults(run=_campaign)
    vio = sub.add_parser("vio-eval", help=COMMANDS["vio-eval"], description=COMMANDS["vio-eval"])
    _add_common(vio)
    vio.add_argument("--waypoints", default="0,0,2; 6,0,2; 6,6,3; 0,0,2",
                     metavar="'X,Y,Z; ...'", help="waypoints in E [m]")
    vio.add_argument("--camera", default="rgbd_camera.yaml",
                     help="forward RGB-D camera YAML (source geometric or rendered)")
    vio.add_argument("--open-loop", action="store_true", help="mocap flies, the VIO runs beside")
    vio.set_defaults(run=_vio_eval)
    return parser


def _vio_eval(args) -> int:
    from alight.diagrams.onboard.waypoints import parse_waypoints
    from alight.diagrams.running.paths import default_run_dir
    from alight.diagrams.analysis.vio import evaluate_vio
    from alight.diagrams.onboard.vio import load_rgbd_camera_params
    from alight.diagrams.running.flights import fly_vio
    try:
        waypoints = parse_waypoints(args.waypoints)
    except ValueError as e:
        print(f"alight vio-eval: {e}", file=sys.stderr)
        return 2
    run = fly_vio(_vehicle_config(args), waypoints, args.seed,
                  args.run_dir or default_run_dir("vio-eval", args.seed),
                  closed_loop=not args.open_loop, camera=load_rgbd_camera_params(args.camera))
    for key, value in evaluate_vio(run).items():
        print(f"{key:16s}{value:.4g}" if isinstance(value, float) else f"{key:16s}{value}")
    return 0


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
