"""The one explicit zenoh configuration of a client session (PLC runtime, nc-status / nc-scope,
the host tests' observer): never zenoh's defaults.

* ``mode: client``, ``connect/endpoints: [endpoint]``, no listen socket;
* multicast and gossip scouting off: only the configured endpoint is ever contacted;
* ``connect/retry`` (:data:`CONNECT_RETRY`): a lost connection is retried every 100-250 ms
  (zenoh's default starts at 1 s and doubles up to 4 s: a router restart then cost 0.5-3 s);
* ``connect/timeout_ms``: how long the first connection attempt keeps retrying before
  ``zenoh.open`` fails (0: at once);
* ``transport/link/tx/lease``: the lease this session announces (how fast its peers drop it
  when it freezes);
* with ``tls_dir``: mutual TLS as ``identity`` (:mod:`nc_schema.tls`; ``tls/`` endpoints).

The NC server's own session (``nc_server.server.transport.zenoh_config``) uses
:data:`CONNECT_RETRY` too for the endpoints it connects to (``--mode client --connect EP``).

zenoh is imported by the function only: ``nc_schema`` itself stays importable without it.
"""
from __future__ import annotations

import json
from typing import Any

#: zenoh ``connect/retry``: every 100 ms, growing by 1.5 up to 250 ms (zenoh 1.x keys).
CONNECT_RETRY = '{period_init_ms: 100, period_max_ms: 250, period_increase_factor: 1.5}'
#: Default ``connect/timeout_ms`` of a PLC session [ms] (its runtime retries in the background after).
CONNECT_TIMEOUT_MS = 2000
#: Default transport lease of a client session [ms].
DEFAULT_LEASE_MS = 500


def client_config(endpoint: str, lease_ms: int = DEFAULT_LEASE_MS, tls_dir: str | None = None,
                  identity: str | None = None, connect_timeout_ms: int = CONNECT_TIMEOUT_MS) -> Any:
    """A client-mode ``zenoh.Config`` for ``endpoint`` (see the module docstring).

    Args:
        endpoint: e.g. ``tcp/127.0.0.1:7450`` or ``tls/router:7450``.
        lease_ms: the lease this session announces [ms].
        tls_dir: certificate directory (mutual TLS with ``<tls_dir>/<identity>.pem``), or None.
        identity: the certificate's name (a client id, e.g. ``plc1`` or ``status``).
        connect_timeout_ms: ``connect/timeout_ms`` (0: ``zenoh.open`` fails at once when nobody
            listens; -1: retries for ever).

    Raises:
        zenoh.ZError: zenoh rejected a value (e.g. the endpoint).
        ValueError: a certificate file is missing (``TlsError``).
    """
    import zenoh

    c = zenoh.Config()
    c.insert_json5("mode", '"client"')
    c.insert_json5("connect/endpoints", json.dumps([endpoint]))
    c.insert_json5("listen/endpoints", "[]")
    c.insert_json5("scouting/multicast/enabled", "false")
    c.insert_json5("scouting/gossip/enabled", "false")
    c.insert_json5("transport/link/tx/lease", json.dumps(int(lease_ms)))
    c.insert_json5("connect/retry", CONNECT_RETRY)
    c.insert_json5("connect/timeout_ms", json.dumps(int(connect_timeout_ms)))
    if tls_dir:
        from .tls import apply_tls
        apply_tls(c, tls_dir, identity or "")
    return c
