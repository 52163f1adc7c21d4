"""Connection strings as MAVProxy and pymavlink users type them.

udpin:0.0.0.0:14550     listen for UDP; replies go to the last sender
udpout:HOST:PORT        send UDP to HOST:PORT; replies come back on the same socket
tcp:HOST:PORT           dial a TCP server (SITL, a telemetry bridge)
tcpin:0.0.0.0:5760      listen for one TCP client
/dev/ttyUSB0            a serial device (baud rate given separately)
flight.tlog             a telemetry log replayed as if it were live
ascii:ADDRESS           any of the above carrying plain-text attitude lines instead of MAVLink
                        (seed 000's `pitch,yaw,roll` firmware: gcs.mavlink.ascii)
"""

from __future__ import annotations

import socket
from dataclasses import dataclass, replace


class AddressError(ValueError):
    """A connection string that cannot be understood."""


@dataclass(frozen=True, slots=True)
class Address:
    kind: str  # "udpin" | "udpout" | "tcp" | "tcpin" | "serial" | "tlog" | "pty"
    host: str = ""
    port: int = 0
    path: str = ""
    framing: str = "mavlink"  # "mavlink" | "ascii": what the bytes are

    def __str__(self) -> str:
        if self.framing == "ascii":
            return f"ascii:{replace(self, framing='mavlink')}"
        if self.kind in ("serial", "tlog"):
            return self.path
        if self.kind == "pty":
            return f"pty:{self.path}"
        return f"{self.kind}:{self.host}:{self.port}"


_NETWORK_KINDS = ("udpin", "udpout", "udp", "tcp", "tcpin")


def parse_address(text: str) -> Address:
    """Parse a connection string; raises AddressError naming what is wrong."""
    text = text.strip()
    if not text:
        raise AddressError("empty connection string")
    scheme, sep, rest = text.partition(":")
    if sep and scheme == "ascii":
        inner = parse_address(rest)
        if inner.framing == "ascii" or inner.kind == "tlog":
            raise AddressError(f"{text!r}: ascii: takes a serial device, pty:, udpin:, udpout:, tcp: or tcpin:")
        return replace(inner, framing="ascii")
    if sep and scheme in _NETWORK_KINDS:
        host, sep2, port_text = rest.rpartition(":")
        if not sep2 or not host:
            raise AddressError(f"{text!r}: expected {scheme}:HOST:PORT")
        try:
            port = int(port_text)
        except ValueError:
            raise AddressError(f"{text!r}: port {port_text!r} is not a number") from None
        if not 0 <= port <= 65535:
            raise AddressError(f"{text!r}: port {port} is outside 0-65535")
        kind = "udpin" if scheme == "udp" else scheme  # pymavlink's "udp:" means listen
        return Address(kind, host.strip("[]"), port)
    if sep and scheme == "pty":
        return Address("pty", path=rest)
    if text.lower().endswith(".tlog"):
        return Address("tlog", path=text)
    if sep and scheme not in ("COM",) and not text.startswith("/"):
        raise AddressError(
            f"{text!r}: unknown scheme {scheme!r}; "
            "use udpin:, udpout:, tcp:, tcpin:, ascii:, a serial device or a .tlog"
        )
    return Address("serial", path=text)


def free_port(kind: socket.SocketKind = socket.SOCK_DGRAM, host: str = "127.0.0.1") -> int:
    """A port nobody is bound to on `host` now (UDP by default), for a link the caller sets up next."""
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind((host, 0))
        port: int = s.getsockname()[1]
        return port
