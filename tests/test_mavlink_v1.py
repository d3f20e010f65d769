"""MAVLink 1 peers (pymavlink's default without MAVLINK20, many scripts and older tools): both ends
read MAVLink 1 and 2 frames and answer in the peer's version, as PX4 with its default
MAV_PROTO_VER = 0 (MAVLink 1 until the peer speaks 2). The companion link against frames fed to it;
the autopilot endpoint against pymavlink clients of each version; `alight sim-autopilot` arming
for a MAVLink 1 client and disarming for the same client once it speaks MAVLink 2."""
import threading
import time

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v10 import common as mavlink1
from pymavlink.dialects.v20 import common as mavlink

from alight.hw.link import LinkParams, MavlinkLink
from alight.hw.realtime import WallClock
from mavlink_fake import FakeAutopilot, FrameEncoder, SimAutopilotProcess, realtime

ARM = mavlink.MAV_CMD_COMPONENT_ARM_DISARM
MAGIC = {1: mavlink.PROTOCOL_MARKER_V1, 2: mavlink.PROTOCOL_MARKER_V2}


class Capture:
    """A stream transport that keeps what the link writes."""

    def __init__(self):
        self.frames: list[bytes] = []

    def write(self, buf):
        self.frames.append(bytes(buf))

    def close(self):
        pass


