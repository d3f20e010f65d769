"""Calibration of the geometric down camera (a sensor model of the image front end) against the
rendered pipeline (issue 20; DESIGN.md "Simulation fidelity"; docs/target.md "Geometric camera model
and its calibration").

The same camera poses (the camera `distance` above the platform, tilted up to 10 deg, the pattern
anywhere in the middle of the image, the car under it) are seen by both sources:
- rendered: the Drake VTK render through the lens model (`DownCameraRig.render`), smeared by the
  motion blur of an angular rate about the camera's x axis over the exposure (a line kernel of the
  pattern centre's image motion; the rendered camera itself renders no blur);
- geometric: `GeometricDownCamera.candidates` at the same pose and rate;
then, for both, the target estimator's front end (`TargetEstimator.front_end`: the detector, L Sec.
5.2.1, or the candidate detection; the keypoint tracker, L Sec. 5.2.2, or the candidate
association, predicted from the true pose).
Printed per distance and per angular rate, for both: the detection rate; the detected corners'
error and the tracked keypoints' error (rectified px, median and 90th percentile, against the true
projection); keypoints found per frame; false detections per frame (a verified detection elsewhere
than the pattern); outlying keypoints per frame (tracked or associated more than 10 px from the
truth); for the geometric source its false candidates per frame.

    python bench/sensing_calibration.py [--frames 6] [--geometric-frames 200]
        [--lighting camera|sun --light-seed N]

Rendering a 1280 x 1024 frame in software takes about 0.5 s of CPU: the default 6 frames per cell
(5 distances + 4 rates, 54 rendered frames) takes about 2 minutes on one core.
"""
import argparse
import dataclasses as dc
import time

import cv2
import numpy as np
from pydrake.math import RigidTransform, RollPitchYaw

from alight.diagrams.onboard.perception import load_target_estimator_params
from alight.diagrams.world.lighting import LightingParams, draw_light
from alight.diagrams.world.target import DownCameraRig
from alight.models import model_path
from alight.systems.params import load_params
from alight.systems.boundary import CameraFrame
from alight.systems.perception.pattern import CORNER_IDS, Pattern
from alight.systems.perception.target_estimator import TargetEstimator
from alight.systems.sensors.down_camera import DownCameraParams
from alight.systems.target.vehicle import load_target_params

DISTANCES = (3.0, 6.0, 12.0, 20.0, 30.0)   # m, camera above the platform (at rest)
RATES = (3.0, 6.0, 12.0, 20.0)             # rad/s about the camera's x axis, at 6 m
RATE_DISTANCE = 6.0
OUTLIER = 10.0                             # px
TARGET = (0.0, 0.0, 0.4)                   # the car's x, y, heading in the rig


def view(rng, distance: float, rig: DownCameraRig) -> RigidTransform:
    """A camera pose `distance` above the platform, tilted up to 10 deg, the pattern within the
    middle half of the image."""
    for _ in range(100):
        offset = rng.uniform(-0.2, 0.2, 2) * distance
        X_WB = RigidTransform(RollPitchYaw(*np.radians(rng.uniform(-10, 10, 2)),
                                           rng.uniform(-np.pi, np.pi)),
                              [TARGET[0] + offset[0], TARGET[1] + offset[1],
                               rig.X_WT().translation()[2] + distance])
        uv, visible = rig.observe(X_WB, TARGET)
        if visible.all():
            return X_WB
    raise RuntimeError("no view with the whole pattern")


def blurred(X_TC: RigidTransform, rate: float, exposure: float):
    """X_TC `exposure` earlier under an angular rate about the camera's x axis (static target)."""
    R = RollPitchYaw(-rate * exposure, 0.0, 0.0).ToRotationMatrix()
    return X_TC @ RigidTransform(R, [0.0, 0.0, 0.0])


def line_kernel(shift: np.ndarray) -> np.ndarray:
    """A normalized line kernel along the image motion `shift` [px]."""
    length = int(np.ceil(np.linalg.norm(shift)))
    if length < 1:
        return np.ones((1, 1), np.float32)
    size = 2 * length + 1
    kernel = np.zeros((size, size), np.float32)
    for s in np.linspace(-0.5, 0.5, 4 * length + 1):
        u, v = np.round(length + s * shift).astype(int)
        kernel[v, u] = 1.0
    return kernel / kernel.sum()


@dc.dataclass
class Tally:
    frames: int = 0
    detected: int = 0
    false_detections: int = 0
    keypoints: int = 0
    outliers: int = 0
    false_candidates: int = 0
    corner_errors: list = dc.field(default_factory=list)
    keypoint_errors: list = dc.field(default_factory=list)

    def row(self) -> str:
        n = max(self.frames, 1)
        c = np.array(self.corner_errors) if self.corner_errors else np.array([np.nan])
        k = np.array(self.keypoint_errors) if self.keypoint_errors else np.array([np.nan])
        return (f"{self.detected / n:5.2f}  {np.median(c):5.2f} {np.percentile(c, 90):5.2f}  "
                f"{np.median(k):5.2f} {np.percentile(k, 90):5.2f}  {self.keypoints / n:5.2f}  "
                f"{self.false_detections / n:5.2f}  {self.outliers / n:5.2f}  "
                f"{self.false_candidates / n:5.2f}")


