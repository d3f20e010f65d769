"""The local camera-frame channel (camera images do not travel over MAVLink): any `CameraFrame`
(image, depth, calibration, geometric keypoints) crosses from the simulated autopilot's process to
the MAVLink vehicle's camera ports intact, newest first, only to a subscriber with the key, with
its stamp mapped from the autopilot's clock to the onboard clock. The simulated world's mocap
estimate crosses it too and becomes the onboard `state_estimate` (hw/channel_odometry.py)."""
import time

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from alight.hw.channel_odometry import ChannelOdometry, ChannelOdometryParams
from alight.hw.frame_channel import EstimateSample, FramePublisher, FrameSubscriber
from alight.hw.link import LinkParams, MavlinkLink
from alight.hw.mavlink_vehicle import MavlinkVehicleParams, make_mavlink_vehicle
from alight.hw.realtime import WallClock
from alight.systems.boundary import STATE_ESTIMATE, CameraFrame
from mavlink_fake import FrameEncoder, NullTransport, lock_clock

RNG = np.random.default_rng(3)


def synthetic_frame(stamp: float) -> CameraFrame:
    return CameraFrame(
        stamp=stamp, image=RNG.integers(0, 256, size=(480, 640), dtype=np.uint8),
        depth=RNG.uniform(0.5, 10.0, size=(480, 640)).astype(np.float32),
        calibration={"K": np.array([[600.0, 0, 320], [0, 600, 240], [0, 0, 1]]),
                     "distortion": np.zeros(5), "width": 640, "height": 480},
        keypoints=RNG.uniform(0, 640, size=(12, 2)), keypoint_ids=np.arange(12))


def wait_for(condition, timeout=5.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.01)
    return False


@pytest.fixture
def channel(tmp_path):
    publisher = FramePublisher(str(tmp_path / "frames.sock"))
    subscriber = FrameSubscriber(publisher.address, retry=0.05)
    assert wait_for(lambda: publisher.connected)
    yield publisher, subscriber
    subscriber.close()
    publisher.close()


