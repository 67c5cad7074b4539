"""``nc-router``: a zenoh router between PLC clients and NC servers (no zenohd needed).

Many hosts share axes through one router: NC servers (``nc-server --mode client --connect EP``) and
PLC clients (``plc-run --nc nc1=EP``) connect to it; it forwards data, queries and liveliness
between them and nothing else (it declares nothing of its own). Its zenoh config is explicit as
everywhere in zenoh-nc: the given listen/connect endpoints only, multicast and gossip scouting off,
the transport lease in ms (how fast a frozen peer is dropped and its liveliness tokens vanish).

Security (docs/roles.md): ``--tls-dir DIR`` makes every link mutual TLS with the router's
certificate ``DIR/<--tls-id>.pem`` (default ``router``, as ``deploy/certs/make-certs.sh`` makes it);
``--roles roles.toml`` (needs ``--tls-dir``) adds the zenoh access control generated from the roles
file (``nc_server.security.acl``): default deny, each client only its own keys by certificate CN.
zenoh reads both once, when the router opens: restart it after changing the roles file.

Exit codes: 0 after SIGINT/SIGTERM, 2 for a bad command line (also an unusable roles file or
certificate directory), 1 when zenoh cannot open (e.g. the endpoint is in use). Prints one
``nc-router ready: ...`` line on stdout once it serves.
"""
from __future__ import annotations

import argparse
import json
import logging
import signal
import sys
import threading
from typing import Any, Sequence

from nc_server.core.params import ConfigError
from nc_server.server.config import check_endpoint

log = logging.getLogger("nc_server.router")

#: Default transport lease [ms]: a frozen peer is dropped within about this time.
DEFAULT_LEASE_MS = 500


def router_config(listen: Sequence[str], connect: Sequence[str] = (), lease_ms: int = DEFAULT_LEASE_MS,
                  extra: dict[str, Any] | None = None) -> Any:
    """The router's explicit zenoh config.

    Args:
        listen: listen endpoints (at least one).
        connect: endpoints of other routers to connect to.
        lease_ms: transport lease [ms].
        extra: further config sections by json5 path (``{"access_control": {...}}``), inserted last.

    Raises:
        zenoh.ZError: zenoh rejected a value.
    """
    import zenoh

    c = zenoh.Config()
    c.insert_json5("mode", '"router"')
    c.insert_json5("listen/endpoints", json.dumps(list(listen)))
    c.insert_json5("connect/endpoints", json.dumps(list(connect)))
    c.insert_json5("scouting/multicast/enabled", "false")
    c.insert_json5("scouting/gossip/enabled", "false")
    c.insert_json5("transport/link/tx/lease", json.dumps(int(lease_ms)))
    # (as nc-server: a BLOCK message, e.g. the NC's reply, to a client whose queue stays full closes that
    # link after 0.5 s instead of holding the router's routing back for zenoh's 5 s)
    c.insert_json5("transport/link/tx/queue/congestion_control/block/wait_before_close", "500000")
    for path, value in (extra or {}).items():
        c.insert_json5(path, json.dumps(value))
    return c


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="nc-router", description="zenoh router for zenoh-nc NC servers and PLC clients.")
    p.add_argument("--listen", metavar="ENDPOINT", action="append", required=True,
                   help="listen endpoint, e.g. tcp/127.0.0.1:7450 (repeatable)")
    p.add_argument("--connect", metavar="ENDPOINT", action="append", default=[],
                   help="another router to connect to (repeatable)")
    p.add_argument("--lease-ms", type=int, default=DEFAULT_LEASE_MS, metavar="MS",
                   help=f"transport lease [ms] (default {DEFAULT_LEASE_MS})")
    p.add_argument("--tls-dir", metavar="DIR", help="certificate directory (deploy/certs/make-certs.sh): mutual TLS, "
                                                     "every endpoint tls/...")
    p.add_argument("--tls-id", default="router", metavar="ID", help="the router's certificate DIR/ID.pem (router)")
    p.add_argument("--roles", metavar="FILE", help="roles file: zenoh access control per certificate CN (needs --tls-dir)")
    p.add_argument("--log-level", default="INFO", choices=("DEBUG", "INFO", "WARNING", "ERROR"))
    return p


def security_extra(tls_dir: str | None, tls_id: str, roles_file: str | None,
                   endpoints: Sequence[str]) -> dict[str, Any]:
    """The config sections (by json5 path) for ``--tls-dir`` / ``--roles``.

    Raises:
        ConfigError: ``--roles`` without ``--tls-dir``, an unusable roles file or certificate
            directory, a non-TLS endpoint.
    """
    from nc_server.security.acl import access_control
    from nc_server.security.roles import RolesError, load_roles
    from nc_schema.tls import TlsError, check_tls_endpoints, tls_section

    extra: dict[str, Any] = {}
    if roles_file is not None and tls_dir is None:
        raise ConfigError("--roles", "needs --tls-dir: the access control identifies clients by certificate CN")
    if tls_dir is not None:
        try:
            extra["transport/link/tls"] = tls_section(tls_dir, tls_id)
            check_tls_endpoints(endpoints, "--listen/--connect")
        except TlsError as exc:
            raise ConfigError("--tls-dir", str(exc)) from None
        extra["transport/link/protocols"] = ["tls"]
    if roles_file is not None:
        try:
            extra["access_control"] = access_control(load_roles(roles_file))
        except (RolesError, ValueError) as exc:
            raise ConfigError("--roles", str(exc)) from None
    return extra


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``nc-router`` (returns the exit code)."""
    args = _parser().parse_args(argv)
    logging.basicConfig(level=args.log_level, stream=sys.stderr, format="nc-router: %(levelname)s %(message)s")
    try:
        for opt, eps in (("--listen", args.listen), ("--connect", args.connect)):
            for i, ep in enumerate(eps):
                check_endpoint(ep, f"{opt}[{i}]")
        if not 100 <= args.lease_ms <= 600_000:
            raise ConfigError("--lease-ms", f"must be 100..600000, got {args.lease_ms}")
        extra = security_extra(args.tls_dir, args.tls_id, args.roles, [*args.listen, *args.connect])
    except ConfigError as exc:
        print(f"nc-router: configuration error: {exc}", file=sys.stderr, flush=True)
        return 2
    if args.tls_dir and not args.roles:
        log.warning("TLS without --roles: clients are authenticated but not authorized (any certificate of the "
                    "CA may use any client id's keys)")
    return _run(router_config(args.listen, args.connect, args.lease_ms, extra), args.listen)


def _run(config: Any, listen: Sequence[str]) -> int:
    import zenoh

    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    try:
        session = zenoh.open(config)
    except zenoh.ZError as exc:
        log.error("cannot open zenoh on %s: %s", ", ".join(listen), exc)
        return 1
    sys.stdout.write(f"nc-router ready: listening {', '.join(listen)}, zid {session.info.zid()}\n")
    sys.stdout.flush()
    try:
        stop.wait()
    finally:
        session.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
