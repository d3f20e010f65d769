"""Tethered take-off (M Sec. 4.2): the F550 tied to the ground below it by 0.4 m of rope (it can
lift 0.18 m) takes off to 2 m on the landoff tracker, with the default admittance (0.5 m) and
without (admittance_distance 10 km), on the SE(3) and the MPC force controller. Prints per run
the largest control error |p_ref - p_EB|, the thrust (largest over the held time, and at its
end), the share of held ticks at full thrust, the largest tilt and how high the vehicle got.

    python bench/landoff.py [--duration 10] [--controllers se3,mpc] [--seed 2]
"""
import argparse
import dataclasses as dc
import tempfile
from pathlib import Path

import numpy as np

from alight.diagrams.running.flights import fly_landoff
from alight.diagrams.world.sim_vehicle import load_sim_vehicle_config, make_sim_vehicle
from alight.diagrams.running.track import resting_position
from alight.systems.plant.tether import TetherParams
from alight.systems.rotations import tilt_deg
from alight.systems.tracking.landoff_tracker import LandoffGoal, load_landoff_tracker_params

HELD_FROM = 2.0   # s: lifted off at 1.6 s, the rope taut from 1.8 s


def figures(run, p0) -> dict:
    n = min(len(run["reference"]), len(run["state_estimate"]))
    error = np.linalg.norm(run.field("reference", "p").to_numpy()[:n]
                           - run.field("state_estimate", "p_EB").to_numpy()[:n], axis=1)
    thrust = run["fc_command"]["thrust"].to_numpy()
    held = run["fc_command"]["time"].to_numpy() > HELD_FROM
    return {"error_m": error.max(), "thrust_max": thrust[held].max(),
            "thrust_end": thrust[-1], "at_full_thrust": np.mean(thrust[held] > 0.99),
            "tilt_deg": tilt_deg(run.field("ground_truth", "q_WB").to_numpy()).max(),
            "lift_m": run["ground_truth"]["p_WB_2"].max() - p0[2]}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=10.0)
    parser.add_argument("--controllers", default="se3,mpc")
    parser.add_argument("--seed", type=int, default=2)
    args = parser.parse_args()
    config = load_sim_vehicle_config()
    p0 = resting_position(make_sim_vehicle(config))
    config = dc.replace(config, tether=TetherParams(
        enabled=True, anchor=[p0[0], p0[1], 0.0], attachment=[0.0, 0.0, 0.0], length=0.4))
    params = load_landoff_tracker_params()
    print(f"tethered take-off to 2 m, {args.duration} s, seed {args.seed}")
    print(f"{'controller':10} {'admittance':>10} {'error m':>8} {'thrust max':>10} "
          f"{'thrust end':>10} {'full thrust':>11} {'tilt deg':>8} {'lift m':>6}")
    with tempfile.TemporaryDirectory() as folder:
        for controller in args.controllers.split(","):
            for distance in (params.admittance_distance, 1e4):
                run = fly_landoff(config, [(0.0, LandoffGoal.takeoff(2.0))], args.duration,
                                  args.seed, Path(folder) / f"{controller}_{distance}",
                                  dc.replace(params, admittance_distance=distance), controller)
                f = figures(run, p0)
                label = f"{distance:g} m" if distance < 1e3 else "none"
                print(f"{controller:10} {label:>10} {f['error_m']:8.2f} {f['thrust_max']:10.3f} "
                      f"{f['thrust_end']:10.3f} {f['at_full_thrust']:11.0%} "
                      f"{f['tilt_deg']:8.1f} {f['lift_m']:6.2f}")


if __name__ == "__main__":
    main()
