"""``nc-ads``: an ADS (AMS/TCP) server in front of one zenoh NC, for pyads and other TwinCAT tools.

    nc-ads --nc nc1=tcp/127.0.0.1:7447 --listen 127.0.0.1:48898 --netid 127.0.0.1.1.1 \\
           [--client-id ads1] [--role observer|operator|engineer] [--tls-dir DIR] \\
           [--allow-write NETID|IP|CIDR ...] [--ports 500,501]

The NC side is an ordinary zenoh client (client mode, only the given endpoint, multicast and gossip
scouting off; with ``--tls-dir`` mutual TLS as ``--client-id``, like plc-run and nc-status). The ADS side
listens on loopback by default. ``--role`` (default observer) decides which writes are let through
(docs/ads.md); ``--allow-write`` restricts which AMS net ids / IP addresses may write at all.

One NC per process: a second ``--nc`` is refused (run one nc-ads per NC, each on its own listen address;
AdsLib clients always connect to TCP 48898).

Prints ``nc-ads ready: ...`` once the ADS port listens (the NC may still be unreachable then: requests
answer 0x707 until its first status frame). Exit status 0 after SIGINT/SIGTERM, 2 for bad arguments,
1 if the listen address cannot be bound.
"""
from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading
from typing import Sequence

from nc_schema import ROLE_CLASSES, Keys, check_client_id
from nc_schema.endpoints import is_loopback_host

from .ams import AMS_TCP_PORT, netid_to_bytes
from .nc_device import MAX_ADS_AXIS_ID, NcDevice

log = logging.getLogger("nc_ads")


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="nc-ads", description="ADS (AMS/TCP) door to a zenoh-nc NC (docs/ads.md)")
    p.add_argument("--nc", action="append", required=True, metavar="NAME=ENDPOINT",
                   help="the NC and its zenoh endpoint, e.g. nc1=tcp/127.0.0.1:7447 (one per nc-ads)")
    p.add_argument("--listen", default=f"127.0.0.1:{AMS_TCP_PORT}", metavar="HOST:PORT",
                   help=f"ADS listen address (default 127.0.0.1:{AMS_TCP_PORT}; AdsLib clients always use port "
                        f"{AMS_TCP_PORT})")
    p.add_argument("--netid", metavar="NETID", help="this server's AMS net id (default: <listen host>.1.1)")
    p.add_argument("--client-id", default="ads1", metavar="ID", help="zenoh identity (certificate CN with --tls-dir)")
    p.add_argument("--role", default="observer", choices=list(ROLE_CLASSES),
                   help="what ADS clients may do through nc-ads (default observer: read only)")
    p.add_argument("--tls-dir", metavar="DIR", help="certificate directory: mutual TLS as --client-id (tls/ endpoint)")
    p.add_argument("--allow-write", nargs="+", action="extend", metavar="NETID|IP",
                   help="AMS net ids and/or IP addresses/CIDRs that may write (default: every client that can "
                        "connect)")
    p.add_argument("--ports", default="500,501", metavar="P,P", help="AMS ports served (default 500,501)")
    p.add_argument("--tick-ms", type=float, default=2.0, help="notification tick [ms] (default 2)")
    p.add_argument("--frame-period", type=int, default=2, metavar="MS",
                   help="status frames taken: nc/<nc>/frame/<MS>ms (0: every NC cycle; default 2)")
    p.add_argument("--query-timeout", type=float, default=1.5, help="wait for an NC reply [s] (default 1.5)")
    p.add_argument("--stale-after", type=float, default=1.0, metavar="S",
                   help="no status frame for this long: the NC counts as unreachable, reads of its cyclic data "
                        "answer 0x707 (default 1.0)")
    p.add_argument("--lenient-netid", action="store_true", help="answer requests for any target net id")
    p.add_argument("--log-level", default="INFO", choices=["DEBUG", "INFO", "WARNING", "ERROR"])
    return p


