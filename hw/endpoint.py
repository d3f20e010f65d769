"""One end of a MAVLink link: a pymavlink transport, a background reader that parses every byte
itself, counts what it must drop, and hands each valid message to the endpoint; a locked sender.

Both ends of alight's link build on it: the companion computer's `MavlinkLink` (hw/link.py) and
the simulated autopilot's endpoint (hw/sim_autopilot.py). Nothing the peer sends can stop the
reader: malformed frames (bad prefix, length or CRC, truncated), unknown message ids, frames from
other systems and frames whose sequence number goes back are counted and dropped; a handler that
finds unusable content (non-finite values, bad enums) counts it as rejected.

Where a UDP end sends is decided here, once for both ends: an end that dials (`udpout`) sends to
the connection string's address, always; an end that listens (`udpin`: the simulated autopilot,
or a companion bound to a port) has one peer, the source address of a valid frame: CRC good, a
known message, accepted by the end's `_accepts` (sender and target ids) and in sequence. The first
valid frame names the peer; another address takes over only after the peer has sent no valid
frame for `peer_timeout` (a restarted client on a new port). Random bytes, bad frames and frames
from other systems never move it (docs/hardware.md: what PX4 does).

Both MAVLink versions are read; an end answers in its peer's version as PX4 does with its default
MAV_PROTO_VER = 0 ("switch to 2 if 2 received"): a peer that has sent only MAVLink 1 frames gets
MAVLink 1 frames, a peer that has sent one valid MAVLink 2 frame gets MAVLink 2 from then on (until
another peer takes over). Before any valid frame an end speaks MAVLink 2. A message that MAVLink 1
cannot carry (id above 255) is not sent to a MAVLink 1 peer, and counted (`unsendable_v1`).
"""
import dataclasses as dc
import errno
import logging
import threading
import time

from pymavlink.dialects.v20 import common as mavlink

LOG = logging.getLogger("alight.hw")

# The reader resynchronizes a peer's sequence numbers after this long without a frame from it, or
# after this many frames in a row that look old (the peer restarted).
_SEQUENCE_RESET_GAP = 1.0  # s
_SEQUENCE_RESET_COUNT = 5


@dc.dataclass
class LinkCounters:
    """What the reader saw. `bytes_received` counts every byte; each frame lands in exactly one
    of messages, malformed, unknown, foreign, out_of_order; `rejected` counts handled messages
    whose content was unusable; `lost` counts gaps in the peer's sequence numbers."""
    bytes_received: int = 0
    messages: int = 0
    malformed: int = 0
    unknown: int = 0
    foreign: int = 0
    out_of_order: int = 0
    rejected: int = 0
    lost: int = 0
    sent: int = 0
    handler_errors: int = 0
    messages_v1: int = 0     # valid frames that came as MAVLink 1
    unsendable_v1: int = 0   # messages not sent: the peer speaks MAVLink 1, their id is > 255


class _SequenceTracker:
    """MAVLink packet sequence numbers (uint8) per source: gaps are lost frames; a frame whose
    number is not ahead of the last one (within half the range) is late or a duplicate."""

    def __init__(self):
        self._last: dict[tuple[int, int], tuple[int, float, int]] = {}

    def classify(self, source: tuple[int, int], seq: int, now: float) -> tuple[bool, int]:
        """(in order, frames lost before this one)."""
        if source not in self._last or now - self._last[source][1] > _SEQUENCE_RESET_GAP:
            self._last[source] = (seq, now, 0)
            return True, 0
        last, _, backwards = self._last[source]
        ahead = (seq - last) % 256
        if ahead == 0 or ahead >= 128:
            if backwards + 1 >= _SEQUENCE_RESET_COUNT:  # the peer restarted its numbering
                self._last[source] = (seq, now, 0)
                return True, 0
            self._last[source] = (last, now, backwards + 1)
            return False, 0
        self._last[source] = (seq, now, 0)
        return True, ahead - 1


