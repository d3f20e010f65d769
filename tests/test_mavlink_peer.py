"""Where a listening UDP end sends (hw/endpoint.py, the peer rule): only a valid MAVLink frame from
a peer names the address that gets the telemetry; the peer keeps it while it talks, and another
address takes over only after `peer_timeout` of silence. First over loopback sockets against the
autopilot endpoint of `alight sim-autopilot`, then 3,000 fuzzed datagrams from eight addresses
into both ends (the simulated autopilot and a companion bound to a port)."""
import socket
import time

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from alight.hw.link import LinkParams, MavlinkLink
from alight.hw.realtime import WallClock
from alight.hw.sim_autopilot import AutopilotEndpoint, SimAutopilotParams, SimClock
from mavlink_fake import FakeAutopilot, FrameEncoder
from test_mavlink_fuzz import FrameFuzzer

PEER_TIMEOUT = SimAutopilotParams().peer_timeout
BAD = {"bit flips", "cut", "foreign", "unknown id", "random"}


def heartbeats_from_autopilot(sock, duration: float) -> list[float]:
    """Reception times of the autopilot's HEARTBEATs on `sock` during `duration`."""
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    times = []
    deadline = time.monotonic() + duration
    while (left := deadline - time.monotonic()) > 0:
        sock.settimeout(left)
        try:
            data, _ = sock.recvfrom(65535)
        except socket.timeout:
            break
        for message in parser.parse_buffer(data) or []:
            header = message.get_header()
            if message.get_type() == "HEARTBEAT" and (header.srcSystem, header.srcComponent) \
                    == (1, 1):
                times.append(time.monotonic())
    return times


def garbage(rng) -> list[bytes]:
    """Datagrams that must not name a peer: random bytes, a heartbeat with one bit flipped, a
    frame cut short, a frame with the autopilot's own ids, one from an unknown system addressed
    to another autopilot."""
    gcs = FrameEncoder(255, 190)
    heartbeat = gcs.frame(gcs.mav.heartbeat_encode(mavlink.MAV_TYPE_GCS,
                                                   mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0))
    flipped = bytearray(heartbeat)
    flipped[12] ^= 0x10
    own = FrameEncoder(1, 1)
    other = FrameEncoder(42, 1)
    return [rng.integers(0, 256, 60, dtype=np.uint8).tobytes(), bytes(flipped), heartbeat[:9],
            own.frame(own.mav.heartbeat_encode(mavlink.MAV_TYPE_HEXAROTOR,
                                               mavlink.MAV_AUTOPILOT_PX4, 0, 0, 0)),
            other.frame(other.mav.command_long_encode(2, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM,
                                                      0, 1, 0, 0, 0, 0, 0, 0))]


def test_garbage_from_a_third_socket_does_not_take_the_telemetry_and_a_valid_peer_does():
    autopilot = FakeAutopilot()  # the sim-autopilot's endpoint on udpin, HEARTBEAT at 10 Hz
    link = MavlinkLink.open(autopilot.url, LinkParams(), WallClock())
    stranger = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    stranger.bind(("127.0.0.1", 0))
    address = ("127.0.0.1", autopilot.port)
    try:
        link.wait_for_autopilot(5.0)
        before = autopilot.endpoint.counters_snapshot()
        for datagram in garbage(np.random.default_rng(0)) * 20:
            stranger.sendto(datagram, address)
        # The client keeps its heartbeats (10 Hz), the stranger gets nothing.
        assert heartbeats_from_autopilot(stranger, 1.0) == []
        assert time.monotonic() - link.state().heartbeat_time < 0.25 and link.link_alive()
        after = autopilot.endpoint.counters_snapshot()
        assert after.malformed - before.malformed >= 60  # random, flipped, cut: every one seen
        assert after.foreign - before.foreign >= 40      # own ids, other system
        # A valid frame from a ground station while the client talks: one peer, as on PX4.
        gcs = FrameEncoder(255, 190)

        def gcs_heartbeat():
            stranger.sendto(gcs.frame(gcs.mav.heartbeat_encode(
                mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)), address)
        gcs_heartbeat()
        assert heartbeats_from_autopilot(stranger, 0.5) == []
        assert time.monotonic() - link.state().heartbeat_time < 0.25
        # The client goes away: the ground station's next valid frame after the peer timeout
        # takes the telemetry.
        link.close()
        closed = time.monotonic()
        received = []
        while not received and time.monotonic() < closed + PEER_TIMEOUT + 2.0:
            gcs_heartbeat()
            received = heartbeats_from_autopilot(stranger, 0.25)
        assert received, "the new peer never got the telemetry"
        assert PEER_TIMEOUT - 0.3 < received[0] - closed < PEER_TIMEOUT + 0.8
        assert len(heartbeats_from_autopilot(stranger, 0.5)) >= 4  # and keeps it, at 10 Hz
        assert autopilot.endpoint.peer == stranger.getsockname()
    finally:
        link.close()
        stranger.close()
        autopilot.close()