def assert_same_frame(a: CameraFrame, b: CameraFrame):
    assert a.stamp == b.stamp
    for field in ("image", "depth", "keypoints", "keypoint_ids"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    np.testing.assert_array_equal(a.calibration["K"], b.calibration["K"])
    assert a.calibration["width"] == b.calibration["width"]


def test_a_camera_frame_crosses_the_channel_intact(channel):
    publisher, subscriber = channel
    frame = synthetic_frame(1.25)
    publisher.publish("down_image", frame)
    assert wait_for(lambda: subscriber.latest("down_image") is not None)
    assert_same_frame(subscriber.latest("down_image"), frame)
    assert subscriber.latest("rgbd") is None


def test_a_slow_reader_gets_the_newest_frame_never_an_old_one(channel):
    publisher, subscriber = channel
    frames = [synthetic_frame(0.05 * k) for k in range(40)]
    for frame in frames:
        publisher.publish("rgbd", frame)
    assert wait_for(lambda: subscriber.latest("rgbd") is not None
                    and subscriber.latest("rgbd").stamp == frames[-1].stamp)
    assert_same_frame(subscriber.latest("rgbd"), frames[-1])
    counters = publisher.counters
    assert counters.published == 40 and counters.sent + counters.replaced == 40
    assert subscriber.counters.received == counters.sent and subscriber.counters.invalid == 0


def test_a_subscriber_without_the_key_gets_nothing(tmp_path):
    publisher = FramePublisher(str(tmp_path / "frames.sock"))
    intruder = FrameSubscriber(publisher.address, authkey=b"wrong", retry=0.05)
    try:
        time.sleep(0.5)
        publisher.publish("down_image", synthetic_frame(1.0))
        time.sleep(0.5)
        assert intruder.latest("down_image") is None and not publisher.connected
    finally:
        intruder.close()
        publisher.close()


def test_the_vehicle_camera_port_holds_the_frame_on_the_onboard_clock(channel):
    publisher, subscriber = channel
    link = MavlinkLink(NullTransport(), LinkParams(), WallClock(), datagrams=True)
    lock_clock(link, FrameEncoder(1, 1), tc1_ns=100_000_000_000)  # the autopilot is at 100 s
    t_sync = link.clock.now()
    vehicle = make_mavlink_vehicle(link, MavlinkVehicleParams(), frames=subscriber)
    simulator = Simulator(vehicle)
    context = simulator.get_mutable_context()
    vehicle.GetInputPort("fc_command").FixValue(context, np.zeros(11))
    frame = synthetic_frame(100.5)  # autopilot time
    publisher.publish("down_image", frame)
    assert wait_for(lambda: subscriber.latest("down_image") is not None)
    simulator.AdvanceTo(0.05)
    port = vehicle.GetOutputPort("down_image").Eval(context)
    assert port.stamp == pytest.approx(link.to_local(100.5)) and port.valid
    assert port.stamp == pytest.approx(t_sync + 0.5, abs=0.01)  # 0.5 s after the sync reply
    np.testing.assert_array_equal(port.image, frame.image)
    np.testing.assert_array_equal(port.keypoints, frame.keypoints)
    assert not vehicle.GetOutputPort("rgbd").Eval(context).valid


def test_a_real_camera_through_opencv_feeds_the_down_image_port(tmp_path):
    """A recorded video stands in for the camera device: 20 frames at 50 fps, each marked."""
    import cv2
    from alight.hw.opencv_camera import CameraError, OpenCvCamera, OpenCvCameraParams
    from alight.systems.sensors.down_camera import DownCameraParams
    calibration = DownCameraParams(width=320, height=240, focal_length=200.0).lens().calibration()
    video = str(tmp_path / "flight.avi")
    writer = cv2.VideoWriter(video, cv2.VideoWriter_fourcc(*"MJPG"), 50, (320, 240))
    for k in range(20):
        writer.write(np.full((240, 320, 3), 10 * k + 5, np.uint8))
    writer.release()
    with pytest.raises(CameraError, match="cannot open camera"):
        OpenCvCamera("down_image", OpenCvCameraParams(device=str(tmp_path / "none.avi")),
                     calibration, WallClock())
    link = MavlinkLink(NullTransport(), LinkParams(), WallClock(), datagrams=True)
    camera = OpenCvCamera("down_image", OpenCvCameraParams(device=video, latency=0.03),
                          calibration, link.clock)
    try:
        vehicle = make_mavlink_vehicle(link, MavlinkVehicleParams(),
                                       cameras={"down_image": camera})
        simulator = Simulator(vehicle)
        context = simulator.get_mutable_context()
        vehicle.GetInputPort("fc_command").FixValue(context, np.zeros(11))
        seen = []
        for step in range(1, 120):  # 0.6 s of 5 ms updates against a 0.4 s video
            simulator.AdvanceTo(0.005 * step)
            frame = vehicle.GetOutputPort("down_image").Eval(context)
            if frame.valid and (not seen or frame.stamp != seen[-1].stamp):
                seen.append(frame)
            time.sleep(0.005)
    finally:
        camera.close()
    levels = [int(round(f.image.mean())) for f in seen]
    assert len(seen) >= 15 and levels == sorted(levels)  # in order, once each, few replaced
    assert seen[0].image.shape == (240, 320) and seen[0].image.dtype == np.uint8  # grayscale
    assert seen[0].calibration["width"] == 320
    np.testing.assert_allclose(seen[0].calibration["K"], calibration["K"])
    assert np.all(np.diff([f.stamp for f in seen]) > 0)
    assert camera.counters.captured == 20 and camera.counters.wrong_size == 0
    assert camera.counters.published + camera.counters.replaced == 20
    # A camera delivering another size than its calibration: every frame dropped and counted.
    wrong = OpenCvCamera("down_image", OpenCvCameraParams(device=video), DownCameraParams(
        width=640, height=480).lens().calibration(), WallClock())
    time.sleep(0.6)
    wrong.close()
    assert wrong.counters.wrong_size == 20 and wrong.counters.captured == 0


def mocap_sample(stamp: float, p_EB, valid: float = 1.0) -> EstimateSample:
    return EstimateSample(STATE_ESTIMATE.vector(
        stamp=stamp, p_EB=p_EB, v_EB=[1.0, 0, 0], var_pv=[1e-6] * 6, var_heading=1e-4,
        valid=valid))


def test_the_channel_mocap_is_the_onboard_state_estimate_until_it_stops(channel):
    publisher, subscriber = channel
    link = MavlinkLink(NullTransport(), LinkParams(), WallClock(), datagrams=True)
    lock_clock(link, FrameEncoder(1, 1), tc1_ns=100_000_000_000)  # the autopilot is at 100 s
    dut = ChannelOdometry(subscriber, link, ChannelOdometryParams(timeout=0.2))
    simulator = Simulator(dut)
    context = simulator.get_mutable_context()
    port = dut.GetOutputPort("state_estimate")
    simulator.AdvanceTo(0.02)
    assert STATE_ESTIMATE.get(port.Eval(context), "valid") == 0.0  # nothing received yet
    publisher.publish("mocap", mocap_sample(100.5, [1.0, 2.0, 3.0]))
    assert wait_for(lambda: subscriber.latest("mocap") is not None)
    simulator.AdvanceTo(0.04)
    estimate = port.Eval(context)
    assert STATE_ESTIMATE.get(estimate, "valid") == 1.0
    np.testing.assert_array_equal(STATE_ESTIMATE.get(estimate, "p_EB"), [1.0, 2.0, 3.0])
    assert STATE_ESTIMATE.get(estimate, "stamp") == pytest.approx(link.to_local(100.5))
    # A NaN or invalid sample never reaches the port: counted and dropped on the channel.
    for count, bad in enumerate([mocap_sample(100.6, [np.nan, 0.0, 0.0]),
                                 mocap_sample(100.7, [9.0, 9.0, 9.0], valid=0.0)], 1):
        publisher.publish("mocap", bad)
        assert wait_for(lambda: subscriber.counters.invalid == count)
    simulator.AdvanceTo(0.06)
    np.testing.assert_array_equal(STATE_ESTIMATE.get(port.Eval(context), "p_EB"), [1, 2, 3])
    # The source stops: the estimate goes invalid `timeout` after its stamp.
    simulator.AdvanceTo(STATE_ESTIMATE.get(estimate, "stamp") + 0.25)
    assert STATE_ESTIMATE.get(port.Eval(context), "valid") == 0.0
