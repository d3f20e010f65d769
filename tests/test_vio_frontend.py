"""The VIO front end on rendered frames (issue 8): new corners only where the depth image has depth,
so that a forward view whose strongest corners lie beyond the depth range (the horizon) still
starts landmarks."""
import numpy as np

from alight.systems.boundary import CameraFrame
from alight.systems.vio.frontend import FrontendParams, KltTracker, lookup_depth


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


def test_keypoint_depth_is_the_median_of_the_valid_depths_around_it():
    """Per keypoint: the median of the finite, positive depths in its patch, clipped at the
    image's border; NaN where the patch has none (a corner on a hole of the depth image)."""
    rng = np.random.default_rng(2)
    depth = rng.uniform(0.5, 9.0, (40, 60)).astype(np.float32)
    depth[rng.random(depth.shape) < 0.3] = np.nan
    depth[rng.random(depth.shape) < 0.05] = 0.0      # no return
    depth[10:17, 20:27] = np.nan                      # a hole larger than the patch
    uv = np.array([[0.2, 0.4], [59.4, 39.0], [30.0, 20.0], [23.0, 13.0], [5.6, 38.5],
                   [12.0, 7.0], [58.0, 1.0]])
    got = lookup_depth(depth, uv, 2)
    for (u, v), value in zip(np.rint(uv).astype(int), got):
        patch = depth[max(v - 2, 0):v + 3, max(u - 2, 0):u + 3]
        valid = patch[np.isfinite(patch) & (patch > 0)]
        assert (np.isnan(value) and valid.size == 0) or value == np.median(valid)
    assert np.isnan(got[3]) and np.isfinite(got[[0, 1, 2, 4, 5, 6]]).all()
    assert lookup_depth(depth, np.zeros((0, 2)), 2).shape == (0,)   # no keypoints
