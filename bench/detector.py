"""Time per frame of the landing-pattern detection (L Sec. 5.2.1) and keypoint tracking (L Sec.
5.2.2) on rendered down-camera frames, at the Chameleon 3 class resolution (1280 x 1024) and at
640 x 480; in the same run, the AprilTag 3 detector (pupil-apriltags, tag36h11, one thread) at
quad_decimate 1 and 2 (its default) on the same frames with a tag36h11 drawn over the pattern: the
ratios ours / AprilTag and the recall of each. The paper wrote its own detector because AprilTag did
not run in real time on its computer.

Ours runs twice per frame: from a cold start (the whole frame) and around a prediction (the truth
moved by a random filter-sized error, with its standard deviation: a window at a pyramid level,
falling back to the whole frame on a miss). Times are the CPU time of the thread (OpenCV on one
thread), per frame the least of 3 runs; mean, p99 and max over the frames.

Also measures the verification tests' discrimination: for every quadrilateral candidate in frames
of the pattern and of the ground's look-alike squares, the NCC score and the BRISK descriptor
distance (the paper's test), and how well each separates the pattern from the look-alikes; and the
false detections of each detector on those look-alike frames (for AprilTag: any tag).

    python bench/detector.py [--frames 60]
"""
import argparse
import time

import cv2
import numpy as np
from pupil_apriltags import Detector as AprilTagDetector
from pydrake.math import RigidTransform, RollPitchYaw

from alight.diagrams.onboard.perception import load_target_estimator_params
from alight.diagrams.world.target import DownCameraRig
from alight.models.textures import GROUND_TILE
from alight.systems.perception.detector import (PatternDetector, Prediction,
                                                RectifiedFrame, Rectifier)
from alight.systems.perception.keypoint_tracker import KeypointTracker
from alight.systems.perception.pattern import CORNER_IDS
from alight.systems.sensors.down_camera import DownCameraParams
from alight.systems.target.vehicle import load_target_params

RESOLUTIONS = ((1280, 1024, 640.0), (640, 480, 320.0))  # width, height, focal length [px]


def views(count: int, seed: int = 0):
    """Camera poses 3-12 m above the platform, tilted up to 20 deg, pattern off-centre."""
    rng = np.random.default_rng(seed)
    for _ in range(count):
        height = rng.uniform(3.0, 12.0)
        offset = rng.uniform(-0.25, 0.25, 2) * height
        yield RigidTransform(RollPitchYaw(*np.radians(rng.uniform(-20, 20, 2)),
                                          rng.uniform(-np.pi, np.pi)),
                             [offset[0], offset[1], 1.0 + height])


def tag_image(frame: np.ndarray, corners_uv: np.ndarray) -> np.ndarray:
    """The frame with a tag36h11 (id 0, white quiet zone) warped onto the pattern's white square."""
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)
    tag = cv2.aruco.generateImageMarker(dictionary, 0, 200)
    tag = cv2.copyMakeBorder(tag, 25, 25, 25, 25, cv2.BORDER_CONSTANT, value=255)
    n = tag.shape[0]
    # Keypoints 0-3 run counter-clockwise about z_T from (+a, +a); seen from above that is
    # top-right, top-left, bottom-left, bottom-right of the square.
    source = np.float32([[n, 0], [0, 0], [0, n], [n, n]])
    H = cv2.getPerspectiveTransform(source, corners_uv.astype(np.float32))
    warped = cv2.warpPerspective(tag, H, frame.shape[::-1], flags=cv2.INTER_LINEAR)
    mask = cv2.warpPerspective(np.full_like(tag, 255), H, frame.shape[::-1])
    return np.where(mask > 127, warped, frame).astype(np.uint8)


PREDICTION_STD = (0.1, 0.03)  # m, rad: the prediction's error is drawn with these


def timed(function, repeats: int = 3) -> float:
    """CPU time of this thread [s], the least of `repeats` runs."""
    best = np.inf
    for _ in range(repeats):
        start = time.thread_time()
        function()
        best = min(best, time.thread_time() - start)
    return best


def predicted(X_CT: RigidTransform, rng) -> Prediction:
    error = RigidTransform(RollPitchYaw(*rng.normal(0.0, PREDICTION_STD[1], 3)),
                           rng.normal(0.0, PREDICTION_STD[0], 3))
    return Prediction(X_CT @ error, *PREDICTION_STD)


