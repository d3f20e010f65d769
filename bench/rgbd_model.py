"""The geometric RGB-D camera model's cost per frame (issues 18, 20): `GeometricRgbdCamera.observe`
on the landing road's landmark map (models/rgbd_camera_landing.yaml) from a scripted camera path
along the road (climbing to 6 m, rolling, pitching and turning), each frame seeded by its index
as the simulation seeds them. Prints the landmarks, the features per frame and the thread CPU
time per frame: mean, p99 and max. Asserts nothing.

    python bench/rgbd_model.py [--frames 600]
"""
import argparse
import time

import numpy as np
from pydrake.math import RigidTransform, RollPitchYaw

from alight.diagrams.onboard.vio import load_rgbd_camera_params
from alight.systems.sensors.rgbd_camera import GeometricRgbdCamera


def camera_pose(t: float, X_BC: RigidTransform) -> RigidTransform:
    """The camera at `t` [s] on the scripted path up the road (30 frames per second)."""
    X_WB = RigidTransform(RollPitchYaw(0.1 * np.sin(t), 0.1 * np.cos(0.7 * t), 0.3 * t),
                          [10 * np.sin(0.1 * t), -30 + 3 * t, 1 + 0.5 * t if t < 10 else 6])
    return X_WB @ X_BC


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=600)
    args = parser.parse_args()
    params = load_rgbd_camera_params("rgbd_camera_landing.yaml")
    camera = GeometricRgbdCamera(params, 0)
    tracks, next_id, seconds, features = {}, 0, [], []
    for k in range(args.frames):
        X_WC = camera_pose(k / 30, params.X_BC())
        start = time.thread_time()
        frame, tracks, next_id, _ = camera.observe(X_WC, k / 30, np.random.default_rng(k),
                                                   tracks, next_id)
        seconds.append(time.thread_time() - start)
        if frame is not None:
            features.append(len(frame.keypoint_ids))
    ms = 1e3 * np.array(seconds)
    print(f"{len(camera.landmarks.p_WL)} landmarks, {len(camera.landmarks.boxes)} boxes; "
          f"{np.mean(features):.0f} features per frame over {args.frames} frames")
    print(f"observe: mean {ms.mean():.2f} ms, p99 {np.percentile(ms, 99):.2f} ms, "
          f"max {ms.max():.2f} ms (thread CPU time)")


if __name__ == "__main__":
    main()
