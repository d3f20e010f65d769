"""Fuzzing the companion link's reader: 12,000 random and mutated MAVLink frames (bit flips, cuts,
random bytes, unknown ids, foreign senders, replays, well-formed frames carrying NaN, infinities and
absurd values) go through `MavlinkLink.feed` while the MAVLink vehicle diagram runs on that link.
Nothing may raise, no handler may fail, no NaN or infinity may reach a port, and every dropped
frame must be counted where a user sees it (`link_status`)."""
import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder, LeafSystem
from pymavlink.dialects.v20 import common as mavlink

from alight.hw.link import LinkParams, MavlinkLink
from alight.hw.mavlink_vehicle import LINK_STATUS, MavlinkVehicleParams, make_mavlink_vehicle
from alight.hw.realtime import WallClock
from alight.systems.boundary import FC_COMMAND
from mavlink_fake import FrameEncoder, NullTransport, lock_clock

DATAGRAMS = 3000   # of 1-7 frames each: 12,000 frames on average
SPECIALS = [0.0, np.nan, np.inf, -np.inf, 1e30, -1e30, 1e-40]


class FrameFuzzer:
    """Random telemetry as PX4 would send it, with random values, then mutated."""

    def __init__(self, seed):
        self.rng = np.random.default_rng(seed)
        self.autopilot = FrameEncoder(1, 1)
        self.stranger = FrameEncoder(7, 1)
        self.history: list[bytes] = []
        self.kinds: dict[str, int] = {}
        self.t_us = 0

    def bytes(self, low, high) -> bytes:
        return self.rng.integers(0, 256, size=int(self.rng.integers(low, high)),
                                 dtype=np.uint8).tobytes()

    def value(self, scale=1.0):
        if self.rng.random() < 0.15:
            return float(self.rng.choice(SPECIALS))
        return float(self.rng.normal() * scale)

    def message(self, mav):
        r = self.rng.integers(0, 9)
        self.t_us += int(self.rng.integers(-2000, 8000))  # mostly forward, sometimes back
        if r == 0:
            return mav.highres_imu_encode(max(self.t_us, 0), *[self.value(10) for _ in range(6)],
                                          *[self.value() for _ in range(7)],
                                          int(self.rng.choice([0b111111, 0, 0xFFFF,
                                                               self.rng.integers(0, 65536)])))
        if r == 1:
            q = [self.value() for _ in range(4)]
            return mav.attitude_quaternion_encode(max(self.t_us // 1000, 0), *q,
                                                  *[self.value() for _ in range(3)])
        if r == 2:
            return mav.heartbeat_encode(int(self.rng.integers(0, 40)),
                                        int(self.rng.choice([mavlink.MAV_AUTOPILOT_PX4, 8,
                                                             self.rng.integers(0, 20)])),
                                        int(self.rng.integers(0, 256)),
                                        int(self.rng.integers(0, 2**32)),
                                        int(self.rng.integers(0, 9)))
        if r == 3:
            return mav.extended_sys_state_encode(int(self.rng.integers(0, 5)),
                                                 int(self.rng.integers(0, 256)))
        if r == 4:
            return mav.command_ack_encode(int(self.rng.integers(0, 65536)),
                                          int(self.rng.integers(0, 256)), 0, 0, 1, 191)
        if r == 5:
            text = self.bytes(0, 50)
            return mav.statustext_encode(int(self.rng.integers(0, 256)), text)
        if r == 6:
            return mav.timesync_encode(int(self.rng.integers(-2**62, 2**62)),
                                       int(self.rng.integers(-2**62, 2**62)))
        if r == 7:
            return mav.scaled_imu_encode(max(self.t_us // 1000, 0),
                                         *[int(self.rng.integers(-32768, 32768)) for _ in range(9)],
                                         0)
        return mav.sys_status_encode(*[0] * 3, 500, 12000, -1, 90, *[0] * 6)

    def frame(self) -> bytes:
        """One frame: valid (40 %), mutated, foreign, unknown, replayed or random bytes."""
        r = self.rng.random()
        if r < 0.40:
            kind, data = "valid", self.autopilot.frame(self.message(self.autopilot.mav))
        elif r < 0.55:
            kind, data = "bit flips", self._flip(self.autopilot.frame(self.message(
                self.autopilot.mav)))
        elif r < 0.65:
            frame = self.autopilot.frame(self.message(self.autopilot.mav))
            kind, data = "cut", frame[:int(self.rng.integers(1, len(frame)))]
        elif r < 0.72:
            kind, data = "foreign", self.stranger.frame(self.message(self.stranger.mav))
        elif r < 0.80:
            kind, data = "unknown id", self._unknown()
        elif r < 0.90 and self.history:
            kind, data = "replay", self.history[int(self.rng.integers(0, len(self.history)))]
        else:
            kind, data = "random", self.bytes(1, 300)
        self.kinds[kind] = self.kinds.get(kind, 0) + 1
        if kind == "valid":
            self.history = (self.history + [data])[-50:]
        return data

    def _flip(self, frame: bytes) -> bytes:
        data = bytearray(frame)
        for _ in range(int(self.rng.integers(1, 4))):
            data[int(self.rng.integers(0, len(data)))] ^= 1 << int(self.rng.integers(0, 8))
        return bytes(data)

    def _unknown(self) -> bytes:
        """A MAVLink 2 frame with a message id that the common dialect does not define."""
        payload = self.bytes(1, 40)
        msgid = int(self.rng.integers(60000, 2**24))
        header = bytes([0xFD, len(payload), 0, 0, int(self.rng.integers(0, 256)), 1, 1,
                        msgid & 0xFF, (msgid >> 8) & 0xFF, msgid >> 16])
        return header + payload + self.bytes(2, 3)


class FreshCommand(LeafSystem):
    """Output `fc_command`: hover attitude, 20 % thrust, stamped with the current time."""

    def __init__(self):
        super().__init__()
        self.DeclareVectorOutputPort("fc_command", FC_COMMAND.size, lambda c, o: o.SetFromVector(
            FC_COMMAND.pack(stamp=c.get_time(), mode=1, q_WD=[1, 0, 0, 0], w_D=np.zeros(3),
                            thrust=0.2, arm=0.0)))


def fuzz(datagrams: bool, seed: int):
    link = MavlinkLink(NullTransport(), LinkParams(), WallClock(), datagrams=datagrams)
    builder = DiagramBuilder()
    vehicle = builder.AddNamedSystem("vehicle", make_mavlink_vehicle(link,
                                                                     MavlinkVehicleParams()))
    command = builder.AddSystem(FreshCommand())
    builder.Connect(command.get_output_port(), vehicle.GetInputPort("fc_command"))
    diagram = builder.Build()
    simulator = Simulator(diagram)
    context = simulator.get_mutable_context()
    vehicle_context = vehicle.GetMyContextFromRoot(context)
    # Lock the clock with one genuine TIMESYNC round trip, as on a real link.
    fuzzer = FrameFuzzer(seed)
    sync = lock_clock(link, fuzzer.autopilot)
    fed = len(sync)
    frames = 0
    non_finite = []
    for k in range(DATAGRAMS):
        count = int(fuzzer.rng.integers(1, 8))
        data = b"".join(fuzzer.frame() for _ in range(count))
        frames += count
        fed += len(data)
        if datagrams:
            link.feed(data)
        else:  # a serial byte stream: cut anywhere
            cut = int(fuzzer.rng.integers(0, len(data) + 1))
            link.feed(data[:cut])
            link.feed(data[cut:])
        simulator.AdvanceTo(0.002 * (k + 1))
        for name in ("fc_attitude", "fc_status", "link_status"):
            value = vehicle.GetOutputPort(name).Eval(vehicle_context)
            if not np.all(np.isfinite(value)):
                non_finite.append((k, name, value))
        imu = vehicle.GetOutputPort("imu").Eval(vehicle_context)
        if not (np.all(np.isfinite(imu.t)) and np.all(np.isfinite(imu.accel))
                and np.all(np.isfinite(imu.gyro))):
            non_finite.append((k, "imu", imu))
    status = vehicle.GetOutputPort("link_status").Eval(vehicle_context)
    return link, fuzzer, frames, fed, non_finite, status, vehicle, vehicle_context


@pytest.mark.parametrize("datagrams", [True, False], ids=["udp", "serial"])
def test_ten_thousand_fuzzed_frames_crash_nothing_and_put_no_nan_on_a_port(datagrams):
    link, fuzzer, frames, fed, non_finite, status, vehicle, context = fuzz(datagrams, seed=11)
    counters = link.counters_snapshot()
    assert frames >= 10_000
    assert non_finite == []
    assert counters.handler_errors == 0  # no handler raised on any content
    assert counters.bytes_received == fed  # every byte went through the parser
    # Every kind of bad input was seen and counted.
    assert counters.malformed > 0.1 * fuzzer.kinds["bit flips"]
    assert counters.unknown > 0.5 * fuzzer.kinds["unknown id"]
    assert counters.foreign > 0.5 * fuzzer.kinds["foreign"]
    assert counters.out_of_order > 0.3 * fuzzer.kinds["replay"]
    assert counters.rejected > 0.05 * fuzzer.kinds["valid"]  # NaN/absurd content refused
    assert 0.5 * fuzzer.kinds["valid"] < counters.messages <= frames
    # ...and shown on the diagnostics port as on the link.
    for field in ("malformed", "unknown", "foreign", "out_of_order", "rejected", "messages"):
        assert LINK_STATUS.get(status, field) == pytest.approx(getattr(counters, field), rel=0.05)
    # What did get through is sane: a unit attitude quaternion, bounded IMU values.
    attitude = vehicle.GetOutputPort("fc_attitude").Eval(context)
    assert np.linalg.norm(attitude[1:5]) == pytest.approx(1.0, abs=1e-9)
    imu = vehicle.GetOutputPort("imu").Eval(context)
    assert len(imu) > 0 and np.all(np.diff(imu.t) > 0) and np.all(np.diff(imu.seq) == 1)
    assert np.max(np.abs(imu.accel)) < 2000 and np.max(np.abs(imu.gyro)) < 200
