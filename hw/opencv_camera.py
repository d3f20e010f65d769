"""A real camera behind a camera port of the MAVLink vehicle, through OpenCV (`cv2.VideoCapture`):
on a vehicle the `down_image` (or `rgbd`) port reads it instead of the local frame channel.

A capture thread takes frames as the camera delivers them (a video file plays at its own frame
rate: recorded flights, tests) and stamps each on the onboard clock at its arrival minus the
configured latency (no hardware trigger; the simulated camera models the same `latency`). The
system's periodic update puts the newest frame on its port, each frame once, with the camera's
calibration (the same dict the simulated camera sends: K, distortion, size, X_BC). A frame whose
size differs from the calibration is dropped and counted: its calibration would be wrong.
"""
import dataclasses as dc
import math
import threading
import time

import cv2
import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem

from alight.hw.endpoint import LOG
from alight.hw.realtime import WallClock
from alight.systems.boundary import CameraFrame
from alight.systems.params import bounded


class CameraError(RuntimeError):
    """A camera that cannot be opened."""


@dc.dataclass
class OpenCvCameraParams:
    device: str = ""       # "0" (an index), "/dev/video0", a GStreamer pipeline, a video file
    grayscale: bool = True  # the down camera's frames are grayscale (DESIGN.md)
    latency: float = bounded(0.03, 0.0, 1.0, "s")   # exposure to arrival
    period: float = bounded(0.005, 0.001, 1.0, "s")  # how often the port takes the newest frame


@dc.dataclass
class CameraCounters:
    captured: int = 0
    published: int = 0
    replaced: int = 0        # captured but superseded before the port took it
    wrong_size: int = 0
    read_failures: int = 0


class OpenCvCamera(LeafSystem):
    """Output `<name>` CameraFrame: the newest frame of the camera, stamped on the onboard clock
    (`clock`), with `calibration` (a dict as `Lens.calibration()`; None: uncalibrated)."""

    def __init__(self, name: str, params: OpenCvCameraParams, calibration: dict | None,
                 clock: WallClock):
        super().__init__()
        source = int(params.device) if params.device.isdigit() else params.device
        self._capture = cv2.VideoCapture(source)
        if not self._capture.isOpened():
            raise CameraError(f"cannot open camera '{params.device}' for {name}: no such device, "
                              f"file or pipeline (see cv2.VideoCapture)")
        fps = self._capture.get(cv2.CAP_PROP_FPS)
        frame_count = self._capture.get(cv2.CAP_PROP_FRAME_COUNT)
        # A file has a frame count and is read as fast as asked: play it at its frame rate.
        self._file_period = 1.0 / fps if frame_count > 0 and fps > 0 else 0.0
        self._params, self._calibration, self._clock, self._name = params, calibration, clock, name
        self._latest: CameraFrame | None = None
        self._lock = threading.Lock()
        self.counters = CameraCounters()
        self._running = True
        self._thread = threading.Thread(target=self._capture_loop, name=f"camera-{name}",
                                        daemon=True)
        self._thread.start()
        self._frame = self.DeclareAbstractState(AbstractValue.Make(CameraFrame()))
        self.DeclarePeriodicUnrestrictedUpdateEvent(params.period, 0.0, self._update)
        self.DeclareStateOutputPort(name, self._frame)

    def _capture_loop(self):
        next_frame = time.monotonic()
        while self._running:
            if self._file_period:
                time.sleep(max(0.0, next_frame - time.monotonic()))
                next_frame += self._file_period
            ok, image = self._capture.read()
            stamp = self._clock.now() - self._params.latency
            if not ok or image is None:
                self.counters.read_failures += 1
                if self._file_period:  # the end of a file
                    return
                time.sleep(0.01)
                continue
            if self._params.grayscale and image.ndim == 3:
                image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
            elif image.ndim == 3:
                image = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
            calibration = self._calibration
            if calibration is not None and (image.shape[1], image.shape[0]) != (
                    calibration["width"], calibration["height"]):
                self.counters.wrong_size += 1
                if self.counters.wrong_size == 1:
                    LOG.error("camera %s delivers %dx%d frames, calibrated for %dx%d: dropped",
                              self._name, image.shape[1], image.shape[0], calibration["width"],
                              calibration["height"])
                continue
            with self._lock:
                if self._latest is not None:
                    self.counters.replaced += 1
                self._latest = CameraFrame(stamp=stamp, image=np.ascontiguousarray(image),
                                           calibration=calibration)
                self.counters.captured += 1

    def _update(self, context, state):
        with self._lock:
            frame, self._latest = self._latest, None
        if frame is None or not math.isfinite(frame.stamp):
            return
        self.counters.published += 1
        state.get_mutable_abstract_state(self._frame).set_value(frame)

    def close(self):
        self._running = False
        self._thread.join(timeout=2.0)
        self._capture.release()
