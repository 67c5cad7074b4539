"""nc-opcua: the OPC UA door of zenoh-nc (command line).

Usage::

    nc-opcua --connect tcp/127.0.0.1:7447 --users users.toml [--nc nc1]... [--listen opc.tcp://0.0.0.0:4840/zenoh-nc]
             [--role engineer] [--anonymous] [--sampling-ms 100] [--cert opcua.der --key opcua.key.pem
             --security sign,encrypt] [--app-uri urn:...] [--client-id opcua] [--tls-dir DIR]
    nc-opcua user FILE NAME --role operator        # add/replace a user (password from the terminal or stdin)
    nc-opcua cert DIR [--name opcua] --uri URN [--host H]...   # an application certificate for Basic256Sha256

Prints ``nc-opcua ready <url>`` on stdout once listening. Exit status 2 for bad options or files (the
message says which), 1 when the server fails.

May import: ``nc_link``, ``nc_schema``, ``asyncua`` and this package.
"""
from __future__ import annotations

import argparse
import asyncio
import logging
import os
import signal
import sys
from typing import TYPE_CHECKING
from urllib.parse import urlparse

from nc_link.users import ROLES, UsersError, load_users, user_main

if TYPE_CHECKING:
    from .server import OpcuaDoor

PROG = "nc-opcua"


def _cert_main(argv: list[str]) -> int:
    from .certs import make_app_certificate
    p = argparse.ArgumentParser(prog=f"{PROG} cert", description="make an OPC UA application instance certificate")
    p.add_argument("dir")
    p.add_argument("--name", default="opcua", help="common name and file name (default opcua)")
    p.add_argument("--uri", required=True, help="the ApplicationUri (subjectAltName URI)")
    p.add_argument("--host", action="append", default=None, help="DNS name or IP in subjectAltName (repeatable; "
                   "default localhost and 127.0.0.1)")
    a = p.parse_args(argv)
    cert, key = make_app_certificate(a.dir, a.name, a.uri, a.host or ("localhost", "127.0.0.1"))
    print(f"{cert}\n{key}")
    return 0


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog=PROG, description="OPC UA server for the NCs on a zenoh router")
    p.add_argument("--connect", required=True, metavar="ENDPOINT", help="zenoh endpoint of the router (or an NC)")
    p.add_argument("--nc", action="append", default=[], metavar="NAME",
                   help="serve this NC (repeatable; default: every NC found on the router)")
    p.add_argument("--listen", default="opc.tcp://127.0.0.1:4840/zenoh-nc", metavar="URL", help="the OPC UA endpoint")
    p.add_argument("--users", metavar="FILE", help="users file (nc-opcua user FILE NAME --role R makes entries)")
    p.add_argument("--anonymous", action="store_true", help="allow anonymous sessions (read-only)")
    p.add_argument("--role", default="engineer", choices=ROLES, help="the door's own role: caps every user's")
    p.add_argument("--sampling-ms", type=int, default=100, choices=(2, 5, 10, 20, 50, 100),
                   help="value update period [ms] (default 100)")
    p.add_argument("--cert", metavar="DER", help="application instance certificate (nc-opcua cert)")
    p.add_argument("--key", metavar="PEM", help="its private key")
    p.add_argument("--security", default=None, metavar="LIST",
                   help="offered policies: none, sign, encrypt (Basic256Sha256), comma-separated "
                        "(default: sign,encrypt with --cert, else none)")
    p.add_argument("--trust", metavar="DIR", help="trusted client application certificates (DER/PEM files; "
                   "default: any client certificate)")
    p.add_argument("--app-uri", default=None, metavar="URI",
                   help="ApplicationUri (default: the certificate's subjectAltName URI, else urn:zenoh-nc:nc-opcua)")
    p.add_argument("--client-id", default="opcua", metavar="ID", help="the door's zenoh client id (default opcua)")
    p.add_argument("--tls-dir", metavar="DIR", help="zenoh mutual TLS as --client-id (tls/ endpoint)")
    p.add_argument("--session-timeout", type=float, default=10.0, metavar="S",
                   help="longest OPC UA session timeout granted [s]: a session whose connection is lost ends then")
    p.add_argument("--log-level", default="WARNING")
    return p.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] == "user":
        return user_main(PROG, argv[1:])
    if argv and argv[0] == "cert":
        return _cert_main(argv[1:])
    a = parse_args(argv)
    logging.basicConfig(level=a.log_level.upper(), format="%(asctime)s %(name)s %(levelname)s %(message)s")
    for noisy in ("asyncua",):
        logging.getLogger(noisy).setLevel(max(logging.WARNING, logging.getLogger().level))
    from .server import DoorConfig, OpcuaDoor
    try:
        users = load_users(a.users) if a.users else {}
    except UsersError as exc:
        print(f"{PROG}: {exc}", file=sys.stderr)
        return 2
    if not users and not a.anonymous:
        print(f"{PROG}: no users (--users FILE) and no --anonymous: nobody could log in", file=sys.stderr)
        return 2
    if bool(a.cert) != bool(a.key):
        print(f"{PROG}: --cert and --key go together", file=sys.stderr)
        return 2
    if a.trust is not None and not os.path.isdir(a.trust):
        print(f"{PROG}: --trust {a.trust}: not a directory", file=sys.stderr)
        return 2
    security = [s.strip() for s in (a.security or ("sign,encrypt" if a.cert else "none")).split(",") if s.strip()]
    host = urlparse(a.listen).hostname or ""
    if "none" in security and users and host not in ("127.0.0.1", "localhost", "::1"):
        logging.getLogger(PROG).warning("listening on %s with security policy none: user passwords may cross the "
                                        "network in clear (give --cert/--key and --security sign,encrypt)", host)
    app_uri = a.app_uri
    if a.cert:
        from .certs import application_uri_of
        try:
            uri = application_uri_of(a.cert)
        except (OSError, ValueError) as exc:
            print(f"{PROG}: --cert {a.cert}: {exc}", file=sys.stderr)
            return 2
        if uri is None:
            print(f"{PROG}: --cert {a.cert} has no ApplicationUri in subjectAltName (make one: nc-opcua cert)",
                  file=sys.stderr)
            return 2
        if app_uri and app_uri != uri:
            print(f"{PROG}: --app-uri {app_uri} differs from the certificate's {uri}", file=sys.stderr)
            return 2
        app_uri = uri
    cfg = DoorConfig(connect=a.connect, door_id=a.client_id, ncs=a.nc, url=a.listen, users=users,
                     allow_anonymous=a.anonymous, role=a.role, sampling_ms=a.sampling_ms, cert=a.cert, key=a.key,
                     security=security, app_uri=app_uri or "urn:zenoh-nc:nc-opcua", tls_dir=a.tls_dir,
                     session_timeout=a.session_timeout, trust=a.trust)
    try:
        door = OpcuaDoor(cfg)
    except ValueError as exc:
        print(f"{PROG}: {exc}", file=sys.stderr)
        return 2
    return asyncio.run(_run(door, a.listen))


async def _run(door: OpcuaDoor, url: str) -> int:
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    try:
        await door.start()
    except (ValueError, OSError) as exc:
        print(f"{PROG}: {exc}", file=sys.stderr)
        return 2
    print(f"{PROG} ready {url}", flush=True)
    await stop.wait()
    await door.stop()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
