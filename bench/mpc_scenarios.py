"""Closed-loop figures of the landing paper's MPC on the simulated F550 with mocap odometry: the
scenarios of tests/test_linear_mpc.py, printed as numbers instead of pass/fail bounds.

    python bench/mpc_scenarios.py [--seed 0]
"""
import argparse
import copy
import dataclasses as dc
import tempfile
from pathlib import Path

import numpy as np
from pydrake.systems.primitives import ConstantVectorSource

from alight.diagrams.onboard.mpc_loop import load_linear_mpc
from alight.diagrams.running.flights import fly_reference
from alight.diagrams.world.sim_vehicle import load_sim_vehicle_config
from alight.systems.plant.wind import WindParams
from alight.systems.rotations import tilt_deg
from alight.systems.sensors.estimate_faults import EstimateFaultParams, EstimateFaults

HOVER = np.array([0.0, 0.0, 3.0])


def hover_then(fn, t0):
    return lambda t: (HOVER, np.zeros(3)) if t < t0 else fn(t - t0)


def after(run, t0):
    truth = run["ground_truth"]
    keep = (truth["time"] >= t0).to_numpy()
    return truth[keep], tilt_deg(run.field("ground_truth", "q_WB").to_numpy()[keep])


def jump_filter(builder, port):
    jump = EstimateFaultParams(jump=[5.0, 0.0, 0.0], jump_time=8.0)
    faults = builder.AddSystem(EstimateFaults(jump))
    zero = builder.AddSystem(ConstantVectorSource(np.zeros(6)))
    builder.Connect(zero.get_output_port(), faults.GetInputPort("noise"))
    builder.Connect(port, faults.GetInputPort("state_estimate"))
    return faults.GetOutputPort("state_estimate")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    config = load_sim_vehicle_config()
    tmp = Path(tempfile.mkdtemp())

    run = fly_reference(config, hover_then(lambda t: (HOVER + [5, 0, 0], np.zeros(3)), 8.0), 16.0,
                        tmp / "step", args.seed)
    truth, tilt = after(run, 8.0)
    x, t = truth["p_WB_0"].to_numpy(), truth["time"].to_numpy() - 8.0
    outside = np.flatnonzero(np.abs(x - 5.0) > 0.2)
    settle = t[min(outside[-1] + 1, len(t) - 1)] if len(outside) else 0.0
    print(f"5 m step: settles within 0.2 m after {settle:.2f} s, overshoot {x.max() - 5:.2f} m, "
          f"max tilt {tilt.max():.1f} deg")

    for with_velocity in (True, False):
        fn = hover_then(lambda t: (HOVER + [4.0 * t, 0, 0],
                                   np.array([4.0, 0, 0]) * with_velocity), 6.0)
        run = fly_reference(config, fn, 16.0, tmp / f"moving{with_velocity}", args.seed)
        truth, _ = after(run, 12.0)
        lag = HOVER[0] + 4.0 * (truth["time"] - 6.0) - truth["p_WB_0"]
        print(f"4 m/s reference {'with' if with_velocity else 'without'} velocity: mean lag "
              f"{lag.mean():.3f} m (s.d. {lag.std():.3f})")

    windy = copy.deepcopy(config)
    windy.wind = WindParams(mean_speed=15 / 3.6, direction=45.0, gust_std=0.8)
    run = fly_reference(windy, lambda t: (HOVER, np.zeros(3)), 25.0, tmp / "wind", args.seed + 2)
    truth, _ = after(run, 10.0)
    error = np.linalg.norm(truth[["p_WB_0", "p_WB_1", "p_WB_2"]].to_numpy() - HOVER, axis=1)
    print(f"hover in 15 km/h wind, gusts 0.8 m/s: max distance {error.max():.2f} m, "
          f"RMS {np.sqrt(np.mean(error ** 2)):.2f} m")

    for soft in (True, False):
        params = dc.replace(load_linear_mpc(), max_velocity=[2.0, 2.0, 1.0], max_tilt=12.0,
                            slack_penalty=1000.0 if soft else 0.0)
        run = fly_reference(config, lambda t: (HOVER, np.zeros(3)), 16.0, tmp / f"jump{soft}",
                            args.seed, params, jump_filter)
        truth, tilt = after(run, 8.0)
        speed = np.linalg.norm(truth[["v_WB_0", "v_WB_1"]].to_numpy(), axis=1)
        label = "soft constraints" if soft else "no constraints (lambda 0)"
        print(f"5 m estimate jump, limits 2 m/s and 12 deg, {label}: max speed "
              f"{speed.max():.2f} m/s, max tilt {tilt.max():.1f} deg")


if __name__ == "__main__":
    main()
