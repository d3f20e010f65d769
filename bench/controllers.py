"""Per-tick time of the flight-stack controllers (M Sec. 5): SE(3) M(38) and the MPC force-feedback
controller M(39)-(52) with each of Drake's QP solvers, and the MPC's ratio to the 10 ms budget of a
100 Hz loop.

Each controller runs alone on its own context: every tick gets a new state estimate around a
hovering reference, with position errors from 0 to 5 m (an estimator jump is the hardest case for
the QP: many bounds active) and velocity errors up to 3 m/s, and one periodic update is timed.

    /work/venv/bin/python bench/controllers.py [--ticks 2000]
"""
import argparse
import dataclasses as dc
import time

import numpy as np

from alight.diagrams.onboard.controllers import load_controllers_config, make_controller
from alight.systems.control.mpc_force import MpcForceQp
from alight.systems.boundary import FC_COMMAND, REFERENCE, STATE_ESTIMATE, CommandMode
from alight.systems.rotations import heading_quaternion

BUDGET = 0.01  # s, one tick of a 100 Hz loop


def estimates(ticks: int, rng: np.random.Generator) -> list[np.ndarray]:
    out = []
    for k in range(ticks):
        size = 5.0 * (k % 100) / 99.0               # sweeps 0 .. 5 m every 100 ticks
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        out.append(STATE_ESTIMATE.vector(
            p_EB=np.array([0, 0, 3.0]) + size * direction, v_EB=rng.uniform(-3, 3, 3),
            q_EB=heading_quaternion(0.1), heading=0.1, var_pv=np.full(6, 1e-4), var_heading=1e-4))
    return out


def time_controller(name: str, ticks: int, solver: str | None = None) -> np.ndarray:
    config = load_controllers_config()
    if solver is not None:
        config.mpc.solver = solver
    dut = make_controller(name, config)
    context = dut.CreateDefaultContext()
    dut.GetInputPort("reference").FixValue(context, REFERENCE.pack(
        stamp=0.0, p=[0, 0, 3.0], v=np.zeros(3), a=np.zeros(3), j=np.zeros(3), heading=0.1,
        heading_rate=0.0))
    dut.GetInputPort("active").FixValue(context, [1.0])
    dut.GetInputPort("last_command").FixValue(context, FC_COMMAND.pack(
        stamp=0.0, mode=CommandMode.RATES_THRUST, q_WD=heading_quaternion(0.1), w_D=np.zeros(3),
        thrust=0.64, arm=1.0))
    estimate_port = dut.GetInputPort("state_estimate")
    times = []
    for k, estimate in enumerate(estimates(ticks, np.random.default_rng(0))):
        context.SetTime(0.01 * k)
        estimate[STATE_ESTIMATE.slice("stamp")] = 0.01 * k
        estimate_port.FixValue(context, estimate)
        start = time.perf_counter()
        update = dut.EvalUniquePeriodicDiscreteUpdate(context)
        times.append(time.perf_counter() - start)
        context.SetDiscreteState(update)
    return np.array(times[10:])  # the first ticks include lazy initialization


def solver_agreement(ticks: int, solver: str, reference: str = "clarabel") -> np.ndarray:
    """max |u - u_reference| over the horizon (m/s^2), per tick, of the MPC's QP solved by
    `solver` and by `reference` from the same initial states (the reference's last first input
    as u_prev): the position and velocity errors of `estimates`."""
    config = load_controllers_config()
    qps = [MpcForceQp(dc.replace(config.mpc, solver=name), config.period)
           for name in (solver, reference)]
    u_prev, gaps = np.zeros(3), []
    for estimate in estimates(ticks, np.random.default_rng(0)):
        e_p = STATE_ESTIMATE.get(estimate, "p_EB") - [0, 0, 3.0]
        x0 = qps[1].initial_state(e_p, STATE_ESTIMATE.get(estimate, "v_EB"), u_prev)
        (ok, u, _), (ok_ref, u_ref, _) = (qp.solve(x0, u_prev) for qp in qps)
        gaps.append(np.abs(u - u_ref).max() if ok and ok_ref else np.inf)
        u_prev = u_ref[:, 0]
    return np.array(gaps)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ticks", type=int, default=2000)
    args = parser.parse_args()
    print(f"{'controller':22s} {'mean ms':>8s} {'p99 ms':>8s} {'max ms':>8s} {'mean/10 ms':>11s}")
    for label, name, solver in (("se3", "se3", None), ("mpc (clarabel)", "mpc", "clarabel"),
                                ("mpc (osqp)", "mpc", "osqp"), ("mpc (daqp)", "mpc", "daqp")):
        t = time_controller(name, args.ticks, solver) * 1e3
        print(f"{label:22s} {t.mean():8.3f} {np.percentile(t, 99):8.3f} {t.max():8.3f} "
              f"{t.mean() / (BUDGET * 1e3):11.3f}")
    for solver in ("osqp", "daqp"):
        gap = solver_agreement(args.ticks, solver)
        print(f"mpc ({solver}) against clarabel, max |u - u_clarabel| over the horizon: median "
              f"{np.median(gap):.2e}, p99 {np.percentile(gap, 99):.2e}, max {gap.max():.2e} m/s^2 "
              f"({np.count_nonzero(~np.isfinite(gap))} failed solves of {len(gap)})")


if __name__ == "__main__":
    main()
