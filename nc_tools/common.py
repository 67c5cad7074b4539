"""What the inspection tools share: an explicit zenoh client config and the key helpers."""
from __future__ import annotations

import argparse
import sys
from typing import Any, cast

import zenoh

from nc_schema.zenoh_config import client_config as shared_client_config


def client_config(endpoint: str, lease_ms: int = 1000, tls_dir: str | None = None,
                  identity: str = "status") -> zenoh.Config:
    """``nc_schema.zenoh_config.client_config`` for a tool: as ``identity`` (with ``tls_dir``, its
    certificate ``<tls_dir>/<identity>.pem``, an observer of the roles file; docs/roles.md); the
    first connection fails at once when nobody listens (a tool prints why and exits), a lost one
    is retried every 100-250 ms.

    Raises:
        zenoh.ZError: zenoh rejected the endpoint.
        ValueError: a certificate file is missing.
    """
    return shared_client_config(endpoint, lease_ms, tls_dir, identity, connect_timeout_ms=0)


def add_connection_args(p: argparse.ArgumentParser, help_connect: str) -> None:
    """``--connect`` (required), ``--tls-dir`` and ``--client-id`` (the certificate's identity)."""
    p.add_argument("--connect", required=True, metavar="ENDPOINT", help=help_connect)
    p.add_argument("--tls-dir", metavar="DIR", help="certificate directory: mutual TLS as --client-id (tls/ endpoint)")
    p.add_argument("--client-id", default="status", metavar="ID",
                   help="identity of the certificate <DIR>/<ID>.pem (an observer of the roles file; default status)")


def open_session(endpoint: str, prog: str, tls_dir: str | None = None, identity: str = "status") -> zenoh.Session:
    """Open a client session to ``endpoint``; on failure print why and exit with status 2."""
    try:
        return zenoh.open(client_config(endpoint, tls_dir=tls_dir, identity=identity))
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
        return str(int(cast(Any, axis)))  # (any key msgpack gave: int() decides)
    except (TypeError, ValueError):
        return str(axis)
