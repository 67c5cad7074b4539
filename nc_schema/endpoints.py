"""Where an endpoint reaches: loopback or beyond (for the start-up warnings of nc-server and nc-ads).

Pure string work, no zenoh: ``tcp/127.0.0.1:7447``, ``tls/[::1]:7447``, ``udp/nc1.local:7447``,
``unixsock-stream//run/x.sock`` (local by construction), ``127.0.0.1:48898`` (a plain HOST:PORT).
"""
from __future__ import annotations

import ipaddress

#: zenoh link protocols that never leave the host.
LOCAL_PROTOCOLS = frozenset({"unixsock-stream", "unixpipe", "vsock"})


def is_loopback_host(host: str) -> bool:
    """True for a loopback address (127.0.0.0/8, ::1, IPv4-mapped loopback) or ``localhost``.

    A wildcard (``0.0.0.0``, ``::``) or any other name counts as beyond loopback.
    """
    host = host.strip("[]")
    if host.lower() == "localhost":
        return True
    try:
        addr = ipaddress.ip_address(host.split("%", 1)[0])
    except ValueError:
        return False
    mapped = getattr(addr, "ipv4_mapped", None)
    return bool(addr.is_loopback or (mapped is not None and mapped.is_loopback))


def endpoint_is_local(endpoint: str) -> bool:
    """True if a zenoh endpoint (``proto/host:port[#config]``) is reachable from this host only."""
    proto, sep, rest = endpoint.partition("/")
    if not sep:
        proto, rest = "", endpoint
    if proto in LOCAL_PROTOCOLS:
        return True
    addr = rest.split("#", 1)[0].split("?", 1)[0]
    host = addr.rsplit(":", 1)[0] if ":" in addr else addr
    return is_loopback_host(host)
