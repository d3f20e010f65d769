"""Per-tick cost of the landing paper's MPC (L Sec. 6.2: 709.53 us mean, 69.85 us std, worst case
under 1 ms with CVXGEN on an i7-7567U).

Flies one closed-loop waypoint flight (mocap odometry, default controller), then replays that
whole flight's controller inputs tick by tick through fresh LinearMpc systems with different
horizons and QP back ends, timing each tick's update (QP data + solve + output command) as the
controller measures it (its `compute_timer`, wall clock; in flight: the run folder's `timing`
stream) and as CPU time of the thread (the figure to compare on a loaded machine). Every back end
solves the same MathematicalProgram: `persistent` keeps one warm-started osqp workspace built from
it (the default), `daqp` one warm-started DAQP dual active-set workspace, `drake` calls Drake's
OsqpSolver, which sets OSQP up cold on every solve. With --check, a second, untimed replay also
solves every tick's QP with Drake's ClarabelSolver (interior point, tolerance 1e-8) and compares
the back end's first input (the command: pitch, roll, thrust acceleration) and whole plan with it
(a separate pass: Clarabel between the ticks would slow the timed ones through the caches).
At N = 20 it prints each back end's iterations per tick (mean, p99, max), how many ticks took
over 1 ms of CPU time and the five slowest ticks' CPU time and iterations (the tail's cause).

Ends with one line: `mpc: N=2 mean X us (R x 709.53 us); in flight N=20 worst Y us` (CPU time of
the --summary back end, default: models/linear_mpc.yaml's; "in flight": the whole recorded flight
replayed at N=20).

    python bench/mpc_solve.py [--horizons 2 20 40] [--solvers persistent daqp drake] [--check]
                              [--summary daqp] [--seed 0]
"""
import argparse
import dataclasses as dc
import os
import tempfile
import time
from pathlib import Path

import numpy as np
from pydrake.solvers import ClarabelSolver

from alight.diagrams.onboard.mpc_loop import load_linear_model, load_linear_mpc
from alight.diagrams.running.flights import fly_waypoints
from alight.diagrams.world.sim_vehicle import load_sim_vehicle_config
from alight.systems.boundary import CONTROLLER_STATUS
from alight.systems.control.linear_mpc import LinearMpc, MpcReason

PAPER_MEAN_US = 709.53
WAYPOINTS = np.array([[0.0, 0.0, 3.0], [8.0, 0.0, 3.0], [8.0, 8.0, 5.0], [0.0, 0.0, 3.0]])
INPUTS = ("state_estimate", "reference", "fc_attitude", "last_command")


@dc.dataclass
class Replay:
    wall: np.ndarray         # s per tick, the controller's compute timer
    cpu: np.ndarray          # s per tick, this thread's CPU time
    failed: int              # ticks whose QP failed (fallback or hover command)
    command_error: float     # max |u_0 - u_0 exact| over the ticks [rad, m/s^2] (NaN: unchecked)
    plan_error: float        # the same over the whole planned inputs
    iterations: np.ndarray   # the QP back end's iterations per tick (-1: no solve that tick)


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


def exact_plan(mpc: LinearMpc) -> np.ndarray:
    """The (N, 3) inputs of the program's current QP solved by Clarabel (interior point)."""
    qp = mpc._qp
    result = ClarabelSolver().Solve(qp.prog)
    if not result.is_success():
        raise RuntimeError(f"Clarabel failed on the reference solve: {result.get_solution_result()}")
    return result.GetSolution(qp.u).reshape(qp.N, -1)


def replay(ticks, horizon: int, solver: str, check: bool = False) -> Replay:
    """A fresh controller fed the recorded inputs tick by tick; per tick its own compute timer
    (wall clock) and this thread's CPU time over the same update [s] (robust to other processes'
    load); with `check`, its plan against Clarabel's on the same QP data."""
    params = dc.replace(load_linear_mpc(), horizon_steps=horizon, solver=solver)
    mpc = LinearMpc(load_linear_model(), params)
    context = mpc.CreateDefaultContext()
    mpc.GetInputPort("active").FixValue(context, [1.0])
    ports = [mpc.GetInputPort(name) for name in INPUTS]
    status, prediction = mpc.GetOutputPort("controller_status"), mpc.GetOutputPort("prediction")
    cpu, failed, command_error, plan_error, iterations = [], 0, [], [], []
    for inputs in ticks:
        for port, name in zip(ports, INPUTS):
            port.FixValue(context, inputs[name])
        context.SetTime(inputs["time"])
        start = time.thread_time()
        context.SetDiscreteState(mpc.EvalUniquePeriodicDiscreteUpdate(context))
        cpu.append(time.thread_time() - start)
        iterations.append(mpc._qp.last.iterations if mpc._qp.last is not None else -1)
        mpc._qp.last = None
        if CONTROLLER_STATUS.get(status.Eval(context), "reason") != MpcReason.OK:
            failed += 1
        elif check:
            error = np.abs(prediction.Eval(context).reshape(horizon, -1) - exact_plan(mpc))
            command_error.append(error[0].max())
            plan_error.append(error.max())
    return Replay(mpc.compute_timer.seconds(), np.array(cpu), failed,
                  max(command_error, default=np.nan), max(plan_error, default=np.nan),
                  np.array(iterations))


