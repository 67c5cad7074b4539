"""Helpers of the security tests (fixtures in this folder's conftest.py)."""
from __future__ import annotations

import json
from pathlib import Path

import zenoh

from nc_schema.tls import apply_tls


def tls_config(port: int, certs_dir: Path, identity: str, lease_ms: int = 1000) -> zenoh.Config:
    """Client-mode config to ``tls/127.0.0.1:<port>`` with ``identity``'s certificate; no scouting."""
    c = zenoh.Config()
    c.insert_json5("mode", '"client"')
    c.insert_json5("connect/endpoints", json.dumps([f"tls/127.0.0.1:{port}"]))
    c.insert_json5("connect/timeout_ms", "5000")
    c.insert_json5("listen/endpoints", "[]")
    c.insert_json5("scouting/multicast/enabled", "false")
    c.insert_json5("scouting/gossip/enabled", "false")
    c.insert_json5("transport/link/tx/lease", str(lease_ms))
    apply_tls(c, certs_dir, identity)
    return c
