"""The VIO front end on rendered frames (issue 8): new corners only where the depth image has depth,
so that a forward view whose strongest corners lie beyond the depth range (the horizon) still
starts landmarks."""
import numpy as np

from alight.systems.boundary import CameraFrame
from alight.systems.vio.frontend import FrontendParams, KltTracker


def _frame(image, depth):
    return CameraFrame(stamp=0.0, image=image, depth=depth, calibration={})


def test_new_corners_are_detected_only_where_there_is_depth():
    rng = np.random.default_rng(0)
    image = np.full((480, 640), 120, np.uint8)
    image[:200] = rng.choice([20, 230], (200, 640)).astype(np.uint8)        # far: strong corners
    image[200:] = np.clip(120 + 25 * rng.standard_normal((280, 640)), 0, 255).astype(np.uint8)
    depth = np.full((480, 640), 3.0, np.float32)
    depth[:200] = np.nan                                                    # beyond depth_max
    keypoints = KltTracker(FrontendParams()).track(_frame(image, depth))
    assert len(keypoints) >= 100
    assert np.all(keypoints.uv[:, 1] >= 200) and np.all(np.isfinite(keypoints.depth))


def test_without_a_depth_image_corners_are_detected_everywhere():
    rng = np.random.default_rng(1)
    image = rng.choice([20, 230], (480, 640)).astype(np.uint8)
    keypoints = KltTracker(FrontendParams()).track(_frame(image, None))
    assert len(keypoints) >= 100 and np.all(np.isnan(keypoints.depth))
    assert keypoints.uv[:, 1].min() < 100 and keypoints.uv[:, 1].max() > 380