def _args(argv: Sequence[str] | None) -> tuple[argparse.Namespace, str, str, tuple[str, int], list[int]]:
    p = _parser()
    a = p.parse_args(argv)
    if len(a.nc) > 1:
        p.error("one NC per nc-ads: run one nc-ads per NC, each on its own listen address")
    name, sep, endpoint = a.nc[0].partition("=")
    if not sep or not endpoint:
        p.error(f"--nc {a.nc[0]!r}: expected NAME=ENDPOINT, e.g. nc1=tcp/127.0.0.1:7447")
    try:
        Keys(name)
        check_client_id(a.client_id)
    except ValueError as exc:
        p.error(str(exc))
    host, sep, port_s = a.listen.rpartition(":")
    if not sep or not host or not port_s.isdigit() or not 0 <= int(port_s) < 65536:
        p.error(f"--listen {a.listen!r}: expected HOST:PORT")
    try:
        ports = [int(x) for x in a.ports.split(",") if x.strip()]
    except ValueError:
        p.error(f"--ports {a.ports!r}: expected AMS port numbers separated by commas")
    if not ports or any(not 0 < x < 65536 for x in ports):
        p.error(f"--ports {a.ports!r}: AMS ports are 1..65535")
    netid = a.netid or f"{host}.1.1"
    try:
        netid_to_bytes(netid)
    except ValueError:
        p.error(f"--netid {netid!r}: an AMS net id has six numbers 0..255 (a.b.c.d.e.f)")
    if not 0 < a.stale_after <= 60 or not 0 < a.query_timeout <= 60:
        p.error("--stale-after and --query-timeout are seconds in (0, 60]")
    if a.tls_dir and not endpoint.startswith("tls/"):
        p.error(f"--tls-dir needs a tls/ endpoint, got {endpoint!r}")
    return a, name, endpoint, (host, int(port_s)), ports


def write_exposure(host: str, role: str, allow_write: bool) -> tuple[int, str] | None:
    """What nc-ads says at start about who may write through it (ADS has no authentication).

    Returns:
        ``(logging.WARNING, text)`` when it listens beyond loopback as operator or engineer without
        ``--allow-write`` (every host that reaches the address may write), ``(logging.INFO, text)`` for
        the same on loopback (every process of this host may), None as observer or with
        ``--allow-write`` (the write policy decides).
    """
    if role == "observer" or allow_write:
        return None
    if not is_loopback_host(host):
        return logging.WARNING, (
            f"ADS on {host} (not loopback) as {role} and no --allow-write: every host that reaches this address "
            f"may write to the NC's axes (ADS has no authentication). Fix: --allow-write NETID|IP|CIDR for the "
            f"hosts that may, or --listen 127.0.0.1:PORT (docs/ads.md)")
    return logging.INFO, (f"ADS on loopback ({host}) as {role} without --allow-write: every process of this host "
                          "may write (docs/ads.md)")


def main(argv: Sequence[str] | None = None) -> int:
    a, name, endpoint, listen, ports = _args(argv)
    logging.basicConfig(level=a.log_level, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    from .server import AdsServer, WritePolicy  # after the argument checks: a bad option fails fast

    try:
        policy = WritePolicy(a.allow_write) if a.allow_write else WritePolicy()
        device = NcDevice(name, endpoint, client_id=a.client_id, role=a.role, tls_dir=a.tls_dir,
                          query_timeout=a.query_timeout, stale_after=a.stale_after,
                          frame_period_ms=a.frame_period)
    except ValueError as exc:
        print(f"nc-ads: {exc}", file=sys.stderr)
        return 2
    server = AdsServer({p: device for p in ports}, a.netid or f"{listen[0]}.1.1", listen, policy,
                       strict_netid=not a.lenient_netid, tick_ms=a.tick_ms)
    try:
        server.start()
    except OSError as exc:
        print(f"nc-ads: cannot listen on {listen[0]}:{listen[1]}: {exc}", file=sys.stderr)
        return 1
    device.start()
    stop = threading.Event()

    def on_signal(signum: int, _frame: object) -> None:
        stop.set()

    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, on_signal)
    host, port = server.bound_address
    said = write_exposure(host, a.role, bool(a.allow_write))
    if said is not None:
        log.log(*said)
    print(f"nc-ads ready: ADS {host}:{port} net id {server.net_id} ports {','.join(map(str, ports))}; NC {name} at "
          f"{endpoint} as {a.client_id} ({a.role}); axes above {MAX_ADS_AXIS_ID} have no ADS index group",
          flush=True)
    try:
        while not stop.wait(0.2):
            pass
    finally:
        device.close()  # first: the held axes are released in order (enables off, Release), then the ADS side
        server.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