class RecordingSocket:
    """A bound UDP socket as the endpoint uses it: records where each datagram goes."""

    def __init__(self):
        self.sent: list[tuple] = []

    def sendto(self, buf, address):
        self.sent.append(address)


class ListeningTransport:
    """pymavlink's `udpin` transport as the endpoint sees it (`port`, `udp_server`)."""
    udp_server = True

    def __init__(self):
        self.port = RecordingSocket()

    def close(self):
        pass


def autopilot_end():
    """The simulated autopilot: its peer's frames come from a companion (1, 191); frames with
    its own ids (1, 1) are foreign."""
    endpoint = AutopilotEndpoint(ListeningTransport(), SimAutopilotParams(), SimClock(),
                                 datagrams=True)
    fuzzer = FrameFuzzer(seed=5)
    fuzzer.autopilot, fuzzer.stranger = FrameEncoder(1, 191), FrameEncoder(1, 1)
    return endpoint, fuzzer, SimAutopilotParams().peer_timeout


def companion_end():
    """The companion bound to a port (`udpin`): its peer is the autopilot (1, 1)."""
    params = LinkParams()
    link = MavlinkLink(ListeningTransport(), params, WallClock(), datagrams=True)
    return link, FrameFuzzer(seed=6), params.heartbeat_timeout


@pytest.mark.parametrize("make_end", [autopilot_end, companion_end], ids=["autopilot",
                                                                         "companion"])
def test_fuzzed_datagrams_from_eight_addresses_move_the_peer_only_by_the_rule(make_end):
    endpoint, fuzzer, peer_timeout = make_end()
    rng = fuzzer.rng
    sources = [(f"10.0.0.{k}", 14550 + k) for k in range(8)]
    sent = endpoint._transport.port.sent
    endpoint.send(endpoint.mav.heartbeat_encode(0, 0, 0, 0, 0))
    assert sent == []  # no valid frame yet: nowhere to send
    peer, peer_seen, now = None, -np.inf, 0.0
    changes = kept = bad_only = 0
    for _ in range(3000):
        now += 0.01 + (rng.uniform(0.0, 2.0 * peer_timeout) if rng.random() < 0.03 else 0.0)
        source = sources[int(rng.integers(0, len(sources)))]
        kinds_before = dict(fuzzer.kinds)
        data = b"".join(fuzzer.frame() for _ in range(int(rng.integers(1, 4))))
        kinds = {kind for kind, n in fuzzer.kinds.items() if n > kinds_before.get(kind, 0)}
        messages = endpoint.counters_snapshot().messages
        endpoint.feed(data, now=now, source=source)
        accepted = endpoint.counters_snapshot().messages > messages
        if kinds <= BAD:
            bad_only += 1
            assert not accepted and endpoint.peer == peer, kinds
        # The rule, written out: the first valid frame names the peer; the peer's frames keep
        # it; another address takes over after peer_timeout without a valid frame from it.
        if accepted and source == peer:
            peer_seen = now
        elif accepted and (peer is None or now - peer_seen > peer_timeout):
            peer, peer_seen = source, now
            changes += 1
        elif accepted:
            kept += 1
        assert endpoint.peer == peer
        endpoint.send(endpoint.mav.heartbeat_encode(0, 0, 0, 0, 0))
        assert sent[-1] == peer  # everything it sends goes to the peer
    assert bad_only > 500 and changes >= 10 and kept > 300
