"""Helpers of the ADS tests (tests/ads/, also used by the nc-ads tests): loopback addresses for pyads.

AdsLib (inside pyads) always connects to TCP port 48898, so tests cannot use a free port: each test gets
its own loopback address 127.0.0.x (Linux routes all of 127.0.0.0/8 to lo) where 48898 is free.
"""
from __future__ import annotations

import errno
import random
import socket

from nc_ads.ams import AMS_TCP_PORT

#: the AMS net id the test servers use
SERVER_NETID = "5.80.201.232.1.1"


def free_ads_address(port: int = AMS_TCP_PORT, tries: int = 200) -> str:
    """A random 127.0.0.x (x in 2..250) where `port` can be bound right now (race: bind it soon)."""
    rng = random.SystemRandom()
    for _ in range(tries):
        host = f"127.0.0.{rng.randint(2, 250)}"
        s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        try:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            s.bind((host, port))
        except OSError as exc:
            if exc.errno not in (errno.EADDRINUSE, errno.EADDRNOTAVAIL, errno.EACCES):
                raise
            continue
        finally:
            s.close()
        return host
    raise RuntimeError(f"no 127.0.0.x with port {port} free after {tries} tries")


def start_server_on_free_address(make, tries: int = 20):
    """`make(host)` -> a started server (e.g. AdsServer(...).start()); retried on another address when
    the bind fails because someone took it meanwhile. Returns (host, server)."""
    last: OSError | None = None
    for _ in range(tries):
        host = free_ads_address()
        try:
            return host, make(host)
        except OSError as exc:
            if exc.errno != errno.EADDRINUSE:
                raise
            last = exc
    raise RuntimeError(f"could not bind an ADS test server: {last}")
