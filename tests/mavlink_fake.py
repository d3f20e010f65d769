"""Helpers of the MAVLink tests: a scripted PX4 stand-in (the real autopilot endpoint of
hw/sim_autopilot.py with hand-driven telemetry and scripted command answers instead of a simulated
vehicle), and `alight sim-autopilot` run as a separate process."""
import signal
import socket
import subprocess
import sys
import threading
import time

import pytest
from pymavlink.dialects.v10 import common as mavlink1
from pymavlink.dialects.v20 import common as mavlink

from alight.hw import px4
from alight.hw.sim_autopilot import AutopilotEndpoint, SimAutopilotParams, SimClock


# Every test that runs `alight sim-autopilot` (a real-time loop in its own process) carries this
# mark; conftest.py runs such tests one at a time across the xdist workers: two at once on a
# 2-core machine starve both autopilots (measured: 943 ms behind real time, a landing tipped
# over), and would judge the load instead of the code.
realtime = pytest.mark.realtime


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_for(condition, timeout: float, what: str) -> float:
    """Polls `condition` until it holds (returns the monotonic time it did) or raises an
    AssertionError naming `what` after `timeout` s of wall time."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return time.monotonic()
        time.sleep(0.01)
    raise AssertionError(f"not within {timeout} s: {what}")


class FakeAutopilot:
    """Answers COMMAND_LONG from `answers[command]` (a list used in order: a MAV_RESULT, or None
    for no answer at all; then ACCEPTED), applies accepted arm/mode/land commands to its own
    state, sends HEARTBEAT (10 Hz) and EXTENDED_SYS_STATE while `alive`, and records every
    SET_ATTITUDE_TARGET and COMMAND_LONG with its reception time."""

    def __init__(self, port: int | None = None):
        self.port = port or free_udp_port()
        self.clock = SimClock()
        self.start = time.monotonic()
        self.endpoint = AutopilotEndpoint.open(f"udpin:127.0.0.1:{self.port}",
                                               SimAutopilotParams(), self.clock)
        self.mav = self.endpoint.mav
        self.answers: dict[int, list] = {}
        self.texts: dict[int, str] = {}
        self.setpoints: list[tuple[float, object]] = []
        self.positions: list[tuple[float, object]] = []
        self.commands: list[tuple[float, object]] = []
        self.armed = False
        self.custom_mode = px4.HOLD
        self.landed_state = mavlink.MAV_LANDED_STATE_ON_GROUND
        self.alive = True
        self.last_sent = time.monotonic()
        self._running = True
        self._thread = threading.Thread(target=self._loop, daemon=True)
        self._thread.start()

    @property
    def url(self) -> str:
        return f"udp:127.0.0.1:{self.port}"

    def fc_time(self) -> float:
        return time.monotonic() - self.start

    def send(self, message) -> None:
        if self.alive:
            self.endpoint.send(message)
            self.last_sent = time.monotonic()

    def _loop(self):
        next_heartbeat = 0.0
        while self._running:
            now = time.monotonic()
            self.clock.tick(self.fc_time())
            while not self.endpoint.inbox.empty():
                self._handle(self.endpoint.inbox.get())
            if now >= next_heartbeat:
                base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED \
                    | (mavlink.MAV_MODE_FLAG_SAFETY_ARMED if self.armed else 0)
                self.send(self.mav.heartbeat_encode(mavlink.MAV_TYPE_HEXAROTOR,
                                                    mavlink.MAV_AUTOPILOT_PX4, base,
                                                    self.custom_mode, mavlink.MAV_STATE_STANDBY))
                self.send(self.mav.extended_sys_state_encode(0, self.landed_state))
                next_heartbeat = now + 0.1
            time.sleep(0.001)

    def _handle(self, message):
        now = time.monotonic()
        if message.get_type() == "SET_ATTITUDE_TARGET":
            self.setpoints.append((now, message))
            return
        if message.get_type() in ("ODOMETRY", "LANDING_TARGET"):
            self.positions.append((now, message))  # external vision, landing targets
            return
        self.commands.append((now, message))
        script = self.answers.get(message.command, [])
        result = script.pop(0) if script else mavlink.MAV_RESULT_ACCEPTED
        if result is None:
            return  # lost
        if result == mavlink.MAV_RESULT_ACCEPTED:
            if message.command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
                self.armed = message.param1 == 1.0
            elif message.command == mavlink.MAV_CMD_DO_SET_MODE:
                self.custom_mode = px4.custom_mode(int(message.param2), int(message.param3))
            elif message.command == mavlink.MAV_CMD_NAV_LAND:
                self.custom_mode = px4.LAND
        elif message.command in self.texts:
            self.send(self.mav.statustext_encode(mavlink.MAV_SEVERITY_CRITICAL,
                                                 self.texts[message.command].encode()))
        header = message.get_header()
        self.send(self.mav.command_ack_encode(message.command, result, 0, 0, header.srcSystem,
                                              header.srcComponent))

    def silence(self):
        """The autopilot goes away: nothing more is sent, not even TIMESYNC answers."""
        self.alive = False
        self.endpoint.close()
        self.silent_since = time.monotonic()

    def commands_named(self, command: int) -> list:
        return [m for _, m in self.commands if m.command == command]

    def close(self):
        self._running = False
        self._thread.join(timeout=2)
        if self.alive:
            self.endpoint.close()


class SimAutopilotProcess:
    """`alight sim-autopilot` in its own process on a free UDP port (or `port`), without the camera
    channel unless `frames` (then on the socket both sides derive from the port), with `args`
    added to its command line; `stop()` sends Ctrl-C (SIGINT) and waits for the run folder."""

    def __init__(self, run_dir, duration: float = 120.0, realtime_rate: float = 1.0,
                 ready_timeout: float = 60.0, port: int | None = None, frames: bool = False,
                 args: tuple[str, ...] = ()):
        self.port = port or free_udp_port()
        self.run_dir = run_dir
        self.stats = run_dir.parent / f"{run_dir.name}-stats.json"
        self.process = subprocess.Popen(
            [sys.executable, "-m", "alight.diagrams.cli", "sim-autopilot",
             "--listen", f"udp:127.0.0.1:{self.port}", "--duration", str(duration),
             *([] if frames else ["--frames", "none"]), "--run-dir", str(run_dir),
             "--stats", str(self.stats), "--realtime-rate", str(realtime_rate), *args],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        self.output: list[str] = []
        self._ready = threading.Event()
        threading.Thread(target=self._read, daemon=True).start()
        if not self._ready.wait(ready_timeout):
            self.stop()
            raise RuntimeError("sim-autopilot did not start:\n" + "".join(self.output))

    @property
    def url(self) -> str:
        return f"udp:127.0.0.1:{self.port}"

    def _read(self):
        for line in self.process.stdout:
            self.output.append(line)
            if line.startswith("sim-autopilot: ready"):
                self._ready.set()

    def stop(self, timeout: float = 60.0) -> int:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
        try:
            return self.process.wait(timeout)
        except subprocess.TimeoutExpired:
            self.process.kill()
            return self.process.wait()


class NullTransport:
    """A link transport that sends nowhere (tests that feed the reader directly)."""

    def write(self, buf):
        pass

    def close(self):
        pass


class FrameEncoder:
    """Encodes frames as a system/component would send them (its own sequence numbers), in
    MAVLink `version` 1 or 2 (pymavlink's own encoder of that version)."""

    def __init__(self, system: int, component: int, version: int = 2):
        self._data = bytearray()
        module = mavlink1 if version == 1 else mavlink
        self.mav = module.MAVLink(self, system, component)

    def write(self, buf):
        self._data += buf

    def frame(self, message) -> bytes:
        self._data = bytearray()
        self.mav.send(message)
        return bytes(self._data)


def lock_clock(link, autopilot: FrameEncoder, tc1_ns: int = 5_000_000_000) -> bytes:
    """One genuine TIMESYNC round trip fed to `link` (no transport); returns the reply's bytes."""
    ts1 = link.clock.scaled_ns()
    link.timesync.request(ts1)
    reply = autopilot.frame(autopilot.mav.timesync_encode(tc1_ns, ts1))
    link.feed(reply)
    assert link.timesync.locked
    return reply


class HilProcess:
    """`alight hil` in its own process, started before the simulated autopilot: it builds its
    mission and waits for the autopilot, so that the mission starts with the autopilot's world
    (the landing target drives from the autopilot's start)."""

    def __init__(self, port: int, args: tuple[str, ...], ready_timeout: float = 60.0):
        self.process = subprocess.Popen(
            [sys.executable, "-m", "alight.diagrams.cli", "hil", "--connect",
             f"udp:127.0.0.1:{port}", "--wait", "60", *args],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        self.output: list[str] = []
        self._ready = threading.Event()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()
        if not self._ready.wait(ready_timeout):
            self.process.kill()
            raise RuntimeError("alight hil did not start:\n" + "".join(self.output))

    def _read(self):
        for line in self.process.stdout:
            self.output.append(line)
            if "waiting for the autopilot" in line:
                self._ready.set()

    def wait(self, timeout: float) -> int:
        try:
            status = self.process.wait(timeout)
            self._reader.join(5.0)
            return status
        except subprocess.TimeoutExpired:
            self.process.send_signal(signal.SIGINT)
            self.process.wait(30)
            raise

    @property
    def text(self) -> str:
        return "".join(self.output)
