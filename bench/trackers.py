"""Per-tick cost of the MPC tracker (M Sec. 4.1), for each constraint group.

Runs the tracker alone on a 3-D step with a heading change (8, -6, +3 m, 2 rad) and on a 3 m
circle at 1.5 m/s sampled at 20 Hz, and prints the QP time of each tick as the tracker measures
it (its `compute_timer`, wall clock: mean, p99, max) and the share of ticks whose QP
failed (the axis then plays on its previous plan). Each tick solves at most one axis QP; the first
tick solves all four cold.

Trajectory generation (M Sec. 6): for seeded random 3-D courses of 10 and 50 waypoints (legs of
10-30 m, turns up to 115 degrees, height changes up to 3 m per leg), the generation time (mean and
max wall clock over the seeds, sub-sectioning to the YAML's max_deviation included) and the flight
time with per-segment stretching (M Sec. 6) and with uniform rescaling (the baseline of [55]).

The landoff (M Sec. 4.2: a 2 m take-off, then a landing), speed (M Sec. 4.3: a 2 m/s velocity
step) and target (L Sec. 6.3: a target driving at 3 m/s, followed then descended on) trackers:
the whole tick as the simulator runs it (wall clock of one 10 ms `AdvanceTo` of the tracker
alone, Drake's overhead included), next to the MPC tracker's on the medium step for scale.

    python bench/trackers.py [--seconds 14] [--part all|tracker|others|trajectory] [--seeds 5]
                             [--velocity-weight W] [--solver daqp|osqp|both]
"""
import time

import argparse

import numpy as np
from pydrake.systems.analysis import Simulator

from alight.systems.boundary import REFERENCE, STATE_ESTIMATE, TRACKER_STATUS
from alight.systems.tracking.goal import TrackerGoal
from alight.systems.tracking.mpc_tracker import (TrackerReason, load_mpc_tracker_params,
                                                 make_mpc_tracker)
from alight.systems.tracking.trajectory_generation import (load_trajectory_generation_params,
                                                           make_trajectory_generator)

HOVER = STATE_ESTIMATE.vector(p_EB=[0.0, 0.0, 2.0])


def whole_ticks(dut, goals: list[tuple[float, object]], seconds: float,
                extra=None) -> np.ndarray:
    """Wall-clock seconds of each 10 ms tick of tracker `dut` alone, hovering at 2 m, with the
    goal switched at the given times; `extra(context, t)` sets more inputs each tick."""
    context = dut.CreateDefaultContext()
    dut.GetInputPort("state_estimate").FixValue(context, HOVER)
    dut.GetInputPort("active").FixValue(context, [1.0])
    dut.GetInputPort("last_reference").FixValue(context, np.full(REFERENCE.size, np.nan))
    simulator = Simulator(dut, context)
    simulator.Initialize()
    times, pending = [], sorted(goals, key=lambda item: item[0])
    for i in range(int(round(seconds / 0.01))):
        t = i * 0.01
        while pending and pending[0][0] <= t:
            dut.GetInputPort("goal").FixValue(context, pending.pop(0)[1])
        if extra is not None:
            extra(context, t)
        start = time.perf_counter()
        simulator.AdvanceTo(t + 0.01)
        times.append(time.perf_counter() - start)
    return np.array(times)


def other_trackers(seconds: float) -> None:
    from alight.diagrams.onboard.controllers import load_controllers_config
    from alight.systems.boundary import TARGET_ESTIMATE
    from alight.systems.control.controller import level_command
    from alight.systems.tracking.landoff_tracker import (LandoffGoal,
                                                         load_landoff_tracker_params,
                                                         make_landoff_tracker)
    from alight.systems.tracking.speed_tracker import (SpeedGoal, load_speed_tracker_params,
                                                       make_speed_tracker)
    from alight.systems.tracking.target_tracker import (TargetGoal, load_target_tracker_params,
                                                        make_target_tracker)
    landoff = make_landoff_tracker(load_controllers_config().vehicle,
                                   load_landoff_tracker_params())

    def hover_command(context, t):
        landoff.GetInputPort("last_command").FixValue(
            context, level_command(t, 0.0, 0.6, 1.0))
    target = make_target_tracker(load_target_tracker_params())

    def driving_target(context, t):
        target.GetInputPort("target_estimate").FixValue(context, TARGET_ESTIMATE.pack(
            stamp=t, p_WT=[3.0 * t, 0.0, 0.8], q_WT=[1, 0, 0, 0], v_WT=[3.0, 0.0, 0.0],
            var_p=0.01, var_rot=0.01, var_v=0.01, last_measurement=t, valid=1.0, keypoints=8,
            frame_counter=0.0))
    runs = {
        "mpc (medium step)": (None, None, None),
        "landoff": (landoff, [(0.0, LandoffGoal.takeoff(2.0)), (seconds / 2, LandoffGoal.land())],
                    hover_command),
        "speed": (make_speed_tracker(load_speed_tracker_params()),
                  [(0.0, SpeedGoal(height=2.0, velocity=(2.0, 0.0)))], None),
        "target": (target, [(0.0, TargetGoal.follow()),
                            (seconds / 2, TargetGoal(descent_rate=0.5))], driving_target),
    }
    print(f"{'tracker':20s}{'mean us':>9s}{'p99 us':>9s}{'max us':>9s}   (whole tick)")
    for name, (dut, goals, extra) in runs.items():
        if dut is None:
            dut = make_mpc_tracker(load_mpc_tracker_params())
            goals = [(0.0, TrackerGoal.point([8.0, -6.0, 5.0], 2.0))]
        us = 1e6 * whole_ticks(dut, goals, seconds, extra)
        print(f"{name:20s}{us.mean():9.0f}{np.percentile(us, 99):9.0f}{us.max():9.0f}")


