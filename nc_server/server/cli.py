"""``nc-server``: run the NC.

Configuration: the embedded default or ``--config FILE`` (replacing it), then ``--config-overlay
FILE`` (partial TOML merged over it), ``--set KEY=VALUE`` and the dedicated options
(:mod:`nc_server.server.config`).

Exit codes: 0 after SIGINT/SIGTERM (clean shutdown), 2 for an invalid configuration or
command line (nothing is started), 1 when the NC cannot start (e.g. the listen endpoint is in use) or dies.
Prints one line on stdout once it serves (tests wait for it), logs go to stderr.
"""
from __future__ import annotations

import argparse
import logging
import logging.handlers
import queue
import signal
import sys
import threading
from typing import Sequence

from nc_server.core.params import ConfigError

from .config import REALTIME_MODES, ZENOH_MODES, check_endpoint, load_config

log = logging.getLogger("nc_server.server")


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="nc-server", description="zenoh-nc NC server (TwinCAT-style NC over zenoh).")
    p.add_argument("--config", metavar="FILE", help="TOML configuration replacing the embedded default as a whole")
    p.add_argument("--config-overlay", metavar="FILE", action="append", default=[],
                   help="partial TOML merged over the configuration ([nc]/[zenoh] keys, [axis.<AxisId>] tables or "
                        "[[axis]] tables with an AxisId; repeatable, applied in order)")
    p.add_argument("--set", metavar="KEY=VALUE", action="append", default=[], dest="sets",
                   help="one configuration value after the overlays: axis.<AxisId>.<Parameter>=VALUE (e.g. "
                        "axis.1.AxisVeloMax=300), nc.<key>=VALUE or zenoh.<key>=VALUE (repeatable)")
    p.add_argument("--listen", metavar="ENDPOINT", action="append",
                   help="zenoh listen endpoint, e.g. tcp/127.0.0.1:7447 (repeatable; replaces zenoh.listen)")
    p.add_argument("--connect", metavar="ENDPOINT", action="append",
                   help="zenoh endpoint to connect to, e.g. a router's tcp/127.0.0.1:7450 (repeatable; replaces zenoh.connect)")
    p.add_argument("--mode", choices=ZENOH_MODES, help="zenoh mode (default from config: router; client: behind nc-router)")
    p.add_argument("--name", help="NC name (key prefix nc/<name>)")
    p.add_argument("--cycle-time", type=float, metavar="SECONDS", help="NC cycle time [s], e.g. 0.001")
    p.add_argument("--watchdog-timeout", type=float, metavar="SECONDS",
                   help="maximum age of a claim holder's PLCTONC [s]")
    p.add_argument("--lease-ms", type=int, metavar="MS",
                   help="zenoh transport lease this NC announces [ms] (replaces zenoh.lease; default 500)")
    p.add_argument("--realtime", choices=REALTIME_MODES, help="cycle thread scheduling (default from config: auto)")
    p.add_argument("--retain", metavar="PATH",
                   help="retain file: positions of axes with AxisEnDataPersistence, homed flags and parameters "
                        "written at run time survive a restart (replaces nc.retain_file)")
    p.add_argument("--roles", metavar="FILE",
                   help="roles file (docs/roles.md): refuse commands a client's role does not allow; with --tls-dir "
                        "the NC's own router session also enforces zenoh access control per certificate CN")
    p.add_argument("--tls-dir", metavar="DIR",
                   help="certificate directory (deploy/certs/make-certs.sh): mutual TLS with DIR/<name>.pem; "
                        "every endpoint must be tls/...")
    p.add_argument("--log-level", default="INFO", choices=("DEBUG", "INFO", "WARNING", "ERROR"))
    return p


