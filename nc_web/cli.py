"""nc-web: the browser commissioning panel of zenoh-nc (command line).

Usage::

    nc-web --nc nc1=tcp/127.0.0.1:7447 [--nc nc2=...] --users users.toml [--listen 127.0.0.1:8080]
           [--role engineer] [--client-id web] [--tls-dir DIR] [--cert web.pem --key web.key.pem]
           [--secret-file FILE] [--frame-ms 50] [--hold-timeout 0.1] [--session-idle 10]
    nc-web --connect tcp/127.0.0.1:7447 --nc nc1 ...     # every --nc without '=' at the --connect endpoint
    nc-web user FILE NAME --role operator                # add/replace a user (the same file as nc-opcua's)

Prints ``nc-web ready <url>`` on stdout once listening. Exit status 2 for bad options or files (the message says
which), 1 when the server fails.

May import: ``nc_link``, ``nc_schema``, ``starlette``, ``uvicorn`` and this package.
"""
from __future__ import annotations

import argparse
import asyncio
import logging
import os
import sys
from pathlib import Path

from nc_link.users import ROLES, UsersError, load_users, user_main
from nc_schema import FRAME_PERIODS_MS

PROG = "nc-web"


def parse_args(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog=PROG, description="browser commissioning panel for NCs on zenoh")
    p.add_argument("--nc", action="append", default=[], metavar="NAME=ENDPOINT",
                   help="an NC and its zenoh endpoint (the NC's or its router's); NAME alone: at --connect")
    p.add_argument("--connect", metavar="ENDPOINT", help="the endpoint of every --nc given without one")
    p.add_argument("--listen", default="127.0.0.1:8080", metavar="HOST:PORT", help="HTTP(S) address")
    p.add_argument("--users", required=True, metavar="FILE", help="users file (nc-web user FILE NAME --role R)")
    p.add_argument("--role", default="engineer", choices=ROLES, help="the door's own role: caps every user's")
    p.add_argument("--client-id", default="web", metavar="ID", help="the door's zenoh client id (default web)")
    p.add_argument("--tls-dir", metavar="DIR", help="zenoh mutual TLS as --client-id (tls/ endpoints)")
    p.add_argument("--cert", metavar="PEM", help="HTTPS certificate (with --key)")
    p.add_argument("--key", metavar="PEM", help="its private key")
    p.add_argument("--secret-file", metavar="FILE", help="the login cookie key (made, mode 0600, if missing; "
                   "default: a new key at every start, logins end with a restart)")
    p.add_argument("--frame-ms", type=int, default=50, choices=FRAME_PERIODS_MS,
                   help="live value period [ms] (default 50: the NC's 50 ms frames)")
    p.add_argument("--hold-timeout", type=float, default=0.1, metavar="S",
                   help="a jog stops this long after the page's last heartbeat [s] (default 0.1; the page beats "
                        "every 30 ms)")
    p.add_argument("--session-idle", type=float, default=10.0, metavar="S",
                   help="a login without an open page this long ends, its claims released [s] (default 10)")
    p.add_argument("--log-level", default="WARNING")
    return p.parse_args(argv)


def read_secret(path: str | None) -> bytes:
    """The cookie key: from ``path`` (made with 32 random bytes, mode 0600, if missing), else a new one.

    Raises:
        ValueError: the file is unreadable or shorter than 16 bytes.
    """
    if path is None:
        return os.urandom(32)
    p = Path(path)
    if not p.exists():
        fd = os.open(p, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        with os.fdopen(fd, "wb") as f:
            f.write(os.urandom(32).hex().encode())
    try:
        data = p.read_bytes().strip()
    except OSError as exc:
        raise ValueError(f"--secret-file {path}: {exc.strerror}") from None
    if len(data) < 16:
        raise ValueError(f"--secret-file {path}: shorter than 16 bytes")
    return data


def parse_ncs(specs: list[str], connect: str | None) -> dict[str, str]:
    """``NAME=ENDPOINT`` (or ``NAME`` with ``connect``) -> {name: endpoint}.

    Raises:
        ValueError: an entry without an endpoint and no ``connect``, or a name given twice.
    """
    out: dict[str, str] = {}
    for s in specs:
        name, sep, ep = s.partition("=")
        if not sep:
            if connect is None:
                raise ValueError(f"--nc {s}: give NAME=ENDPOINT, or --connect ENDPOINT")
            ep = connect
        if not name or not ep:
            raise ValueError(f"--nc {s}: NAME=ENDPOINT")
        if name in out:
            raise ValueError(f"--nc {name} given twice")
        out[name] = ep
    return out


def main(argv: list[str] | None = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    if args and args[0] == "user":
        return user_main(PROG, args[1:])
    a = parse_args(args)
    logging.basicConfig(level=a.log_level.upper(), format="%(asctime)s %(name)s %(levelname)s %(message)s")
    try:
        ncs = parse_ncs(a.nc, a.connect)
        if not ncs:
            raise ValueError("no NC: --nc NAME=ENDPOINT")
        users = load_users(a.users)
        secret = read_secret(a.secret_file)
        if bool(a.cert) != bool(a.key):
            raise ValueError("--cert and --key go together")
        host, sep, port_s = a.listen.rpartition(":")
        if not sep or not port_s.isdigit():
            raise ValueError(f"--listen {a.listen}: HOST:PORT")
        if a.hold_timeout <= 0 or a.session_idle <= 0:
            raise ValueError("--hold-timeout and --session-idle must be > 0")
    except (ValueError, UsersError, OSError) as exc:
        print(f"{PROG}: {exc}", file=sys.stderr)
        return 2
    if not users:
        print(f"{PROG}: {a.users} has no user: nobody could log in", file=sys.stderr)
        return 2
    host = host.strip("[]")
    if not a.cert and host not in ("127.0.0.1", "localhost", "::1"):
        logging.getLogger(PROG).warning("listening on %s without HTTPS: passwords and the login cookie cross the "
                                        "network in clear (give --cert/--key)", host)
    from .app import WebConfig, WebDoor
    cfg = WebConfig(ncs=ncs, users=users, secret=secret, role=a.role, door_id=a.client_id, tls_dir=a.tls_dir,
                    frame_ms=a.frame_ms, hold_timeout=a.hold_timeout, session_idle=a.session_idle,
                    secure_cookie=bool(a.cert))
    try:
        if a.tls_dir:
            from nc_link import check_tls
            check_tls(a.tls_dir, a.client_id, ncs.values(), "--nc endpoints")
        door = WebDoor(cfg)
    except Exception as exc:  # ValueError, TlsError
        print(f"{PROG}: {exc}", file=sys.stderr)
        return 2
    return asyncio.run(_serve(door, host, int(port_s), a.cert, a.key, a.log_level))


async def _serve(door: object, host: str, port: int, cert: str | None, key: str | None, level: str) -> int:
    import uvicorn

    from .app import WebDoor
    assert isinstance(door, WebDoor)
    config = uvicorn.Config(door.app, host=host, port=port, ssl_certfile=cert, ssl_keyfile=key, log_level=level.lower(),
                            access_log=False, lifespan="on", ws_ping_interval=5.0, ws_ping_timeout=20.0)
    server = uvicorn.Server(config)
    task = asyncio.create_task(server.serve())
    while not server.started:
        if task.done():
            return 1 if task.exception() is not None or not server.started else 0
        await asyncio.sleep(0.05)
    scheme = "https" if cert else "http"
    print(f"{PROG} ready {scheme}://{host}:{port}/", flush=True)
    await task
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
