"""VIO figures (issue 8): per-frame front-end and back-end time, ATE, RPE per metre and final drift
for the geometric and rendered sources, on the same waypoint flight (closed loop). Prints figures;
asserts nothing. `python bench/vio.py [--sources geometric,rendered] [--seeds 0,1] [--clock wall]`.

The front- and back-end times are CPU time by default (`--clock cpu`: the compute timers of this
process measure this thread's CPU clock, so other jobs on a shared machine do not inflate them);
`--clock wall` keeps the wall clock a run folder logs. The back end is also given as p99."""
import argparse
import dataclasses as dc
import os
import tempfile
import time
import types

import numpy as np

from alight.diagrams.world.sim_vehicle import load_sim_vehicle_config
from alight.diagrams.analysis.vio import evaluate_vio
from alight.diagrams.onboard.vio import load_rgbd_camera_params
from alight.diagrams.running.flights import fly_vio
from alight.systems import timing

WAYPOINTS = [[0, 0, 2], [6, 0, 2], [6, 6, 3], [0, 0, 2]]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--sources", default="geometric,rendered")
    parser.add_argument("--seeds", default="0")
    parser.add_argument("--clock", choices=("cpu", "wall"), default="cpu")
    args = parser.parse_args()
    if args.clock == "cpu":
        timing.time = types.SimpleNamespace(perf_counter=time.thread_time)
    print(f"{args.clock} clock, load average {os.getloadavg()[0]:.2f}")
    print(f"{'source':10s} {'seed':>4s} {'path m':>7s} {'ATE m':>7s} {'RPE/m':>7s} {'drift':>7s} "
          f"{'front ms':>8s} {'back ms':>8s} {'back p99':>8s} {'back max':>8s} {'restarts':>8s} "
          f"{'wall s':>7s}")
    for source in args.sources.split(","):
        for seed in [int(s) for s in args.seeds.split(",")]:
            camera = dc.replace(load_rgbd_camera_params(), source=source)
            start = time.perf_counter()
            with tempfile.TemporaryDirectory() as run_dir:
                run = fly_vio(load_sim_vehicle_config(), WAYPOINTS, seed, run_dir, camera=camera)
                r = evaluate_vio(run)
                p99 = np.percentile(run.compute_seconds("vio", "backend"), 99) * 1e3
            wall = time.perf_counter() - start
            print(f"{source:10s} {seed:4d} {r['travelled']:7.1f} {r['ate_rmse']:7.3f} "
                  f"{r['rpe_per_m']:7.4f} {r['final_drift']:7.4f} {r['frontend_ms']:8.2f} "
                  f"{r['backend_ms']:8.1f} {p99:8.1f} {r['backend_max_ms']:8.1f} "
                  f"{r['restarts']:8d} "
                  f"{wall:7.1f}", flush=True)


if __name__ == "__main__":
    main()
