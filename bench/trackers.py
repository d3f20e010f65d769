"""Per-tick cost of the MPC tracker (M Sec. 4.1), for each constraint group.

Runs the tracker alone on a 3-D step with a heading change (8, -6, +3 m, 2 rad) and on a 3 m
circle at 1.5 m/s sampled at 20 Hz, and prints the QP time of each tick as the tracker measures
it (`tracker_status.compute_time`, wall clock: mean, p99, max) and the share of ticks whose QP
failed (the axis then plays on its previous plan). Each tick solves at most one axis QP; the first
tick solves all four cold.

Trajectory generation (M Sec. 6): for seeded random 3-D courses of 10 and 50 waypoints (legs of
10-30 m, turns up to 115 degrees, height changes up to 3 m per leg), the generation time (mean and
max wall clock over the seeds, sub-sectioning to the YAML's max_deviation included) and the flight
time with per-segment stretching (M Sec. 6) and with uniform rescaling (the baseline of [55]).

    python bench/trackers.py [--seconds 14] [--part all|tracker|trajectory] [--seeds 5]
                             [--velocity-weight W]
"""
import argparse

import numpy as np
from pydrake.systems.analysis import Simulator

from alight.systems.boundary import REFERENCE, STATE_ESTIMATE, TRACKER_STATUS
from alight.systems.tracking.goal import TrackerGoal
from alight.systems.tracking.mpc_tracker import TrackerReason, make_mpc_tracker
from alight.systems.tracking.trajectory_generation import (load_trajectory_generation_params,
                                                           make_trajectory_generator)


def tick_times(goal, group: str, seconds: float, p_start) -> tuple[np.ndarray, np.ndarray]:
    dut = make_mpc_tracker()
    context = dut.CreateDefaultContext()
    dut.GetInputPort("state_estimate").FixValue(context, STATE_ESTIMATE.pack(
        stamp=0.0, p_EB=p_start, v_EB=0.0, a_EB=0.0, q_EB=[1, 0, 0, 0], heading=0.0,
        heading_rate=0.0, var_pv=0.0, var_heading=0.0, frame_id=0, frame_counter=0,
        p_OldNew=0.0, q_OldNew=[1, 0, 0, 0], valid=1.0))
    dut.GetInputPort("active").FixValue(context, [1.0])
    dut.GetInputPort("last_reference").FixValue(context, np.full(REFERENCE.size, np.nan))
    dut.GetInputPort("constraint_group").FixValue(context, [dut.group_names.index(group)])
    dut.GetInputPort("goal").FixValue(context, goal)
    simulator = Simulator(dut, context)
    times, reasons = [], []
    for i in range(int(round(seconds / 0.01))):
        simulator.AdvanceTo((i + 1) * 0.01)
        status = dut.GetOutputPort("tracker_status").Eval(context)
        times.append(TRACKER_STATUS.get(status, "compute_time"))
        reasons.append(TRACKER_STATUS.get(status, "reason"))
    return np.array(times), np.array(reasons)


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
            results = [generator.generate(course(count, seed), rescaling=rescaling)
                       for seed in range(seeds)]
            ms = 1e3 * np.array([r.compute_time for r in results])
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
    parser.add_argument("--part", choices=("all", "tracker", "trajectory"), default="all")
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--velocity-weight", type=float, default=None,
                        help="override the YAML's (0: pure minimum snap)")
    args = parser.parse_args()
    if args.part in ("all", "trajectory"):
        trajectory_generation(args.seeds, args.velocity_weight)
    if args.part == "trajectory":
        return
    t = np.arange(0.0, args.seconds + 3.0, 0.05)
    circle = np.column_stack([3 * np.cos(0.5 * t), 3 * np.sin(0.5 * t), np.full_like(t, 2.0),
                              0.5 * t + np.pi / 2])
    goals = {"step": (TrackerGoal.point([8.0, -6.0, 5.0], 2.0), (0.0, 0.0, 2.0)),
             "circle": (TrackerGoal(circle, 0.0, 0.05), (3.0, 0.0, 2.0))}
    print(f"{'goal':8s}{'group':8s}{'mean us':>9s}{'p99 us':>9s}{'max us':>9s}"
          f"{'max after 1st us':>18s}{'failed %':>10s}")
    for name, (goal, p_start) in goals.items():
        for group in ("slow", "medium", "fast"):
            times, reasons = tick_times(goal, group, args.seconds, p_start)
            us = 1e6 * times
            failed = 100.0 * np.mean(reasons == TrackerReason.SOLVER_FAILED)
            print(f"{name:8s}{group:8s}{us.mean():9.0f}{np.percentile(us, 99):9.0f}"
                  f"{us.max():9.0f}{us[1:].max():18.0f}{failed:10.2f}")


if __name__ == "__main__":
    main()