def make_rig(width: int, height: int, focal_length: float) -> DownCameraRig:
    return DownCameraRig(DownCameraParams(width=width, height=height, focal_length=focal_length),
                         load_target_params())


def bench_resolution(rig: DownCameraRig, frames: int):
    """Per frame: CPU seconds of detect (cold), detect (around a prediction), track, AprilTag at
    decimate 1 and 2; found by each of the four detectors (0/1)."""
    params = load_target_estimator_params()
    rectifier = Rectifier(params.detector)
    detector = PatternDetector(rig.scene.pattern, params.detector)
    tracker = KeypointTracker(rig.scene.pattern, params.tracker)
    apriltags = [AprilTagDetector(families="tag36h11", nthreads=1, quad_decimate=d)
                 for d in (1.0, 2.0)]
    lens = rig.lens
    rng = np.random.default_rng(7)
    rows = []
    for X_WB in views(frames):
        image = rig.render(X_WB, (0.0, 0.0, 0.0), seed=1)
        uv, visible = rig.observe(X_WB)
        if not visible[list(CORNER_IDS)].all():
            continue
        X_CT = rig.X_CT()
        z_up_C = (X_WB.rotation() @ rig.X_BC.rotation()).inverse().multiply([0.0, 0.0, 1.0])
        tagged = tag_image(image, uv[list(CORNER_IDS)])
        prediction = predicted(X_CT, rng)
        found = {}

        def detect(name, **kwargs):
            found[name] = detector.detect(RectifiedFrame(rectifier, image, lens), z_up_C=z_up_C,
                                          **kwargs)

        def track():
            tracker.track(RectifiedFrame(rectifier, image, lens), prediction.X_CT)

        def tag(k):
            found[k] = apriltags[k].detect(tagged)

        if not rows:  # one-time set-up outside the timing (rectification maps, allocations)
            detect("cold"), detect("roi", prediction=prediction), track(), tag(0), tag(1)
        rows.append((timed(lambda: detect("cold")),
                     timed(lambda: detect("roi", prediction=prediction)), timed(track),
                     timed(lambda: tag(0)), timed(lambda: tag(1)),
                     *(bool(found[k]) for k in ("cold", "roi", 0, 1))))
    return np.array(rows, float)


def false_detections(rig: DownCameraRig, frames):
    """Frames of the ground's look-alike squares (no target, no tag) with a detection: ours cold,
    ours around a wrong prediction (a pattern 6 m below the image centre), AprilTag decimate 1,
    decimate 2."""
    params = load_target_estimator_params()
    rectifier = Rectifier(params.detector)
    detector = PatternDetector(rig.scene.pattern, params.detector)
    apriltags = [AprilTagDetector(families="tag36h11", nthreads=1, quad_decimate=d)
                 for d in (1.0, 2.0)]
    counts = np.zeros(4, int)
    for X_WB in frames:
        image = rig.render(X_WB, (500.0, 500.0, 0.0), seed=2)
        R_WC = X_WB.rotation() @ rig.X_BC.rotation()
        z_up_C = R_WC.inverse().multiply([0.0, 0.0, 1.0])
        wrong = Prediction(RigidTransform(R_WC.inverse(), [0.0, 0.0, 6.0]), 0.3, 0.1)
        counts += [bool(detector.detect(RectifiedFrame(rectifier, image, rig.lens),
                                        z_up_C=z_up_C)),
                   bool(detector.detect(RectifiedFrame(rectifier, image, rig.lens),
                                        z_up_C=z_up_C, prediction=wrong)),
                   bool(apriltags[0].detect(image)), bool(apriltags[1].detect(image))]
    return counts


def lookalike_poses():
    """A 4 x 4 grid over one ground texture tile, 4-8 m up."""
    spacing = GROUND_TILE / 4
    return [RigidTransform(RollPitchYaw(0.05, -0.03, 0.3 * i + j), [
        -GROUND_TILE / 2 + (i + 0.5) * spacing, -GROUND_TILE / 2 + (j + 0.5) * spacing,
        4.0 + 2.0 * ((i + j) % 3)]) for i in range(4) for j in range(4)]


