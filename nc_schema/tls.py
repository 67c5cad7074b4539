"""The TLS part of a zenoh config, from a certificate directory (``deploy/certs/make-certs.sh``).

Owned here, below both sides: the client config (:mod:`nc_schema.zenoh_config`, the client link ``nc_link``)
and nc-server's own sessions and ``nc-router`` build their TLS sections with it. Imports only the standard
library (no zenoh: the caller passes its ``zenoh.Config``).

The directory holds ``ca.pem`` (the private CA) and, per identity, ``<id>.pem`` and ``<id>.key``
(certificate with CN=<id>, its private key). One section serves both directions, since the
certificates are made for client and server use:

* listening (an NC in router mode, ``nc-router``): the identity's certificate, client
  certificates required and verified against ``ca.pem`` (mutual TLS);
* connecting (``plc-run``, an NC behind a router): the identity's certificate is sent (zenoh
  sends it only with ``enable_mtls: true``), the peer's certificate is verified against
  ``ca.pem`` and its name (``verify_name_on_connect``: SAN ``DNS:router``, ``DNS:localhost``,
  ``IP:127.0.0.1``).

``transport/link/protocols`` is set to ``["tls"]``: a stray ``tcp/`` endpoint then makes
``zenoh.open`` fail instead of opening an unencrypted port.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

__all__ = ["TlsError", "TlsFiles", "tls_files", "tls_section", "apply_tls", "check_tls_endpoints"]


class TlsError(ValueError):
    """A certificate directory that cannot be used (a file is missing), or a non-TLS endpoint."""


@dataclass(frozen=True)
class TlsFiles:
    """Absolute paths of one identity's TLS files."""

    ca: str
    cert: str
    key: str


def tls_files(cert_dir: str | Path, identity: str) -> TlsFiles:
    """The CA, certificate and key of ``identity`` in ``cert_dir``.

    Raises:
        TlsError: a file is missing or unreadable.
    """
    d = Path(cert_dir)
    files = TlsFiles(str((d / "ca.pem").resolve()), str((d / f"{identity}.pem").resolve()),
                     str((d / f"{identity}.key").resolve()))
    missing = [p for p in (files.ca, files.cert, files.key) if not Path(p).is_file()]
    if missing:
        raise TlsError(f"TLS directory {cert_dir}: missing {', '.join(Path(m).name for m in missing)} "
                       f"(make them with deploy/certs/make-certs.sh {cert_dir} {identity})")
    for p in (files.ca, files.cert, files.key):
        try:
            with open(p, "rb"):
                pass
        except OSError as exc:
            raise TlsError(f"TLS directory {cert_dir}: cannot read {Path(p).name}: {exc.strerror or exc}") from None
    return files


def tls_section(cert_dir: str | Path, identity: str) -> dict[str, Any]:
    """The ``transport/link/tls`` section for ``identity`` (listening and connecting).

    Raises:
        TlsError: see :func:`tls_files`.
    """
    f = tls_files(cert_dir, identity)
    return {"root_ca_certificate": f.ca, "listen_certificate": f.cert, "listen_private_key": f.key,
            "connect_certificate": f.cert, "connect_private_key": f.key, "enable_mtls": True,
            "verify_name_on_connect": True, "close_link_on_expiration": True}


def check_tls_endpoints(endpoints: Sequence[str], what: str) -> None:
    """Raise TlsError unless every endpoint is ``tls/...``."""
    bad = [ep for ep in endpoints if not ep.startswith("tls/")]
    if bad:
        raise TlsError(f"{what}: with TLS every endpoint must be tls/<host>:<port>, got {', '.join(bad)}")


def apply_tls(config: Any, cert_dir: str | Path, identity: str) -> None:
    """Insert the TLS section for ``identity`` and ``protocols: ["tls"]`` into a ``zenoh.Config``.

    Raises:
        TlsError: see :func:`tls_files`.
        zenoh.ZError: zenoh rejected a value.
    """
    config.insert_json5("transport/link/tls", json.dumps(tls_section(cert_dir, identity)))
    config.insert_json5("transport/link/protocols", json.dumps(["tls"]))