def test_the_companion_link_answers_a_mavlink1_autopilot_in_mavlink1_until_it_speaks_2():
    transport = Capture()
    link = MavlinkLink(transport, LinkParams(command_timeout=2.0), WallClock(), datagrams=False)
    heartbeat = link.mav.heartbeat_encode(mavlink.MAV_TYPE_ONBOARD_CONTROLLER,
                                          mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
    link.send(heartbeat)
    assert transport.frames[-1][0] == MAGIC[2]  # unheard peer: MAVLink 2
    old = FrameEncoder(1, 1, version=1)
    link.feed(old.frame(old.mav.heartbeat_encode(mavlink.MAV_TYPE_HEXAROTOR,
                                                 mavlink.MAV_AUTOPILOT_PX4, 0, 0, 0)))
    assert link.state().heartbeat_time > -float("inf") and link.peer_version == 1
    results = []
    waiter = threading.Thread(target=lambda: results.append(link.command(ARM, 1.0)))
    waiter.start()
    deadline = time.monotonic() + 2.0
    while not any(f[5:6] == bytes([mavlink.MAVLINK_MSG_ID_COMMAND_LONG]) for f in
                  transport.frames) and time.monotonic() < deadline:
        time.sleep(0.005)
    sent = transport.frames[-1]
    assert sent[0] == MAGIC[1]
    parsed = mavlink1.MAVLink(None).parse_buffer(sent)  # a MAVLink 1-only parser reads it
    assert [m.get_type() for m in parsed] == ["COMMAND_LONG"] and parsed[0].command == ARM
    link.feed(old.frame(old.mav.command_ack_encode(ARM, mavlink.MAV_RESULT_ACCEPTED)))
    waiter.join(3.0)
    assert results == [mavlink.MAV_RESULT_ACCEPTED]
    # ODOMETRY (id 331) has no MAVLink 1 form: not sent, counted
    sent_before = len(transport.frames)
    link.send(link.mav.odometry_encode(0, 1, 8, 0, 0, 0, [1, 0, 0, 0], 0, 0, 0, 0, 0, 0,
                                       [float("nan")] * 21, [float("nan")] * 21))
    assert len(transport.frames) == sent_before and link.counters.unsendable_v1 == 1
    new = FrameEncoder(1, 1, version=2)
    new.mav.seq = old.mav.seq  # the same autopilot: one sequence
    link.feed(new.frame(new.mav.heartbeat_encode(mavlink.MAV_TYPE_HEXAROTOR,
                                                 mavlink.MAV_AUTOPILOT_PX4, 0, 0, 0)))
    link.send(heartbeat)
    assert transport.frames[-1][0] == MAGIC[2] and link.peer_version == 2
    old.mav.seq = new.mav.seq
    link.feed(old.frame(old.mav.heartbeat_encode(mavlink.MAV_TYPE_HEXAROTOR,
                                                 mavlink.MAV_AUTOPILOT_PX4, 0, 0, 0)))
    assert link.peer_version == 2  # once 2, always 2 (PX4 never switches back)
    counters = link.counters_snapshot()
    assert counters.messages == 4 and counters.messages_v1 == 3 and counters.malformed == 0


@pytest.fixture
def pymavlink_client(monkeypatch):
    """A factory of pymavlink clients (mavutil, dialect common) of MAVLink version 1 or 2, chosen
    as pymavlink users do, by the MAVLINK20 environment variable; mavutil's global dialect is
    restored afterwards."""
    saved = mavutil.mavlink, mavutil.current_dialect
    clients = []

    def make(version: int, url: str):
        if version == 2:
            monkeypatch.setenv("MAVLINK20", "1")
        else:
            monkeypatch.delenv("MAVLINK20", raising=False)
        client = mavutil.mavlink_connection(url.replace("udp:", "udpout:"), dialect="common",
                                            source_system=255, source_component=190)
        clients.append(client)
        return client

    yield make
    for client in clients:
        client.close()
    mavutil.mavlink, mavutil.current_dialect = saved


def wait_message(client, kind: str, timeout: float = 5.0, condition=lambda m: True):
    deadline = time.monotonic() + timeout
    while (left := deadline - time.monotonic()) > 0:
        message = client.recv_match(type=kind, blocking=True, timeout=left)
        if message is not None and condition(message):
            return message
    raise AssertionError(f"no {kind} within {timeout} s")


@pytest.mark.parametrize("version", [1, 2])
def test_the_autopilot_endpoint_acknowledges_a_command_in_the_clients_version(
        version, pymavlink_client):
    autopilot = FakeAutopilot()
    try:
        client = pymavlink_client(version, autopilot.url)
        assert client.WIRE_PROTOCOL_VERSION == f"{version}.0"
        client.mav.heartbeat_send(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        client.mav.command_long_send(1, 1, ARM, 0, 1, 0, 0, 0, 0, 0, 0)
        ack = wait_message(client, "COMMAND_ACK")
        assert ack.command == ARM and ack.result == mavlink.MAV_RESULT_ACCEPTED
        assert ack.get_msgbuf()[0] == MAGIC[version]
        assert autopilot.armed  # acted on
        wait_message(client, "HEARTBEAT", condition=lambda m: m.base_mode
                     & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
        counters = autopilot.endpoint.counters_snapshot()
        assert counters.messages_v1 == (counters.messages if version == 1 else 0)
        assert counters.malformed == 0 and counters.messages >= 2
    finally:
        autopilot.close()


@realtime
def test_sim_autopilot_arms_for_a_mavlink1_client_and_disarms_once_it_speaks_2(
        tmp_path, pymavlink_client):
    server = SimAutopilotProcess(tmp_path / "sim-autopilot", duration=60.0)
    try:
        old = pymavlink_client(1, server.url)
        old.mav.heartbeat_send(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        wait_message(old, "HEARTBEAT", 10.0)
        old.mav.command_long_send(1, 1, ARM, 0, 1, 0, 0, 0, 0, 0, 0)
        ack = wait_message(old, "COMMAND_ACK", 10.0)
        assert ack.result == mavlink.MAV_RESULT_ACCEPTED and ack.get_msgbuf()[0] == MAGIC[1]
        armed = wait_message(old, "HEARTBEAT", 5.0, lambda m: m.base_mode
                             & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
        assert armed.get_msgbuf()[0] == MAGIC[1]
        assert armed.base_mode & mavlink.MAV_MODE_FLAG_HIL_ENABLED  # says it is simulated
        # A ground station's AUTOPILOT_VERSION request, the old command and the new one
        for command, param1 in ((mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, 1),
                                (mavlink.MAV_CMD_REQUEST_MESSAGE,
                                 mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION)):
            old.mav.command_long_send(1, 1, command, 0, param1, 0, 0, 0, 0, 0, 0)
            version = wait_message(old, "AUTOPILOT_VERSION", 10.0)
            assert version.capabilities & mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
            assert version.capabilities & mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
        # The same socket, now speaking MAVLink 2 (pymavlink switches its encoder so)
        old.mav.WIRE_PROTOCOL_VERSION = "2.0"
        new = mavlink.MAVLink(old, 255, 190, use_native=False)
        new.seq = old.mav.seq
        new.send(new.command_long_encode(1, 1, ARM, 0, 0, 0, 0, 0, 0, 0, 0))
        old.mav = new  # parse MAVLink 2 frames from now on
        ack = wait_message(old, "COMMAND_ACK", 10.0, lambda m: m.get_msgbuf()[0] == MAGIC[2])
        assert ack.command == ARM and ack.result == mavlink.MAV_RESULT_ACCEPTED
        wait_message(old, "HEARTBEAT", 5.0, lambda m: not m.base_mode
                     & mavlink.MAV_MODE_FLAG_SAFETY_ARMED and m.get_msgbuf()[0] == MAGIC[2])
    finally:
        assert server.stop() == 0, "".join(server.output)
