"""Per-tick cost of the landing paper's MPC (L Sec. 6.2: 709.53 us mean, 69.85 us std, worst case
under 1 ms with CVXGEN on an i7-7567U).

Flies one closed-loop waypoint flight (mocap odometry, default controller), then replays that
flight's controller inputs tick by tick through fresh LinearMpc systems with different horizons and
QP back ends, timing each tick's update (QP data + solve + output command) as the controller
measures it (its `compute_timer`, wall clock; in flight: the run folder's `timing` stream) and as
CPU time of the thread (the figure to compare on a loaded machine). Both back ends solve the
same MathematicalProgram: `persistent` keeps one warm-started osqp workspace built from it,
`drake` calls Drake's OsqpSolver, which sets OSQP up cold on every solve.

    python bench/mpc_solve.py [--horizons 2 20 40] [--seed 0]
"""
import argparse
import os
import dataclasses as dc
import tempfile
import time
from pathlib import Path

import numpy as np

from alight.diagrams.onboard.mpc_loop import load_linear_model, load_linear_mpc
from alight.diagrams.running.flights import fly_waypoints
from alight.diagrams.world.sim_vehicle import load_sim_vehicle_config
from alight.systems.control.linear_mpc import LinearMpc

PAPER_MEAN_US = 709.53
WAYPOINTS = np.array([[0.0, 0.0, 3.0], [8.0, 0.0, 3.0], [8.0, 8.0, 5.0], [0.0, 0.0, 3.0]])


def tick_inputs(run) -> list[dict[str, np.ndarray]]:
    """The inputs the controller saw at each of its ticks (latest logged sample, zero-order)."""
    ticks = run["controller_status"]["time"].to_numpy()
    streams = {"state_estimate": run["state_estimate"], "reference": run["reference"],
               "fc_attitude": run["fc_attitude"], "last_command": run["fc_command"]}
    columns = {name: [c for c in frame.columns if c != "time"] for name, frame in streams.items()}
    out = []
    for t in ticks[ticks > 1.0]:
        inputs = {"time": t}
        for name, frame in streams.items():
            i = max(int(np.searchsorted(frame["time"].to_numpy(), t, side="right")) - 1, 0)
            inputs[name] = frame[columns[name]].iloc[i].to_numpy(float)
        out.append(inputs)
    return out


def replay(ticks, horizon: int, solver: str) -> tuple[np.ndarray, np.ndarray]:
    """Per tick of a fresh controller fed the recorded inputs: its own compute timer (wall clock)
    and this thread's CPU time over the same update [s] (robust to other processes' load)."""
    params = dc.replace(load_linear_mpc(), horizon_steps=horizon, solver=solver)
    mpc = LinearMpc(load_linear_model(), params)
    context = mpc.CreateDefaultContext()
    mpc.GetInputPort("active").FixValue(context, [1.0])
    cpu = []
    for inputs in ticks:
        for name in ("state_estimate", "reference", "fc_attitude", "last_command"):
            mpc.GetInputPort(name).FixValue(context, inputs[name])
        context.SetTime(inputs["time"])
        start = time.thread_time()
        context.SetDiscreteState(mpc.EvalUniquePeriodicDiscreteUpdate(context))
        cpu.append(time.thread_time() - start)
    return mpc.compute_timer.seconds(), np.array(cpu)


def row(label: str, seconds: np.ndarray) -> str:
    us = seconds * 1e6
    return (f"{label:34s} {us.mean():8.0f} {us.std():8.0f} {np.percentile(us, 99):8.0f} "
            f"{us.max():8.0f} {us.mean() / PAPER_MEAN_US:8.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--horizons", type=int, nargs="+", default=[2, 20, 40])
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        run = fly_waypoints(load_sim_vehicle_config(), WAYPOINTS, seed=args.seed,
                            run_dir=Path(tmp) / "flight")
        ticks = tick_inputs(run)
        flown = run.compute_seconds("linear_mpc")
    period = load_linear_mpc().period
    print(f"recorded flight: {len(ticks)} controller ticks at {1 / period:.0f} Hz, "
          f"landed {run.metadata['landed']}; load average {os.getloadavg()[0]:.1f} on "
          f"{os.cpu_count()} CPUs (timings spread with load)")
    print(f"{'':34s} {'mean':>8s} {'std':>8s} {'p99':>8s} {'max':>8s} {'/709.53':>8s}   [us]")
    print(row(f"in flight (N={load_linear_mpc().horizon_steps}, default)", flown))
    means = {}
    for horizon in args.horizons:
        for solver in ("persistent", "drake"):
            wall, cpu = replay(ticks, horizon, solver)
            means[horizon, solver] = cpu.mean()
            label = f"N={horizon:3d} ({horizon * period:.2f} s) {solver}"
            print(row(label + " wall", wall))
            print(row(label + " CPU", cpu))
    for horizon in args.horizons:
        print(f"N={horizon}: Drake OsqpSolver / persistent osqp workspace (CPU time) = "
              f"{means[horizon, 'drake'] / means[horizon, 'persistent']:.2f}")


if __name__ == "__main__":
    main()
