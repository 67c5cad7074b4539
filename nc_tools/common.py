"""What the inspection tools share: an explicit zenoh client config and the key helpers."""
from __future__ import annotations

import json
import sys

import zenoh


def client_config(endpoint: str, lease_ms: int = 1000) -> zenoh.Config:
    """Client mode, connect to ``endpoint`` only: no listening, multicast and gossip scouting off.

    Raises:
        zenoh.ZError: zenoh rejected the endpoint.
    """
    c = zenoh.Config()
    c.insert_json5("mode", '"client"')
    c.insert_json5("connect/endpoints", json.dumps([endpoint]))
    c.insert_json5("listen/endpoints", "[]")
    c.insert_json5("scouting/multicast/enabled", "false")
    c.insert_json5("scouting/gossip/enabled", "false")
    c.insert_json5("transport/link/tx/lease", str(int(lease_ms)))
    return c


def open_session(endpoint: str, prog: str) -> zenoh.Session:
    """Open a client session to ``endpoint``; on failure print why and exit with status 2."""
    try:
        return zenoh.open(client_config(endpoint))
    except Exception as exc:  # zenoh.ZError: bad endpoint, nothing listening, ...
        print(f"{prog}: cannot connect to {endpoint}: {exc}", file=sys.stderr)
        raise SystemExit(2) from None


def nc_of(key: object) -> str:
    """The NC name of a key ``nc/<nc>/...``."""
    parts = str(key).split("/")
    return parts[1] if len(parts) > 1 else ""


def axis_key(axis: object) -> str:
    """A map key for an axis id (msgpack maps may use ints or strings): its decimal string."""
    try:
        return str(int(axis))  # type: ignore[call-overload]
    except (TypeError, ValueError):
        return str(axis)