class Bench:
    def __init__(self, lighting: LightingParams):
        self.camera = load_params(DownCameraParams, model_path("down_camera.yaml"))
        self.lighting = lighting
        self.rig = DownCameraRig(self.camera, load_target_params(), lighting)
        self.params = load_target_estimator_params()
        self.pattern = Pattern(self.params.pattern)
        self.estimator = TargetEstimator(self.pattern, self.params)
        self.lens = self.camera.lens()
        self.calibration = self.lens.calibration()

    def truth(self, X_CT: RigidTransform) -> np.ndarray:
        return self.lens.rectified_project(X_CT.multiply(self.pattern.p_TK.T).T)

    def rendered(self, tally: Tally, X_WB, rate: float, seed: int) -> None:
        image = self.rig.render(X_WB, TARGET, seed)
        X_CT = self.rig.X_CT()
        before = blurred(X_CT.inverse(), rate, self.camera.exposure).inverse()
        shift = self.lens.project(before.translation()[None])[0] - \
            self.lens.project(X_CT.translation()[None])[0]
        image = cv2.filter2D(image, -1, line_kernel(shift))
        self._measure(tally, CameraFrame(0.0, image=image, calibration=self.calibration), X_CT)

    def geometric(self, tally: Tally, X_WB, rate: float, rng) -> None:
        self.rig.set_poses(X_WB, TARGET)
        X_CT = self.rig.X_CT()
        uv, ids = self.rig.geometric.candidates(
            X_CT.inverse(), blurred(X_CT.inverse(), rate, self.camera.exposure), rng)
        tally.false_candidates += int(np.sum(ids < 0))
        self._measure(tally, CameraFrame(0.0, keypoints=uv, calibration=self.calibration), X_CT)

    def _measure(self, tally: Tally, frame: CameraFrame, X_CT: RigidTransform) -> None:
        """The front end's detection (no reference orientation: the image's up, as at the first
        detection) and its tracking predicted from the true pose, against the truth."""
        R_CT = X_CT.rotation().matrix()
        detection, tracked = self.estimator.front_end(frame, X_CT, None, R_CT[:, 2])
        truth = self.truth(X_CT)
        tally.frames += 1
        if detection is not None:
            if np.linalg.norm(detection[0].translation() - X_CT.translation()) < \
                    0.25 * X_CT.translation()[2]:
                tally.detected += 1
                tally.corner_errors += [_nearest_corner(z, truth) for k, z in detection[1]
                                        if k in CORNER_IDS]
            else:
                tally.false_detections += 1
        errors = [float(np.linalg.norm(uv - truth[k])) for k, uv in tracked]
        tally.keypoints += sum(e <= OUTLIER for e in errors)
        tally.outliers += sum(e > OUTLIER for e in errors)
        tally.keypoint_errors += [e for e in errors if e <= OUTLIER]


def _nearest_corner(uv: np.ndarray, truth: np.ndarray) -> float:
    """Distance to the nearest true corner (the detection's 90-degree rotation is ambiguous)."""
    return float(np.min(np.linalg.norm(truth[list(CORNER_IDS)] - uv, axis=1)))


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=6, help="rendered frames per cell")
    parser.add_argument("--geometric-frames", type=int, default=200,
                        help="geometric frames per cell")
    parser.add_argument("--lighting", choices=("camera", "sun"), default="camera",
                        help="the rendered scene's light: Drake's headlight (the calibration's) "
                             "or the sun drawn from --light-seed (vehicle.lighting)")
    parser.add_argument("--light-seed", type=int, default=0)
    args = parser.parse_args()
    bench = Bench(LightingParams(kind=args.lighting, seed=args.light_seed))
    if args.lighting == "sun":
        print(f"lit by {draw_light(bench.lighting)}")
    cells = [(d, 0.0) for d in DISTANCES] + [(RATE_DISTANCE, r) for r in RATES]
    header = "detect  corner p50 p90  kp p50 p90  kp/fr  falsedet/fr  outl/fr  falsecand/fr"
    print(f"camera {bench.camera.width}x{bench.camera.height}, f {bench.camera.focal_length} px, "
          f"exposure {bench.camera.exposure * 1e3:.1f} ms; errors in rectified px "
          f"(f {bench.lens.K_rectified[0, 0]:.0f} px); outliers > {OUTLIER:.0f} px")
    print(f"{'distance':>8} {'rate':>5} {'blur':>5}  source     {header}")
    start = time.process_time()
    for i, (distance, rate) in enumerate(cells):
        rng = np.random.default_rng(100 + i)
        views = [view(rng, distance, bench.rig) for _ in range(args.geometric_frames)]
        rendered, geometric = Tally(), Tally()
        for j, X_WB in enumerate(views[:args.frames]):
            bench.rendered(rendered, X_WB, rate, seed=j)
        noise = np.random.default_rng(200 + i)
        for X_WB in views:
            bench.geometric(geometric, X_WB, rate, noise)
        blur = bench.camera.focal_length * rate * bench.camera.exposure
        print(f"{distance:8.1f} {rate:5.1f} {blur:5.1f}  rendered   {rendered.row()}")
        print(f"{'':8} {'':5} {'':5}  geometric  {geometric.row()}")
    print(f"CPU {time.process_time() - start:.0f} s")


if __name__ == "__main__":
    main()