class MavlinkEndpoint:
    """Base of both link ends. Subclasses implement `_accepts(msg)` (is this frame for us, from
    our peer?), `_handle(msg, now)` and `clock_ns()` (this end's clock for TIMESYNC).
    `peer_timeout` [s]: how long a listening UDP end keeps its peer without a valid frame from it
    before another address may take its place."""

    def __init__(self, transport, system_id: int, component_id: int, datagrams: bool,
                 peer_timeout: float):
        self._transport = transport
        self._datagrams = datagrams  # UDP: a frame never spans datagrams; resync per datagram
        # A UDP transport is read and written on its socket, so that each datagram's source is
        # known and only a valid frame picks the peer (pymavlink's udpin takes every sender).
        self._socket = getattr(transport, "port", None) if datagrams else None
        self._listening = self._socket is not None and bool(getattr(transport, "udp_server",
                                                                    False))
        self.peer: tuple | None = None  # where a listening UDP end sends; None: nowhere yet
        self.peer_version: int | None = None  # MAVLink version of the peer's frames; None: unheard
        self._peer_seen = -float("inf")  # time of the peer's last valid frame
        self._peer_timeout = peer_timeout
        self._send_lock = threading.Lock()
        self._encoder = mavlink.MAVLink(_Writer(self), system_id, component_id)
        self._parser = self._new_parser()
        self._sequences = _SequenceTracker()
        self._counter_lock = threading.Lock()
        self.counters = LinkCounters()
        self.system_id, self.component_id = system_id, component_id
        self._running = False
        self._reader: threading.Thread | None = None

    # --- lifecycle -------------------------------------------------------------------------
    def start(self):
        self._running = True
        self._reader = threading.Thread(target=self._read_loop, name="mavlink-reader", daemon=True)
        self._reader.start()
        return self

    def close(self):
        self._running = False
        if self._reader is not None and self._reader is not threading.current_thread():
            self._reader.join(timeout=2.0)
        try:
            self._transport.close()
        except OSError:
            pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # --- sending ---------------------------------------------------------------------------
    def send(self, message) -> None:
        """Sends `message` in the peer's MAVLink version (module docstring)."""
        mavlink1 = self.peer_version == 1
        with self._send_lock:
            if mavlink1 and message.id > 255:
                self.counters.unsendable_v1 += 1
                return
            self._encoder.send(message, force_mavlink1=mavlink1)
            self.counters.sent += 1

    @property
    def mav(self):
        """The encoder, for building messages: `endpoint.send(endpoint.mav.heartbeat_encode(...))`."""
        return self._encoder

    # --- receiving -------------------------------------------------------------------------
    def _read_loop(self):
        while self._running:
            try:
                if not self._transport.select(0.05):
                    continue
                data, source = self._receive()
            except (OSError, ValueError) as e:  # closed under us, device unplugged
                if self._running:
                    LOG.warning("MAVLink transport error: %s", e)
                    time.sleep(0.05)
                continue
            if data:
                self.feed(bytes(data) if not isinstance(data, bytes) else data, source=source)

    def _receive(self) -> tuple[bytes, tuple | None]:
        """What the transport holds: (one datagram and its source address) on UDP, (bytes, None)
        on a stream."""
        if self._socket is None:
            return self._transport.recv(4096), None
        try:
            return self._socket.recvfrom(65535)
        except OSError as e:
            if e.errno in (errno.EAGAIN, errno.EWOULDBLOCK, errno.ECONNREFUSED):
                return b"", None
            raise

    def feed(self, data: bytes, now: float | None = None, source: tuple | None = None) -> None:
        """Parses `data` (one datagram, or a piece of a byte stream) and handles what it holds;
        `source` is the datagram's sender (UDP), which a valid frame makes the peer of a
        listening end."""
        now = time.monotonic() if now is None else now
        with self._counter_lock:
            self.counters.bytes_received += len(data)
        try:
            messages = self._parser.parse_buffer(data) or []
        except Exception:  # the robust parser should not raise; never let it stop the reader
            messages = [None]
            self._parser = self._new_parser()
        if self._datagrams:
            if self._parser.buf_len() > 0:  # a frame cut short at the end of the datagram
                messages.append(None)
            self._parser = self._new_parser()
        for message in messages:
            self._dispatch(message, now, source)

    def _dispatch(self, message, now: float, source: tuple | None = None) -> None:
        counters = self.counters
        if message is None or message.get_type() == "BAD_DATA":
            with self._counter_lock:
                counters.malformed += 1
            return
        if message.get_type().startswith("UNKNOWN"):
            with self._counter_lock:
                counters.unknown += 1
            return
        header = message.get_header()
        if not self._accepts(message):
            with self._counter_lock:
                counters.foreign += 1
            return
        in_order, lost = self._sequences.classify((header.srcSystem, header.srcComponent),
                                                  header.seq, now)
        version = 1 if message.get_msgbuf()[0] == mavlink.PROTOCOL_MARKER_V1 else 2
        with self._counter_lock:
            counters.lost += lost
            if not in_order:
                counters.out_of_order += 1
                return
            counters.messages += 1
            counters.messages_v1 += version == 1
        from_peer = self._valid_frame_from(source, header, now, version) \
            if self._listening and source is not None else True
        if from_peer and self.peer_version != 2:  # 1 until the peer speaks 2 (MAV_PROTO_VER 0)
            with self._send_lock:
                self.peer_version = version
        try:
            if message.get_type() == "TIMESYNC":
                self._timesync(message, now)
            elif not self._handle(message, now):
                with self._counter_lock:
                    counters.rejected += 1
        except Exception:
            with self._counter_lock:
                counters.handler_errors += 1
                first = counters.handler_errors <= 3
            if first:
                LOG.exception("MAVLink handler failed on %s", message.get_type())

    def _valid_frame_from(self, source: tuple, header, now: float, version: int) -> bool:
        """The peer rule of a listening UDP end (module docstring); True when `source` is (now)
        the peer. A new peer and its version (that of the frame that made it the peer) change
        together under the send lock: no frame goes to it in another version in between."""
        if source == self.peer:
            self._peer_seen = now
        elif self.peer is None or now - self._peer_seen > self._peer_timeout:
            with self._send_lock:
                self.peer, self.peer_version, self._peer_seen = source, version, now
            LOG.info("MAVLink peer: %s:%d (system %d, component %d)", source[0], source[1],
                     header.srcSystem, header.srcComponent)
        else:
            return False
        return True

    def _timesync(self, message, now: float) -> None:
        """Answers a TIMESYNC request (tc1 = 0) with this end's clock (not while it has none:
        a simulated autopilot before its simulation starts); passes replies on."""
        if message.tc1 == 0:
            clock_ns = self.clock_ns()
            if clock_ns is not None:
                self.send(self._encoder.timesync_encode(clock_ns, message.ts1))
        else:
            self._timesync_reply(message, now)

    def _timesync_reply(self, message, now: float) -> None:
        """A reply to one of our TIMESYNC requests (the companion side uses it)."""

    def counters_snapshot(self) -> LinkCounters:
        with self._counter_lock:
            return dc.replace(self.counters)

    # --- subclass interface ----------------------------------------------------------------
    def _accepts(self, message) -> bool:
        raise NotImplementedError

    def _handle(self, message, now: float) -> bool:
        """Handles a valid message; False when its content was unusable (counted as rejected)."""
        raise NotImplementedError

    def clock_ns(self) -> int | None:
        """This end's clock [ns] for TIMESYNC answers; None: no clock yet."""
        raise NotImplementedError

    @staticmethod
    def _new_parser():
        parser = mavlink.MAVLink(None)
        parser.robust_parsing = True
        return parser


def addressed_to(message, system_id: int, component_id: int | None = None) -> bool:
    """False when the message names another target system (or component); broadcast (0) is ours."""
    target_system = getattr(message, "target_system", 0)
    if target_system not in (0, system_id):
        return False
    if component_id is not None:
        target_component = getattr(message, "target_component", 0)
        return target_component in (0, component_id)
    return True


class _Writer:
    """pymavlink's encoder writes to `file.write`: to the peer on a listening UDP end (nothing
    before a valid frame named it), else to the transport; a transport may reject writes when
    closed."""

    def __init__(self, endpoint: MavlinkEndpoint):
        self._endpoint = endpoint

    def write(self, buf):
        endpoint = self._endpoint
        try:
            if endpoint._listening:
                peer = endpoint.peer
                if peer is not None:
                    endpoint._socket.sendto(buf, peer)
            else:
                endpoint._transport.write(buf)
        except OSError:
            pass