def _setup_logging(level: str) -> logging.handlers.QueueListener:
    # The cycle thread logs too: route records through a queue so it never blocks on stderr.
    q: queue.SimpleQueue[logging.LogRecord] = queue.SimpleQueue()
    h = logging.StreamHandler(sys.stderr)
    h.setFormatter(logging.Formatter("nc-server: %(levelname)s %(message)s"))
    listener = logging.handlers.QueueListener(q, h)
    root = logging.getLogger()
    root.handlers[:] = [logging.handlers.QueueHandler(q)]
    root.setLevel(level)
    logging.getLogger("zenoh").setLevel(logging.WARNING)
    listener.start()
    return listener


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``nc-server`` (returns the exit code; also calls sys.exit when run as a script)."""
    args = _parser().parse_args(argv)
    try:
        for opt, eps in (("--listen", args.listen), ("--connect", args.connect)):
            for i, ep in enumerate(eps or []):
                check_endpoint(ep, f"{opt}[{i}]")
        cfg = load_config(args.config, listen=args.listen, connect=args.connect, mode=args.mode, name=args.name, cycle_time=args.cycle_time,
                          realtime=args.realtime, watchdog_timeout=args.watchdog_timeout,
                          retain_file=args.retain, roles=args.roles, tls_dir=args.tls_dir,
                          lease_ms=args.lease_ms, overlays=args.config_overlay, sets=args.sets)
    except ConfigError as exc:
        print(f"nc-server: configuration error: {exc}", file=sys.stderr, flush=True)
        return 2

    listener = _setup_logging(args.log_level)
    try:
        return _run(cfg)
    finally:
        listener.stop()


def _run(cfg: object) -> int:
    # Imported here so that `nc-server --help` and config errors stay fast.
    import zenoh

    from nc_server.core import NcCore
    from nc_server.drives.group import build_drives

    from .app import NcServer
    from .config import ServerConfig
    from .cycle import AffinityError, RealtimeError
    from .retain import RetainLockError
    from .transport import OpenCancelled

    assert isinstance(cfg, ServerConfig)
    try:
        # each axis's Drive (default [nc] drive) names its backend, checked against the installed ones by the
        # config; the backend checks its own options ([drives.<backend>], the axis's Drive table)
        drives = cfg.axis_drives or tuple((cfg.drive, {}) for _ in cfg.axes)
        drive = build_drives([a.params for a in cfg.axes], cfg.cycle_time, [b for b, _ in drives],
                             [o for _, o in drives], cfg.drive_options, nc_name=cfg.name, zenoh=cfg.zenoh,
                             axis_ids=[a.AxisId for a in cfg.axes])
    except ConfigError as exc:
        print(f"nc-server: configuration error: {exc}", file=sys.stderr, flush=True)
        return 2
    except Exception as exc:  # a backend that cannot load or open its hardware: a start failure
        log.error("drives: %s: %s", type(exc).__name__, exc)
        return 1
    try:
        core = NcCore(list(cfg.axes), cycle_time=cfg.cycle_time, drive=drive)
        core.configure_remote(cfg.name, cfg.remote_masters, cfg.remote_max_age)
    except ConfigError as exc:
        drive.close()
        print(f"nc-server: configuration error: {exc}", file=sys.stderr, flush=True)
        return 2
    except BaseException:
        drive.close()  # (CANopen nodes back from OPERATIONAL, a remote link's threads ended)
        raise

    stop = threading.Event()

    def on_signal(signum: int, _frame: object) -> None:
        stop.set()
        if signum == signal.SIGTERM:  # one is enough: a repeated one must not cut the stop ramp short
            signal.signal(signal.SIGTERM, signal.SIG_IGN)

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGHUP, on_signal)  # (a closed terminal or session: stop cleanly too)

    try:
        server = NcServer(cfg, core)
    except BaseException:
        drive.close()
        raise
    try:
        server.start(cancel=stop)
    except OpenCancelled as exc:
        log.warning("%s", exc)
        return 0
    except zenoh.ZError as exc:
        log.error("cannot open zenoh on %s: %s", ", ".join(cfg.zenoh.listen + cfg.zenoh.connect), exc)
        return 1
    except RealtimeError as exc:
        log.error("%s (use realtime = \"auto\" or \"off\")", exc)
        return 1
    except AffinityError as exc:
        log.error("%s", exc)
        return 1
    except RetainLockError as exc:  # another NC runs on this retain file: a start failure
        log.error("%s", exc)
        return 1
    # one write: with PYTHONUNBUFFERED, print() would write text and newline separately and a log
    # line on stderr could land between them when both streams go to one file
    sys.stdout.write(f"nc-server {cfg.name} ready: {len(cfg.axes)} axes, cycle {cfg.cycle_time * 1e3:.3f} ms, "
                     f"timing {server.timing}, listening {', '.join(cfg.zenoh.listen) or '-'}"
                     + (f", connected to {', '.join(cfg.zenoh.connect)}" if cfg.zenoh.connect else "")
                     + f", instance {server.transport.instance}\n")
    sys.stdout.flush()
    rc = 0
    try:
        while not stop.wait(0.5):
            if not server.loop.alive:  # the cycle died (a bug): stop and say so
                log.error("cycle thread ended unexpectedly: %r", server.loop.error)
                rc = 1
                break
    finally:
        server.stop()
    log.info("stopped after %d cycles", int(core.cycle))
    return rc


if __name__ == "__main__":
    sys.exit(main())
