"""Opening a client session: the one client config, TLS checked before anything is opened.

May import: ``nc_schema`` (the config and the TLS files), ``zenoh``.
"""
from __future__ import annotations

from typing import Any, Iterable

from nc_schema.tls import check_tls_endpoints, tls_files
from nc_schema.zenoh_config import DEFAULT_LEASE_MS, client_config


def check_tls(tls_dir: str, identity: str, endpoints: Iterable[str], what: str = "endpoints") -> None:
    """Check a TLS client's setup now, not at its first connection: ``<tls_dir>/ca.pem`` and the identity's
    certificate and key exist and are readable, and every endpoint is ``tls/``.

    Raises:
        nc_schema.tls.TlsError: a file is missing or unreadable, or an endpoint is not ``tls/`` (``what``
            names the endpoints in the message).
    """
    tls_files(tls_dir, identity)
    check_tls_endpoints(list(endpoints), what)


def open_session(endpoint: str, identity: str, lease_ms: int = DEFAULT_LEASE_MS, tls_dir: str | None = None,
                 config: Any = None) -> Any:
    """Open a zenoh client session to ``endpoint`` as ``identity`` with :func:`client_config` (or ``config``).

    Raises:
        Exception: zenoh's (``zenoh.ZError``: nobody listens there yet, a bad endpoint) or a missing
            certificate (``TlsError``).
    """
    import zenoh

    return zenoh.open(config if config is not None else client_config(endpoint, lease_ms, tls_dir, identity))


def short_error(exc: BaseException) -> str:
    """zenoh's error text without its source location (``... at src/...``)."""
    return str(exc).split(" at ")[0]
