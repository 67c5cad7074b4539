"""``plc-run``: run a PLC program file cyclically against one or more NC servers.

    plc-run program.py [--nc nc1=tcp/127.0.0.1:7447] [--cycle-time 0.01] [--client-id ID] [--duration S]
                       [--tls-dir DIR] [--arg NAME=VALUE ...]

``program.py`` defines either ``def cycle(plc)`` (called once per PLC cycle with the
:class:`~plc_client.runtime.PlcRuntime`), or a class ``Program`` (instantiated once without
arguments; its ``cycle(plc)`` or ``cycle()`` method is called each cycle). AXIS_REFs in the
program name their NC (``AXIS_REF(nc="nc1", axis_id=1)``); every NC used needs a ``--nc``
(default: ``nc1=tcp/127.0.0.1:7447``). The AXIS_REFs the program declares are bound when it is
loaded (their data is valid once the NC's frames arrive, without a block call), and ``--arg
NAME=VALUE`` (repeatable) are the program's arguments, read with ``program_args(NAME=default, ...)``
(:mod:`plc_client.program`).

Exit codes: 0 after SIGINT/SIGTERM or ``--duration``; 1 when the program raised (the runtime
then switched the enables off and released its claims); 2 for a bad command line, a bad program
argument or a program file that cannot be loaded (one line on stderr, no traceback, nothing
connected). Prints one line on stdout once it runs; logs go to stderr.

The shutdown after SIGINT/SIGTERM is bounded (see :mod:`plc_client.runtime`), also when an NC is
dead or frozen: 3 cycles of enables-off frames, at most ``--timeout`` for the Release replies and
2 s for closing the zenoh sessions. If a session is still closing then, the process ends with
``os._exit`` (nothing of the interpreter's clean-up waits for zenoh's threads).
"""
from __future__ import annotations

import argparse
import logging
import os
import sys
from typing import Sequence

from .program import ProgramArgsError, load, load_program, parse_program_args

__all__ = ["main", "parse_ncs", "load_program"]


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="plc-run", description="Run a zenoh-nc PLC program (TcMC function blocks).")
    p.add_argument("program", help="Python file defining cycle(plc) or a Program class")
    p.add_argument("--nc", action="append", metavar="NAME=ENDPOINT",
                   help="an NC and its server endpoint, e.g. nc1=tcp/127.0.0.1:7447 (repeatable)")
    p.add_argument("--cycle-time", type=float, default=0.010, metavar="SECONDS", help="PLC cycle time [s] (0.01)")
    p.add_argument("--client-id", help="client id (default plc-<host>-<pid>)")
    p.add_argument("--duration", type=float, metavar="SECONDS", help="stop after this many seconds")
    p.add_argument("--stale-cycles", type=int, metavar="N",
                   help="PLC cycles without a new NC frame before axis data is invalid (default: 0.2 s worth)")
    p.add_argument("--timeout", type=float, default=1.0, metavar="SECONDS",
                   help="function block command timeout [s] (1.0)")
    p.add_argument("--tls-dir", metavar="DIR",
                   help="certificate directory (deploy/certs/make-certs.sh): mutual TLS with DIR/<client-id>.pem; "
                        "every --nc endpoint must be tls/...")
    p.add_argument("--lease-ms", type=int, default=None, metavar="MS",
                   help="zenoh transport lease this PLC announces [ms] (500): the NC drops a frozen PLC after "
                        "about 0.75 x lease (its claims fault with 0x8F01, its motions stop)")
    p.add_argument("--arg", action="append", metavar="NAME=VALUE", dest="program_args",
                   help="an argument of the program, read with plc_client.program_args(NAME=default) and typed "
                        "like its default, e.g. --arg speed=300 --arg axis=2 (repeatable)")
    p.add_argument("--whole-frames", action="store_true",
                   help="take every axis's data (nc/<nc>/frame/<P>ms) instead of this client's view of its own axes "
                        "(nc/<nc>/view/<client-id>): for an NC of protocol version 2")
    p.add_argument("--log-level", default="INFO", choices=("DEBUG", "INFO", "WARNING", "ERROR"))
    return p


def parse_ncs(items: Sequence[str] | None) -> dict[str, str]:
    """``["nc1=tcp/127.0.0.1:7447", ...]`` -> ``{"nc1": "tcp/127.0.0.1:7447"}``.

    Raises:
        ValueError: an item without ``=`` or with an empty name/endpoint, or a repeated name.
    """
    out: dict[str, str] = {}
    for item in items or ["nc1=tcp/127.0.0.1:7447"]:
        name, sep, ep = item.partition("=")
        if not sep or not name or not ep:
            raise ValueError(f"--nc {item!r}: expected NAME=ENDPOINT, e.g. nc1=tcp/127.0.0.1:7447")
        if name in out:
            raise ValueError(f"--nc {name} given twice")
        out[name] = ep
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``plc-run``; returns the exit code."""
    args = _parser().parse_args(argv)
    logging.basicConfig(level=args.log_level, format="plc-run: %(levelname)s %(name)s: %(message)s")
    logging.getLogger("zenoh").setLevel(logging.WARNING)
    try:
        ncs = parse_ncs(args.nc)
        loaded = load(args.program, parse_program_args(args.program_args))
    except ProgramArgsError as exc:
        print(f"plc-run: {exc}", file=sys.stderr, flush=True)
        return 2
    except Exception as exc:  # any import-time failure of the user's file
        print(f"plc-run: {exc.__class__.__name__}: {exc}", file=sys.stderr, flush=True)
        return 2

    from .runtime import DEFAULT_LEASE_MS, PlcRuntime

    try:
        if args.lease_ms is not None and not 100 <= args.lease_ms <= 600_000:
            raise ValueError(f"--lease-ms must be 100..600000, got {args.lease_ms}")
        rt = PlcRuntime(loaded.program, ncs, axes=loaded.axes, cycle_time=args.cycle_time, client_id=args.client_id,
                        stale_cycles=args.stale_cycles, command_timeout=args.timeout, tls_dir=args.tls_dir,
                        lease_ms=DEFAULT_LEASE_MS if args.lease_ms is None else args.lease_ms,
                        view=not args.whole_frames)
    except (ValueError, TypeError) as exc:
        print(f"plc-run: {exc}", file=sys.stderr, flush=True)
        return 2
    try:
        rt.open(wait=2.0)
    except KeyboardInterrupt:
        rt.stop()
        return 0
    print(f"plc-run {rt.client_id} running {args.program}: cycle {rt.cycle_time * 1000:.1f} ms, "
          f"NCs {', '.join(f'{k}={v}' for k, v in ncs.items())}", flush=True)
    rc = rt.run(args.duration)
    if rt.overruns:
        logging.getLogger("plc_client").info("%d PLC cycle overruns", rt.overruns)
    if rt.unclosed and argv is None:
        # A zenoh session is still closing (its NC is frozen or unreachable, see PlcRuntime):
        # do not let the interpreter's exit wait for zenoh's threads. Our token is undeclared;
        # the NC drops the claims when the connection ends.
        logging.shutdown()
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(rc)
    return rc


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