def row(label: str, seconds: np.ndarray) -> str:
    us = seconds * 1e6
    return (f"{label:34s} {us.mean():8.0f} {us.std():8.0f} {np.percentile(us, 99):8.0f} "
            f"{us.max():8.0f} {us.mean() / PAPER_MEAN_US:8.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--horizons", type=int, nargs="+", default=[2, 20, 40])
    parser.add_argument("--solvers", nargs="+", default=["persistent", "daqp", "drake"],
                        choices=["persistent", "daqp", "drake"])
    parser.add_argument("--summary", default=load_linear_mpc().solver,
                        choices=["persistent", "daqp", "drake"],
                        help="the back end of the summary line (default: the model file's)")
    parser.add_argument("--check", action="store_true",
                        help="compare every tick's plan with Clarabel's (slow, not timed)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    solvers = list(dict.fromkeys(args.solvers + [args.summary]))
    horizons = sorted(set(args.horizons) | {2, 20})
    with tempfile.TemporaryDirectory() as tmp:
        run = fly_waypoints(load_sim_vehicle_config(), WAYPOINTS, seed=args.seed,
                            run_dir=Path(tmp) / "flight")
        ticks = tick_inputs(run)
        flown = run.compute_seconds("linear_mpc")
    params = load_linear_mpc()
    print(f"recorded flight: {len(ticks)} controller ticks at {1 / params.period:.0f} Hz, "
          f"landed {run.metadata['landed']}; load average {os.getloadavg()[0]:.1f} on "
          f"{os.cpu_count()} CPUs (timings spread with load)")
    print(f"{'':34s} {'mean':>8s} {'std':>8s} {'p99':>8s} {'max':>8s} {'/709.53':>8s}   [us]")
    print(row(f"in flight (N={params.horizon_steps}, {params.solver})", flown))
    replays = {}
    for horizon in horizons:
        for solver in solvers:
            result = replays[horizon, solver] = replay(ticks, horizon, solver)
            if args.check:
                checked = replay(ticks, horizon, solver, check=True)
                result.command_error, result.plan_error = checked.command_error, checked.plan_error
            label = f"N={horizon:3d} ({horizon * params.period:.2f} s) {solver}"
            print(row(label + " wall", result.wall))
            print(row(label + " CPU", result.cpu))
    print(f"load average {os.getloadavg()[0]:.1f} after the replays")
    for (horizon, solver), result in replays.items():
        checked = (f"; |u_0 - Clarabel's| max {result.command_error:.1e}, whole plan "
                   f"{result.plan_error:.1e} [rad, m/s^2]") if args.check else ""
        print(f"N={horizon} {solver}: CPU mean / 709.53 us = "
              f"{result.cpu.mean() * 1e6 / PAPER_MEAN_US:.2f}, failed ticks {result.failed}"
              + checked)
    for (horizon, solver), result in replays.items():
        if solver == "drake" or horizon != 20:
            continue
        its, worst = result.iterations, np.argsort(result.cpu)[::-1][:5]
        print(f"N=20 {solver}: iterations per tick mean {its.mean():.1f}, p99 "
              f"{np.percentile(its, 99):.0f}, max {its.max()}; ticks over 1 ms CPU "
              f"{int(np.sum(result.cpu > 1e-3))}; the 5 slowest ticks (CPU us / iterations): "
              + ", ".join(f"{result.cpu[i] * 1e6:.0f}/{its[i]}" for i in worst))
    for horizon in horizons:
        base = replays.get((horizon, "persistent"))
        for solver in ("daqp", "drake"):
            if base is not None and (horizon, solver) in replays:
                print(f"N={horizon}: {solver} / persistent osqp (mean CPU time) = "
                      f"{replays[horizon, solver].cpu.mean() / base.cpu.mean():.2f}")
    mean_us = replays[2, args.summary].cpu.mean() * 1e6
    worst_us = replays[20, args.summary].cpu.max() * 1e6
    print(f"mpc: N=2 mean {mean_us:.0f} us ({mean_us / PAPER_MEAN_US:.2f} x 709.53 us); "
          f"in flight N=20 worst {worst_us:.0f} us")


if __name__ == "__main__":
    main()
