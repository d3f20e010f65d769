"""The VIO's per-frame CPU time without the rest of the simulation: `capture` flies the VIO landing
(field scenario, 2 m/s, seed 0) and pickles every IMU batch and camera frame the estimator got;
`time` replays them into a fresh `VioEstimator` (the same inputs, so the same keyframes) and prints,
min over the repeats, the CPU ms of `keypoints_of` per frame, of `add_frame` on frames that add no
keyframe, and of `add_frame` on keyframes less the iSAM2 `update` (the Python around GTSAM), with
the update's own ms. Quieter than a whole mission on a loaded machine: compare alternated runs.

    python bench/vio_frames.py capture /tmp/vio_inputs.pkl
    python bench/vio_frames.py time /tmp/vio_inputs.pkl --repeats 5
"""
import argparse
import pickle
import tempfile
import time
import types

import gtsam

from alight.systems.vio import backend, estimator, frontend


def capture(path: str) -> None:
    from alight.diagrams.running.runner import run
    from alight.diagrams.scenario import load_scenario
    calls, params = [], []
    cls = estimator.VioEstimator
    init, add_imu, add_frame = cls.__init__, cls.add_imu, cls.add_frame

    def recording_init(self, p, timer=None):
        params.append(p)
        calls.clear()  # (the initialization event makes the estimator anew)
        init(self, p, timer)

    cls.__init__ = recording_init
    cls.add_imu = lambda self, samples: (calls.append(("imu", samples)), add_imu(self, samples))
    cls.add_frame = lambda self, frame: (calls.append(("frame", frame)), add_frame(self, frame))
    with tempfile.TemporaryDirectory() as run_dir:
        run(load_scenario("field", overrides=["target_motion.speed: 2", "random_seed: 0"]),
            run_dir=run_dir, command="land")
    with open(path, "wb") as f:
        pickle.dump((params[-1], calls), f)
    print(f"{len(calls)} calls")


def replay(path: str, repeats: int) -> None:
    with open(path, "rb") as f:
        params, calls = pickle.load(f)
    isam_seconds = [0.0]

    class TimedISAM2(gtsam.ISAM2):
        def update(self, *args):
            start = time.thread_time()
            result = super().update(*args)
            isam_seconds[0] += time.thread_time() - start
            return result

    # the back end's gtsam with a timed ISAM2 (its module only: GTSAM's own type is left alone)
    backend.gtsam = types.SimpleNamespace(**{**vars(gtsam), "ISAM2": TimedISAM2})
    frames = [x for kind, x in calls if kind == "frame" and x.valid]
    rows = []
    for _ in range(repeats):
        tracker = frontend.KltTracker(params.frontend)
        start = time.thread_time()
        for frame in frames:
            frontend.keypoints_of(frame, tracker)
        front = (time.thread_time() - start) / len(frames)
        isam_seconds[0] = 0.0
        vio = estimator.VioEstimator(params)
        plain, keyframe = [], []
        for kind, x in calls:
            if kind == "imu":
                vio.add_imu(x)
            else:
                before = vio.window.keyframes if vio.window else 0
                start = time.thread_time()
                vio.add_frame(x)
                seconds = time.thread_time() - start
                (plain if (vio.window.keyframes if vio.window else 0) == before
                 else keyframe).append(seconds)
            vio.estimate()
        rows.append((front, sum(plain) / len(plain),
                     (sum(keyframe) - isam_seconds[0]) / len(keyframe),
                     isam_seconds[0] / len(keyframe)))
    best = [min(column) * 1e3 for column in zip(*rows)]
    print(f"keypoints_of {best[0]:.3f} ms/frame, add_frame without keyframe {best[1]:.3f} ms, "
          f"keyframe less iSAM2 update {best[2]:.3f} ms, iSAM2 update {best[3]:.2f} ms "
          f"(min of {repeats}; {len(plain)} + {len(keyframe)} frames)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("command", choices=("capture", "time"))
    parser.add_argument("path")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    capture(args.path) if args.command == "capture" else replay(args.path, args.repeats)


if __name__ == "__main__":
    main()
