"""MAVLink connection strings -> pymavlink transports.

Accepted forms (`role` is "connect" for the companion computer, "listen" for an autopilot endpoint):

    udp:HOST:PORT       connect: send to HOST:PORT (udpout); listen: bind HOST:PORT (udpin)
    udpin:HOST:PORT     bind HOST:PORT and answer whoever sends (PX4 SITL's peer listens so)
    udpout:HOST:PORT    send to HOST:PORT, receive the replies on the same socket
    tcp:HOST:PORT       connect to a TCP server;  tcpin:HOST:PORT: accept one TCP client
    serial:DEVICE:BAUD  a serial port (Pixhawk USB /dev/ttyACM0 or TELEM2 UART /dev/ttyTHS1 ...)

pymavlink opens the port; alight reads raw bytes from it and parses them itself (hw/endpoint.py),
so that every malformed or unknown byte is counted.
"""
import re

_HOST_PORT = re.compile(r"^(?P<host>[^:\s]+):(?P<port>\d{1,5})$")
FORMS = "udp:HOST:PORT, udpin:HOST:PORT, udpout:HOST:PORT, tcp:HOST:PORT, tcpin:HOST:PORT, " \
        "serial:DEVICE:BAUD"


class MavlinkConnectionError(ValueError):
    """A connection string that cannot be used, or a port that cannot be opened."""


def parse_connection(url: str, role: str) -> tuple[str, dict]:
    """The pymavlink device string and keyword arguments for `url`."""
    if role not in ("connect", "listen"):
        raise ValueError(f"role must be 'connect' or 'listen', not {role!r}")
    scheme, _, rest = url.partition(":")
    if scheme == "serial":
        device, _, baud = rest.rpartition(":")
        if not device or not baud.isdigit() or int(baud) <= 0:
            raise MavlinkConnectionError(
                f"'{url}': a serial connection is serial:DEVICE:BAUD, e.g. "
                f"serial:/dev/ttyACM0:921600")
        return device, {"baud": int(baud)}
    if scheme not in ("udp", "udpin", "udpout", "tcp", "tcpin"):
        raise MavlinkConnectionError(f"'{url}': unknown connection type '{scheme}'; use {FORMS}")
    match = _HOST_PORT.match(rest)
    if match is None or not 0 < int(match["port"]) < 65536:
        raise MavlinkConnectionError(f"'{url}': expected {scheme}:HOST:PORT with a port in "
                                     f"1..65535")
    if scheme == "udp":
        scheme = "udpout" if role == "connect" else "udpin"
    return f"{scheme}:{rest}", {}


def open_connection(url: str, role: str):
    """Opens `url` as a pymavlink transport (a `mavutil.mavfile`: recv, write, select, close)."""
    device, options = parse_connection(url, role)
    from pymavlink import mavutil
    try:
        return mavutil.mavlink_connection(device, **options)
    except Exception as e:  # OSError (address in use, no such device), serial.SerialException
        raise MavlinkConnectionError(f"cannot open '{url}': {e}") from None
