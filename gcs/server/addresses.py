"""Where a dashboard can be opened: this machine's own URL, and for one bound to every interface
(`--host 0.0.0.0` or `::`) the addresses other machines reach it at. At the field teammates open
the dashboard from their own laptops; the start-up line used to print http://0.0.0.0:PORT, which
no other machine can open."""

from __future__ import annotations

import ipaddress
import socket

import psutil

#: a wildcard bind, and the address families it accepts (Linux binds :: dual-stack by default)
WILDCARDS = {"0.0.0.0": {socket.AF_INET}, "::": {socket.AF_INET, socket.AF_INET6}}
#: where this machine opens a dashboard bound to a wildcard
LOOPBACK = {"0.0.0.0": "127.0.0.1", "::": "::1"}


def url_host(host: str) -> str:
    """`host` as a URL writes it: an IPv6 address in brackets."""
    return f"[{host}]" if ":" in host else host


def local_host(host: str) -> str:
    """The address this machine opens a dashboard bound to `host` at."""
    return LOOPBACK.get(host, host)


def shared_hosts(host: str) -> list[str]:
    """This machine's interface addresses (loopback and link-local left out) a dashboard bound to
    the wildcard `host` is reachable at from other machines; [] for any other host, whose own
    address is already the one to share."""
    families = WILDCARDS.get(host)
    if families is None:
        return []
    found: list[str] = []
    for addresses in psutil.net_if_addrs().values():
        for address in addresses:
            if address.family not in families:
                continue
            ip = ipaddress.ip_address(address.address.split("%")[0])
            if not (ip.is_loopback or ip.is_link_local) and str(ip) not in found:
                found.append(str(ip))
    return found