def tick_times(goal, group: str, seconds: float, p_start,
               solver: str) -> tuple[np.ndarray, np.ndarray]:
    params = load_mpc_tracker_params()
    params.axis.solver = solver
    dut = make_mpc_tracker(params)
    context = dut.CreateDefaultContext()
    dut.GetInputPort("state_estimate").FixValue(context, STATE_ESTIMATE.vector(p_EB=p_start))
    dut.GetInputPort("active").FixValue(context, [1.0])
    dut.GetInputPort("last_reference").FixValue(context, np.full(REFERENCE.size, np.nan))
    dut.GetInputPort("constraint_group").FixValue(context, [dut.group_names.index(group)])
    dut.GetInputPort("goal").FixValue(context, goal)
    simulator = Simulator(dut, context)
    reasons = []
    for i in range(int(round(seconds / 0.01))):
        simulator.AdvanceTo((i + 1) * 0.01)
        status = dut.GetOutputPort("tracker_status").Eval(context)
        reasons.append(TRACKER_STATUS.get(status, "reason"))
    return dut.compute_timer.seconds(), np.array(reasons)


def course(count: int, seed: int) -> np.ndarray:
    """A random 3-D course of `count` waypoints [x, y, z, heading along the leg]."""
    rng = np.random.default_rng(seed)
    p, yaw = np.array([0.0, 0.0, 3.0]), 0.0
    rows = [np.append(p, yaw)]
    for _ in range(count - 1):
        yaw += rng.uniform(-2.0, 2.0)
        p = p + rng.uniform(10.0, 30.0) * np.array([np.cos(yaw), np.sin(yaw), 0.0])
        p[2] = np.clip(p[2] + rng.uniform(-3.0, 3.0), 2.0, 10.0)
        rows.append(np.append(p, yaw))
    return np.array(rows)


def trajectory_generation(seeds: int, velocity_weight: float | None) -> None:
    params = load_trajectory_generation_params()
    if velocity_weight is not None:
        params.velocity_weight = velocity_weight
    generator = make_trajectory_generator(params)
    print(f"{'waypoints':>10s}{'rescaling':>13s}{'mean ms':>9s}{'max ms':>9s}{'flight s':>10s}"
          f"{'segments':>10s}{'solves':>8s}{'fallback':>10s}")
    for count in (10, 50):
        flights = {}
        for rescaling in ("per_segment", "uniform"):
            generator.compute_timer.clear()
            results = [generator.generate(course(count, seed), rescaling=rescaling)
                       for seed in range(seeds)]
            ms = 1e3 * generator.compute_timer.seconds()
            flights[rescaling] = np.array([r.total_time for r in results])
            print(f"{count:10d}{rescaling:>13s}{ms.mean():9.1f}{ms.max():9.1f}"
                  f"{flights[rescaling].mean():10.1f}"
                  f"{np.mean([len(r.segment_times) for r in results]):10.1f}"
                  f"{np.mean([r.iterations for r in results]):8.1f}"
                  f"{sum(r.uniform_fallback for r in results):10d}")
        ratio = flights["per_segment"] / flights["uniform"]
        print(f"{count:10d} waypoints: per-segment flight time = {ratio.mean():.3f} x uniform "
              f"(range {ratio.min():.3f}-{ratio.max():.3f})")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=14.0)
    parser.add_argument("--part", choices=("all", "tracker", "others", "trajectory"),
                        default="all")
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--solver", choices=("daqp", "osqp", "both"), default="both",
                        help="the MPC tracker's axis QP back end (both: side by side)")
    parser.add_argument("--velocity-weight", type=float, default=None,
                        help="override the YAML's (0: pure minimum snap)")
    args = parser.parse_args()
    if args.part in ("all", "trajectory"):
        trajectory_generation(args.seeds, args.velocity_weight)
    if args.part in ("all", "others"):
        other_trackers(args.seconds)
    if args.part in ("trajectory", "others"):
        return
    t = np.arange(0.0, args.seconds + 3.0, 0.05)
    circle = np.column_stack([3 * np.cos(0.5 * t), 3 * np.sin(0.5 * t), np.full_like(t, 2.0),
                              0.5 * t + np.pi / 2])
    goals = {"step": (TrackerGoal.point([8.0, -6.0, 5.0], 2.0), (0.0, 0.0, 2.0)),
             "circle": (TrackerGoal(circle, 0.0, 0.05), (3.0, 0.0, 2.0))}
    print(f"{'goal':8s}{'group':8s}{'solver':8s}{'mean us':>9s}{'p99 us':>9s}{'max us':>9s}"
          f"{'max after 1st us':>18s}{'failed %':>10s}")
    solvers = ("daqp", "osqp") if args.solver == "both" else (args.solver,)
    for name, (goal, p_start) in goals.items():
        for group in ("slow", "medium", "fast"):
            for solver in solvers:
                times, reasons = tick_times(goal, group, args.seconds, p_start, solver)
                us = 1e6 * times
                failed = 100.0 * np.mean(reasons == TrackerReason.SOLVER_FAILED)
                print(f"{name:8s}{group:8s}{solver:8s}{us.mean():9.0f}"
                      f"{np.percentile(us, 99):9.0f}{us.max():9.0f}{us[1:].max():18.0f}"
                      f"{failed:10.2f}")


if __name__ == "__main__":
    main()