def discrimination(frames: int):
    """Verification scores of the pattern's own quadrilaterals and of every other candidate
    (look-alikes on the ground, car parts) at 640 x 512."""
    rig = DownCameraRig(DownCameraParams(width=640, height=512, focal_length=320.0),
                        load_target_params())
    params = load_target_estimator_params().detector
    rectifier = Rectifier(params)
    detector = PatternDetector(rig.scene.pattern, params)
    pattern, others = [], []
    poses = list(views(frames, seed=1)) + lookalike_poses()
    for X_WB in poses:
        image = rig.render(X_WB, (0.0, 0.0, 0.0), seed=2)
        uv, _ = rig.observe(X_WB)
        truth = rig.lens.rectify_points(uv[list(CORNER_IDS)]) if np.all(np.isfinite(uv)) else None
        for c in detector.candidates(RectifiedFrame(rectifier, image, rig.lens).view(),
                                     both_scores=True):
            own = truth is not None and np.linalg.norm(
                c.corners[None] - truth[:, None], axis=2).min(axis=1).max() < 3.0
            (pattern if own else others).append((c.correlation, c.brisk_distance))
    return np.array(pattern), np.array(others)


def stats(seconds: np.ndarray) -> str:
    ms = 1000 * seconds
    return f"{ms.mean():6.1f} {np.percentile(ms, 99):6.1f} {ms.max():6.1f}"


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--frames", type=int, default=60)
    args = parser.parse_args()
    if args.frames < 1:
        parser.error("--frames must be at least 1")
    cv2.setNumThreads(1)  # one core for both detectors
    print("CPU time per frame [ms] (thread time, least of 3 runs per frame; OpenCV one thread): "
          "mean p99 max; recall over the frames")
    names = ("detect, whole frame (cold start)", "detect around the prediction",
             "track (keypoints, in the searched window)", "AprilTag 3, quad_decimate 1",
             "AprilTag 3, quad_decimate 2")
    summary = None
    rigs = {}
    for width, height, f in RESOLUTIONS:
        rigs[width] = make_rig(width, height, f)
        rows = bench_resolution(rigs[width], args.frames if width > 640 else
                                max(1, args.frames // 3))
        recall = {0: rows[:, 5], 1: rows[:, 6], 3: rows[:, 7], 4: rows[:, 8]}
        print(f"{width}x{height}, {len(rows)} frames:")
        for i, name in enumerate(names):
            extra = f"  recall {recall[i].mean():.3f}" if i in recall else ""
            print(f"  {name:<46} {stats(rows[:, i])}{extra}")
        mean = rows.mean(axis=0)
        print(f"  ours / AprilTag (mean): cold {mean[0] / mean[3]:.2f} and {mean[0] / mean[4]:.2f}"
              f", around the prediction {mean[1] / mean[3]:.2f} and {mean[1] / mean[4]:.2f} "
              f"(decimate 1 and 2)")
        if width == 1280:
            summary = (f"detector 1280x1024: ours/AprilTag(decimate 2) {mean[0] / mean[4]:.2f}, "
                       f"recall {recall[0].mean():.3f} vs {recall[4].mean():.3f}")
    counts = false_detections(rigs[1280], lookalike_poses())
    print(f"\nfalse detections in {len(lookalike_poses())} look-alike ground frames at 1280x1024:"
          f" ours cold {counts[0]}, ours around a wrong prediction {counts[1]}, AprilTag "
          f"decimate 1 {counts[2]}, decimate 2 {counts[3]}")
    pattern, others = discrimination(args.frames)
    print(f"\nverification at 640x512: {len(pattern)} candidates of the pattern, "
          f"{len(others)} others (look-alikes, car)")
    for name, column, better in (("NCC", 0, "higher"), ("BRISK distance", 1, "lower")):
        a, b = pattern[:, column], others[:, column]
        if better == "lower":
            a, b = -a, -b
        margin = a.min() - b.max()
        print(f"  {name:>15}: pattern {np.abs(a).min():.3f}-{np.abs(a).max():.3f}, others "
              f"{np.abs(b).min():.3f}-{np.abs(b).max():.3f}; worst-case margin {margin:+.3f} "
              f"({better} is the pattern); others past the pattern's worst: "
              f"{np.mean(b >= a.min()):.3f}")
    print(summary)


if __name__ == "__main__":
    main()
