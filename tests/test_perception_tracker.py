"""Keypoint tracking on rendered down-camera images (L Sec. 5.2.2), and the rendered camera source
in the vehicle diagram. Rendered at 640 x 512 px, the default lens scaled by 1/2."""
import dataclasses as dc

import numpy as np
import pytest
from pydrake.common import RandomGenerator
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.systems.analysis import Simulator

from alight.diagrams.onboard.perception import load_target_estimator_params
from alight.diagrams.world.sim_vehicle import make_sim_vehicle
from alight.diagrams.world.target import DownCameraRig
from alight.systems.boundary import FC_COMMAND
from alight.systems.perception.detector import RectifiedFrame, Rectifier
from alight.systems.perception.keypoint_tracker import KeypointTracker
from alight.systems.sensors.down_camera import DownCameraParams
from alight.systems.target.vehicle import load_target_params

TARGET = (3.0, -2.0, 0.4)  # x, y, heading of the target


@pytest.fixture(scope="module")
def rig():
    return DownCameraRig(DownCameraParams(width=640, height=512, focal_length=320.0),
                         load_target_params())


@pytest.fixture(scope="module")
def tracker(rig):
    """The paper's 20 px patches and 60 px search on the 1280 px camera: 10 and 30 px here."""
    params = load_target_estimator_params()
    scaled = dc.replace(params.tracker, patch_size=params.tracker.patch_size // 2,
                        search_size=params.tracker.search_size // 2)
    return Rectifier(params.detector), KeypointTracker(rig.scene.pattern, scaled)


def _track(rig, tracker, X_WB, X_CT_predicted, target=TARGET):
    rectifier, keypoints = tracker
    image = rig.render(X_WB, target, seed=2)
    binary = rectifier.binarize(rectifier.smooth(rectifier.rectify(image, rig.lens)))
    return keypoints.match(binary, rectifier.valid(rig.lens), rig.lens.K_rectified,
                           X_CT_predicted)


def _true_pixels(rig):
    p_C = (rig.X_CT().GetAsMatrix34() @ np.vstack([rig.scene.pattern.p_TK.T,
                                                   np.ones(len(rig.scene.pattern.p_TK))])).T
    return rig.lens.rectified_project(p_C)


@pytest.mark.parametrize("height, tilt_deg", [(4.0, 0.0), (8.0, 20.0)])
def test_tracker_finds_the_keypoints_from_a_predicted_pose(rig, tracker, height, tilt_deg):
    """The prediction is 15 cm and 3 deg off (a filter between frames): the keypoints are found
    at their true pixels."""
    X_WB = RigidTransform(RollPitchYaw(np.radians(tilt_deg), 0.0, 1.0),
                          [TARGET[0] + 0.5, TARGET[1] - 0.3, 1.0 + height])
    rig.set_poses(X_WB, TARGET)
    X_CT = rig.X_CT()
    error = RigidTransform(RollPitchYaw(0.0, np.radians(2.0), np.radians(3.0)), [0.1, -0.1, 0.05])
    matches = _track(rig, tracker, X_WB, X_CT @ error)
    truth = _true_pixels(rig)
    residuals = np.array([np.linalg.norm(m.uv - truth[m.id]) for m in matches])
    shifts = np.array([np.linalg.norm(m.predicted - truth[m.id]) for m in matches])
    print(f"\n{len(matches)} of 9 keypoints, residuals {residuals.round(2)} px, prediction off "
          f"by {shifts.round(1)} px")
    assert len(matches) >= 8
    assert shifts.mean() > 3.0  # the search had something to find
    # The EKF weighs keypoints with 5 px (L Sec. 5.2.2); the tracker does much better.
    assert np.median(residuals) < 1.5 and residuals.max() < 4.0


def test_tracker_rejects_patches_where_the_pattern_is_not(rig, tracker):
    """Predicted onto bare ground (the target is 40 m away): the binary patches do not match."""
    X_WB = RigidTransform(RollPitchYaw(0.0, 0.0, 1.0), [TARGET[0], TARGET[1], 6.0])
    rig.set_poses(X_WB, TARGET)
    X_CT = rig.X_CT()
    matches = _track(rig, tracker, X_WB, X_CT, target=(TARGET[0] + 40.0, TARGET[1], 0.0))
    assert len(matches) <= 1


def test_rendered_source_publishes_grey_lens_frames_from_the_vehicle(vehicle_config):
    camera = DownCameraParams(source="rendered", width=320, height=256, focal_length=160.0)
    target = dc.replace(load_target_params(), profile="straight", initial_position=[4.0, 0.0])
    dut = make_sim_vehicle(dc.replace(vehicle_config, down_camera=camera, target=target))
    simulator = Simulator(dut)
    context = simulator.get_mutable_context()
    dut.SetRandomContext(context, RandomGenerator(0))
    dut.GetInputPort("fc_command").FixValue(context, FC_COMMAND.pack(
        stamp=0.0, mode=1, q_WD=[1, 0, 0, 0], w_D=0.0, thrust=0.0, arm=0))
    simulator.AdvanceTo(0.2)
    frame = dut.GetOutputPort("down_image").Eval(context)
    assert frame.valid and frame.image.shape == (256, 320) and frame.image.dtype == np.uint8
    # Exposed at 12.3 ms + k 50 ms, released 30 ms later, stamped 5 ms late (no hardware sync).
    assert frame.stamp == pytest.approx(0.1623 + 0.005)
    assert frame.calibration["K"][0, 0] == 160.0 and len(frame.calibration["distortion"]) == 5
    assert 20.0 < frame.image.mean() < 235.0 and frame.image.std() > 1.0  # the ground, lit


@pytest.mark.parametrize("height, tilt_deg", [(4.0, 0.0), (8.0, 20.0)])
def test_tracking_in_the_searched_window_equals_the_whole_frame(rig, tracker, height, tilt_deg):
    """`track` rectifies and binarizes only the window around the searches (plus half the
    threshold's block): the same matches as on the whole frame's binary image, bit for bit."""
    rectifier, keypoints = tracker
    X_WB = RigidTransform(RollPitchYaw(np.radians(tilt_deg), 0.0, 1.0),
                          [TARGET[0] + 0.5, TARGET[1] - 0.3, 1.0 + height])
    image = rig.render(X_WB, TARGET, seed=2)
    X_CT = rig.X_CT() @ RigidTransform(RollPitchYaw(0.0, 0.03, 0.05), [0.1, -0.1, 0.05])
    whole = RectifiedFrame(rectifier, image, rig.lens)
    expected = keypoints.match(whole.view().binary, whole.view().valid, rig.lens.K_rectified,
                               X_CT)
    frame = RectifiedFrame(rectifier, image, rig.lens)
    window = frame.view(0, keypoints._window(frame, X_CT))
    found = keypoints.track(frame, X_CT)
    assert window.binary.size < 0.5 * whole.view().binary.size  # a window, not the frame
    assert len(found) == len(expected) >= 8
    for a, b in zip(found, expected):
        assert a.id == b.id and np.array_equal(a.uv, b.uv) and a.difference == b.difference


def test_tracking_a_pattern_predicted_out_of_view_finds_nothing(rig, tracker):
    """Predicted beside the image (the target left the view): no window, no match, no error."""
    rectifier, keypoints = tracker
    X_WB = RigidTransform(RollPitchYaw(0.0, 0.0, 1.0), [TARGET[0], TARGET[1], 6.0])
    rig.set_poses(X_WB, TARGET)
    image = rig.render(X_WB, TARGET, seed=2)
    frame = RectifiedFrame(rectifier, image, rig.lens)
    beside = RigidTransform([40.0, 0.0, 0.0]) @ rig.X_CT()
    assert keypoints._window(frame, beside) is None
    assert keypoints.track(frame, beside) == []
    with pytest.raises(ValueError, match="outside"):
        frame.view(0, (700.0, 0.0, 900.0, 100.0))
