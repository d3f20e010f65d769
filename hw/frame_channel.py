"""A local channel for camera frames between processes: camera images do not travel over MAVLink.

The simulated autopilot publishes its cameras' `CameraFrame`s (whatever fields the camera ports
hold) and the MAVLink vehicle's camera ports read them. It also carries the simulated world's
motion-capture estimate (`EstimateSample`, name "mocap"), as a mocap system streams poses to the
companion computer beside the flight controller's link (hw/channel_odometry.py reads it). Items are
pickled by `multiprocessing.connection` over a Unix socket after its HMAC authkey handshake, so only
processes that know the key can connect; it is a same-machine channel, not a network protocol. Only
the newest item per name is kept: a slow reader gets fewer (counted), never old ones.
"""
import dataclasses as dc
import logging
import os
import socket
import tempfile
import threading
from multiprocessing.connection import Client, Listener

import numpy as np

from alight.systems.boundary import STATE_ESTIMATE, CameraFrame

LOG = logging.getLogger("alight.hw")
DEFAULT_AUTHKEY = b"alight-camera-frames"


@dc.dataclass
class EstimateSample:
    """A STATE_ESTIMATE vector from an odometry source of the simulated world (its mocap), stamped
    on the autopilot's clock."""
    value: np.ndarray

    @property
    def stamp(self) -> float:
        return float(STATE_ESTIMATE.get(self.value, "stamp"))

    @property
    def valid(self) -> bool:
        """Of the right size, finite, and flagged valid by its source."""
        value = self.value
        return isinstance(value, np.ndarray) and value.shape == (STATE_ESTIMATE.size,) \
            and bool(np.all(np.isfinite(value))) and STATE_ESTIMATE.get(value, "valid") > 0.5


CHANNEL_ITEMS = (CameraFrame, EstimateSample)


def default_frame_address(name: str) -> str:
    """A per-link socket path, e.g. from the MAVLink port: default_frame_address("14540")."""
    safe = "".join(c if c.isalnum() else "_" for c in str(name))
    return os.path.join(tempfile.gettempdir(), f"alight-frames-{safe}.sock")


@dc.dataclass
class ChannelCounters:
    published: int = 0  # frames handed to the publisher
    sent: int = 0       # frames that reached a subscriber
    replaced: int = 0   # frames superseded by a newer one before they could be sent
    received: int = 0   # frames a subscriber got
    invalid: int = 0    # objects that were not (name, CameraFrame or valid EstimateSample)


class FramePublisher:
    """Serves the newest item (CameraFrame, EstimateSample) of each name to the one connected
    subscriber."""

    def __init__(self, address: str, authkey: bytes = DEFAULT_AUTHKEY):
        if os.path.exists(address):
            os.unlink(address)  # a socket left by a previous run
        self.address = address
        self._listener = Listener(address, family="AF_UNIX", authkey=authkey)
        os.chmod(address, 0o600)
        self._pending: dict[str, CameraFrame] = {}
        self._condition = threading.Condition()
        self._connection = None
        self._running = True
        self.counters = ChannelCounters()
        threading.Thread(target=self._accept_loop, name="frames-accept", daemon=True).start()
        threading.Thread(target=self._send_loop, name="frames-send", daemon=True).start()

    def publish(self, camera: str, frame: CameraFrame | EstimateSample) -> None:
        with self._condition:
            self.counters.published += 1
            if camera in self._pending:
                self.counters.replaced += 1
            if self._connection is not None:
                self._pending[camera] = frame
                self._condition.notify_all()

    @property
    def connected(self) -> bool:
        return self._connection is not None

    def _accept_loop(self):
        while self._running:
            try:
                connection = self._listener.accept()
            except Exception as e:  # closed, or a client that failed the handshake
                if self._running:
                    LOG.warning("frame channel: refused a subscriber: %s", e)
                    continue
                return
            with self._condition:
                if self._connection is not None:
                    self._connection.close()
                self._connection = connection
                self._condition.notify_all()

    def _send_loop(self):
        while self._running:
            with self._condition:
                while self._running and (not self._pending or self._connection is None):
                    self._condition.wait(0.5)
                if not self._running:
                    return
                items, self._pending = list(self._pending.items()), {}
                connection = self._connection
            for camera, frame in items:
                try:
                    connection.send((camera, frame))
                    self.counters.sent += 1
                except (OSError, ValueError):  # the subscriber went away
                    with self._condition:
                        if self._connection is connection:
                            self._connection = None
                    break

    def close(self):
        self._running = False
        with self._condition:
            if self._connection is not None:
                self._connection.close()
            self._condition.notify_all()
        try:  # wake the accept loop: this knock fails the handshake and the loop sees the stop
            with socket.socket(socket.AF_UNIX) as knock:
                knock.connect(self.address)
        except OSError:
            pass
        self._listener.close()
        if os.path.exists(self.address):
            os.unlink(self.address)


class FrameSubscriber:
    """Connects to a publisher (retrying until it exists) and keeps the newest item per name."""

    def __init__(self, address: str, authkey: bytes = DEFAULT_AUTHKEY, retry: float = 0.2):
        self.address = address
        self._authkey = authkey
        self._retry = retry
        self._latest: dict[str, CameraFrame] = {}
        self._lock = threading.Lock()
        self._running = True
        self._connection = None
        self.counters = ChannelCounters()
        self._thread = threading.Thread(target=self._receive_loop, name="frames-receive",
                                        daemon=True)
        self._thread.start()

    def latest(self, camera: str) -> CameraFrame | EstimateSample | None:
        with self._lock:
            return self._latest.get(camera)

    @property
    def connected(self) -> bool:
        return self._connection is not None

    def _receive_loop(self):
        stop = threading.Event()
        while self._running:
            try:
                self._connection = Client(self.address, family="AF_UNIX", authkey=self._authkey)
            except (OSError, EOFError):
                stop.wait(self._retry)
                continue
            except Exception as e:  # a wrong authkey
                LOG.error("frame channel %s: %s", self.address, e)
                stop.wait(self._retry)
                continue
            try:
                while self._running:
                    if not self._connection.poll(0.2):
                        continue
                    item = self._connection.recv()
                    if not _well_formed(item):
                        self.counters.invalid += 1
                        continue
                    with self._lock:
                        self._latest[item[0]] = item[1]
                    self.counters.received += 1
            except (OSError, EOFError):
                pass
            except Exception as e:  # unpicklable data
                self.counters.invalid += 1
                LOG.warning("frame channel %s: dropped a bad message: %s", self.address, e)
            finally:
                connection, self._connection = self._connection, None
                if connection is not None:
                    connection.close()

    def close(self):
        """Stops the receiving thread, which closes the connection itself within one poll
        (0.2 s): closing it from here too raced with the thread's own close (EBADF in the
        thread, measured in tests/test_mavlink_mission.py)."""
        self._running = False
        self._thread.join(timeout=2.0)
        if self._thread.is_alive():
            LOG.warning("frame channel %s: the receiving thread did not stop within 2 s",
                        self.address)


def _well_formed(item) -> bool:
    """(name, CameraFrame) or (name, EstimateSample) with a valid estimate."""
    return isinstance(item, tuple) and len(item) == 2 and isinstance(item[0], str) \
        and isinstance(item[1], CHANNEL_ITEMS) \
        and (not isinstance(item[1], EstimateSample) or item[1].valid)
