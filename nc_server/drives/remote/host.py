"""``nc-drive-sim``: a process hosting simulated CiA 402 drives that an NC reaches over zenoh (:mod:`.wire`).

    nc-drive-sim --config nc.toml --host drives1          # the axes of nc.toml whose Drive.host is drives1
    nc-drive-sim --nc nc1 --host drives1 --axes 2 --connect tcp/127.0.0.1:7447

The devices (:class:`..cia402.device.Cia402Device`, the axes' Sim* parameters from the NC's TOML) are stepped
every drive cycle (``--cycle-time``, 1 ms) by one thread at their own rate, whatever the NC does. Each cycle
the newest outputs the NC sent (``nc/<nc>/drive/<host>/rx``) are applied and the inputs are published
(``.../tx``); a liveliness token ``.../alive`` lives as long as the process; ``.../status`` (msgpack) and the
``--status-file`` (JSON, replaced atomically) show the drives about every 100 ms, also while the NC is gone.

Decisions:

* Between two outputs of the NC the drive extrapolates its target with the NC's target velocity (0x60FF, CSP's
  velocity feed forward) for at most ``--extrapolate`` (10 ms), then holds it: a late NC cycle (zenoh, the
  scheduler) does not make the motor stop and jump, and an NC that is gone does not run it away.
* Silence timeout ``--timeout`` (default: the TOML's ``[drives.remote] timeout_ms``, else :data:`DEFAULT_TIMEOUT`
  = 100 ms): no outputs for that long is the drive's communication fault 0x8130: each drive stops on its own
  quick-stop ramp (the axis's AxisDec) and keeps its position. It must be longer than a standby NC's longest
  takeover (docs/standby.md: its limit grows under load up to 1 s or the NC's lease, whichever is shorter, plus one
  cycle: ``config.worst_takeover``; a crash is seen at once) and than the longest stalls seen on a loaded 2-core VM
  (1-6 ms, zenoh spikes 3-5 ms); 100 ms is 20x the worst stall and still a short coast. With ``--config`` and
  ``[redundancy] enabled`` in the TOML the default is that longest takeover + 100 ms (601 ms at 1 ms cycles and the
  default lease), and a timeout not longer than the longest takeover is a configuration error (exit code 2); without
  ``--config`` the bound in force is learnt from the NC's outputs (``takeover_limit_ms``): a timeout not longer is logged
  once as a warning and shown in the status (``timeout_short``), not refused (the drives are running by then).
  When outputs come back the fault stays until the NC's MC_Reset (a fault reset), as on any drive.
* The process never exits because the NC went away; SIGTERM, SIGINT and SIGHUP end it (exit code 0) after the
  last status is written; its token is undeclared, so the NC sees the host go.
* Outputs that do not fit (another slot count, other AxisIds than this host serves: an NC configured for other
  drives) are refused (counted, logged once): they count as silence, the drives never follow them.
* The session is a zenoh client of ``--connect`` (default: from the TOML: ``[drives.remote] connect``, else the
  NC's ``[zenoh] connect``, else its listen endpoints), opened in the background and retried until it is open:
  the drives run (and time out) with or without it.

Exit codes: 0 stopped by a signal, 2 bad arguments or configuration.

It may import: numpy, msgpack, zenoh, nc_schema, nc_server.core.params, nc_server.drives.
"""
from __future__ import annotations

import argparse
import json
import logging
import os
import signal
import sys
import threading
import time
import tomllib
from pathlib import Path
from typing import Any, Mapping, Sequence

import msgpack
import numpy as np
import zenoh
from zenoh.handlers import RingChannel

from ...core.params import AxisParams, ConfigError
from ..cia402.device import Cia402Device
from ..cia402.drive import axis_options as cia402_axis_options
from ..cia402.objects import State
from . import wire
from .config import (DEFAULT_LEASE_MS, DEFAULT_TAKEOVER_CYCLES, RemoteOptions, check_timeout, host_slots, link_endpoints,
                     pair_default_timeout, parse_options)
from .link import link_config, open_retrying

log = logging.getLogger("nc_drive_sim")

DEFAULT_CYCLE = 0.001
DEFAULT_TIMEOUT = 0.1  # (= config.DEFAULT_TIMEOUT)
DEFAULT_EXTRAPOLATE = 0.01
#: Status key and file period [s].
STATUS_PERIOD = 0.1
#: More than this many drive cycles late: the loop resynchronises (counted in ``overruns``) instead of catching up.
MAX_LATE_CYCLES = 5


class _Zenoh:
    """Minimal settings the config helpers need (listen, connect, lease_ms, tls_dir)."""

    def __init__(self, listen: Sequence[str], connect: Sequence[str]) -> None:
        self.listen, self.connect = tuple(listen), tuple(connect)


def load_axes(path: str, host: str) -> tuple[str, list[AxisParams], list[int], tuple[str, ...]]:
    """The NC name, the parameters and AxisIds (slot order) of the axes ``host`` serves, and the endpoints to
    connect to (empty: the TOML names none), from the NC's TOML (:func:`load_config` with the timing too).

    Raises:
        ConfigError: unreadable file, bad TOML, no axis on ``host``, bad Drive tables or parameters.
    """
    name, params, ids, endpoints, _, _ = load_config(path, host)
    return name, params, ids, endpoints


def load_config(path: str, host: str) -> tuple[str, list[AxisParams], list[int], tuple[str, ...], float | None,
                                               tuple[int, float, float] | None]:
    """:func:`load_axes` plus the TOML's ``[drives.remote] timeout_ms`` [s] (None: not given) and, with
    ``[redundancy] enabled``, the pair's ``(takeover_cycles, [nc] cycle_time, [zenoh] lease [s])`` (None: no
    redundancy).

    Raises:
        ConfigError: as :func:`load_axes`; a bad ``[redundancy]`` or ``[nc] cycle_time``.
    """
    try:
        data = tomllib.loads(Path(path).read_text(encoding="utf-8"))
    except OSError as exc:
        raise ConfigError(path, exc.strerror or str(exc)) from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(path, f"invalid TOML: {exc}") from None
    nc = data.get("nc", {})
    name = nc.get("name", "nc1") if isinstance(nc, Mapping) else "nc1"
    drives = data.get("drives", {})
    if not isinstance(drives, Mapping):
        raise ConfigError("drives", "must be a table")
    opts: RemoteOptions = parse_options(drives.get("remote", {}))
    zn = data.get("zenoh", {})
    zs = _Zenoh(zn.get("listen", ["tcp/127.0.0.1:7447"]), zn.get("connect", [])) if isinstance(zn, Mapping) \
        else _Zenoh(["tcp/127.0.0.1:7447"], [])
    tables = data.get("axis", [])
    if not isinstance(tables, list):
        raise ConfigError("axis", "must be an array of [[axis]] tables")
    mine: list[tuple[int, Mapping[str, Any]]] = []
    for i, t in enumerate(tables):
        if not isinstance(t, Mapping):
            raise ConfigError(f"axis[{i}]", "must be a table")
        d = t.get("Drive")
        if isinstance(d, Mapping) and d.get("backend") == "remote":
            mine.append((i, t))
    if not mine:
        raise ConfigError(f"{path}: axis", "no axis with Drive = { backend = \"remote\", ... }")
    # (mode and kv concern the NC's side: the mode travels in the outputs; checked as the NC checks them)
    opts_list = [cia402_axis_options({k: v for k, v in t["Drive"].items() if k != "backend"}, f"axis[{i}].Drive")[2]
                 for i, t in mine]
    hosts = host_slots(opts_list, [int(t.get("AxisId", 0)) for _, t in mine],
                       [f"axis[{i}].Drive" for i, _ in mine])
    hs = next((h for h in hosts if h.host == host), None)
    if hs is None:
        raise ConfigError(f"{path}: axis", f"no axis with Drive.host = {host!r} (hosts: "
                                           f"{', '.join(h.host for h in hosts)})")
    params = []
    for row in hs.rows:
        i, t = mine[row]
        p = {k: v for k, v in t.items() if k not in ("AxisId", "Name", "ClientLossReaction", "Drive")}
        params.append(AxisParams.from_mapping(p, where=f"axis[{i}]"))
    try:
        endpoints = link_endpoints(opts, zs)
    except ConfigError:  # nothing to derive them from: --connect must say it
        endpoints = ()
    return name, params, list(hs.ids), endpoints, \
        None if opts.timeout_ms is None else opts.timeout_ms / 1000.0, _redundancy(data)


def _redundancy(data: Mapping[str, Any]) -> tuple[int, float, float] | None:
    """``(takeover_cycles, cycle_time, lease [s])`` of the TOML's ``[redundancy]`` if enabled (checked as the NC
    checks them)."""
    r = data.get("redundancy", {})
    if not isinstance(r, Mapping) or r.get("enabled") is not True:
        return None
    cycles = r.get("takeover_cycles", DEFAULT_TAKEOVER_CYCLES)
    if isinstance(cycles, bool) or not isinstance(cycles, int) or not 2 <= cycles <= 100_000:
        raise ConfigError("redundancy.takeover_cycles", f"must be an integer 2..100000, got {cycles!r}")
    nc = data.get("nc", {})
    ct = nc.get("cycle_time", 0.001) if isinstance(nc, Mapping) else 0.001
    if isinstance(ct, bool) or not isinstance(ct, (int, float)) or not 0.0001 <= ct <= 1.0:
        raise ConfigError("nc.cycle_time", f"must be a number 0.0001..1 [s], got {ct!r}")
    zn = data.get("zenoh", {})
    lease = zn.get("lease", DEFAULT_LEASE_MS) if isinstance(zn, Mapping) else DEFAULT_LEASE_MS
    if isinstance(lease, bool) or not isinstance(lease, int) or not 100 <= lease <= 600_000:
        raise ConfigError("zenoh.lease", f"must be an integer 100..600000 [ms], got {lease!r}")
    return cycles, float(ct), lease / 1000.0


class DriveHost:
    """The drives of one host and their exchange with the NC.

    Args:
        nc: the NC's name; host: this host's name.
        params: per slot the axis parameters (Sim*, AxisDec, encoder scaling).
        ids: per slot the AxisId the NC must name (0: not checked).
        cycle_time: the drive cycle [s]; timeout: the silence timeout [s]; extrapolate: the longest extrapolation [s].
        connect: endpoints (None: no session, e.g. a test of the loop); lease_ms, tls_dir: the session's.
        status_file: where the JSON status goes (None: nowhere).
    """

    def __init__(self, nc: str, host: str, params: Sequence[AxisParams], ids: Sequence[int], cycle_time: float,
                 timeout: float, extrapolate: float, connect: Sequence[str] | None, lease_ms: int = 500,
                 tls_dir: str | None = None, status_file: str | None = None) -> None:
        self.nc, self.host = nc, wire.check_host(host)
        self.n = len(params)
        self.ids = np.asarray(ids, dtype=np.uint32)
        self.cycle_time, self.timeout, self.extrapolate = cycle_time, timeout, min(extrapolate, timeout)
        self.device = Cia402Device(self.n, cycle_time, timeout=timeout)
        for i, p in enumerate(params):
            self.device.configure(i, p)
        self.status_file = status_file
        self.cycle = 0
        self.rx_cycle = 0          # the NC cycle of the outputs in effect
        self.rx_count = 0
        self.refused = 0
        self.epoch = 0             # the highest NC epoch seen: outputs of a lower one are refused
        self.stale_epoch = 0       # outputs refused for their epoch
        self.takeovers = 0         # epochs followed (the first one included)
        self.overruns = 0
        self.takeover_limit_ms = 0.0  # the NC's takeover limit, as its outputs say (0: no redundancy)
        self.timeout_short = False  # the silence timeout is not longer than that limit (warned once)
        self.bad_diagnostics = 0    # outputs whose diagnostic fields (takeover_limit_ms) were ignored as malformed
        self.silent_logged = True  # (nothing to report before the first outputs)
        self._last_tp = np.zeros(self.n)
        self._last_tv = np.zeros(self.n)
        self._stop = threading.Event()
        self._ready = False
        self._session: zenoh.Session | None = None
        self._rx_sub: Any = None
        self._tx_pub: Any = None
        self._status_pub: Any = None
        self._token: Any = None
        self._connect = tuple(connect) if connect is not None else None
        self._lease, self._tls = lease_ms, tls_dir
        self._opener: threading.Thread | None = None
        self._thread: threading.Thread | None = None
        self._stopped_logged = True

    # ---- session ------------------------------------------------------------------------------------
    def _declare(self, s: zenoh.Session) -> None:
        self._rx_sub = s.declare_subscriber(wire.rx_key(self.nc, self.host), RingChannel(8))
        self._tx_pub = s.declare_publisher(wire.tx_key(self.nc, self.host), congestion_control=zenoh.CongestionControl.DROP,
                                           priority=zenoh.Priority.REAL_TIME)
        self._status_pub = s.declare_publisher(wire.status_key(self.nc, self.host))
        self._token = s.liveliness().declare_token(wire.alive_key(self.nc, self.host))
        self._session = s
        self._ready = True
        log.info("connected: serving %d axes of %s as %s", self.n, self.nc, wire.prefix(self.nc, self.host))

    def start(self) -> None:
        """Start the drive loop and the session opener (returns at once)."""
        if self._connect is not None:
            eps, lease, tls, ident = self._connect, self._lease, self._tls, self.host
            self._opener = open_retrying(lambda: link_config(eps, lease, tls, ident), self._stop,
                                         f"drive host {self.host}", self._declare)
        self._thread = threading.Thread(target=self._run, name=f"drives-{self.host}", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """End the loop, write the last status, undeclare and close the session (idempotent)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)
        if self._opener is not None:
            self._opener.join(2.0)
        self._ready = False
        s, self._session = self._session, None
        if s is not None and not s.is_closed():
            try:
                if self._token is not None:
                    self._token.undeclare()
                s.close()
            except Exception as exc:
                log.warning("close: %s", exc)

    # ---- the drive cycle ------------------------------------------------------------------------------
    def _run(self) -> None:
        period = self.cycle_time
        next_t = time.monotonic()
        next_status = next_t
        while not self._stop.is_set():
            self.step_once()
            now = time.monotonic()
            if now >= next_status:
                self.write_status()
                next_status = now + STATUS_PERIOD
            next_t += period
            late = now - next_t
            if late > MAX_LATE_CYCLES * period:
                self.overruns += 1
                next_t = now
            elif late < 0:
                self._stop.wait(-late)
        self.write_status()

    def _take_rx(self) -> Any:
        """The newest usable outputs that arrived since the last cycle (None: none). Outputs of an NC epoch below the
        highest seen are refused (a replaced NC: docs/standby.md); a higher epoch is followed from then on."""
        if not self._ready:
            return None
        best = None
        while True:
            try:
                s = self._rx_sub.try_recv()
            except Exception:
                break
            if s is None:
                break
            try:
                msg = wire.decode_rx(s.payload.to_bytes())
            except wire.WireError as exc:
                self._refuse(f"malformed outputs: {exc}")
                continue
            # checked before its epoch counts: outputs of a misconfigured NC with a higher epoch must not lock out
            # the right one
            if len(msg.ids) != self.n:
                self._refuse(f"outputs for {len(msg.ids)} slots, this host has {self.n}")
                continue
            if self.ids.any() and msg.ids.any() and not np.array_equal(msg.ids, self.ids):
                self._refuse(f"outputs for AxisIds {msg.ids.tolist()}, this host serves {self.ids.tolist()}")
                continue
            if msg.epoch < self.epoch:
                self.stale_epoch += 1
                if self.stale_epoch <= 3 or self.stale_epoch % 10000 == 0:
                    log.warning("refused outputs of NC epoch %d (following epoch %d; %d refused)", msg.epoch,
                                self.epoch, self.stale_epoch)
                continue
            if msg.epoch > self.epoch:
                if self.rx_count:
                    log.warning("NC epoch %d takes over from epoch %d", msg.epoch, self.epoch)
                self.epoch = msg.epoch
                self.takeovers += 1
            best = msg  # (the newest of the highest epoch: the ring keeps arrival order)
        return best

    def _takeover_limit(self, limit_ms: float) -> None:
        """The NC's outputs name its takeover limit: a silence timeout not longer is warned about once per value."""
        self.takeover_limit_ms = limit_ms
        short = limit_ms > 0 and not self.timeout * 1e3 > limit_ms
        if short and not self.timeout_short:
            log.warning("the silence timeout (%g ms, --timeout) is not longer than the takeover limit of %s's "
                        "hot-standby pair (%g ms): a takeover will find the drives stopped (0x8130); start with a "
                        "longer --timeout", self.timeout * 1e3, self.nc, limit_ms)
        self.timeout_short = short

    def _refuse(self, why: str) -> None:
        self.refused += 1
        if self.refused <= 3 or self.refused % 10000 == 0:
            log.error("refused %d: %s", self.refused, why)
        return None

    def step_once(self) -> None:
        """One drive cycle: the newest outputs (or the extrapolated target), the devices, the inputs out."""
        dev = self.device
        msg = self._take_rx()
        if msg is not None:
            rx = msg.image
            self._last_tp, self._last_tv = rx.target_position.copy(), rx.target_velocity.copy()
            if self.silent_logged and self.rx_count:
                log.info("outputs again from NC cycle %d (the drives keep their fault until a reset)", rx.cycle)
            self.silent_logged = False
            self.rx_cycle = int(rx.cycle)
            self.rx_count += 1
            if msg.takeover_limit_ms is None:  # (a diagnostic: the outputs are used, the value is not)
                self.bad_diagnostics += 1
                if self.bad_diagnostics <= 3 or self.bad_diagnostics % 10000 == 0:
                    log.warning("outputs with a malformed takeover_limit_ms (ignored; %d so far)", self.bad_diagnostics)
            elif msg.takeover_limit_ms != self.takeover_limit_ms:
                self._takeover_limit(msg.takeover_limit_ms)
            tx = dev.step(rx)
        else:
            if self.rx_count and dev.silent + self.cycle_time < self.extrapolate:
                # between two NC outputs: the target moves on with the NC's target velocity
                dev.rx.target_position = self._last_tp + self._last_tv * (dev.silent + self.cycle_time)
            tx = dev.step(None)
            if not self.silent_logged and self.rx_count and dev.silent >= self.timeout:
                self.silent_logged = True
                self._stopped_logged = False
                log.warning("no outputs from %s for %.0f ms: communication fault 0x8130, quick stop", self.nc,
                            dev.silent * 1e3)
        if not self._stopped_logged and not dev.velocity.any():
            self._stopped_logged = True
            log.warning("stopped: positions [inc] %s", ", ".join(f"{p:.3f}" for p in dev.position))
        self.cycle += 1
        if self._ready:
            try:
                self._tx_pub.put(wire.encode_tx(tx, self.cycle, self.rx_cycle, self.epoch))
            except Exception as exc:  # the session closing
                log.debug("put: %s", exc)

    # ---- status -----------------------------------------------------------------------------------------
    def status(self) -> dict[str, Any]:
        """What the host shows: its counters and per slot the drive's state, statusword, 0x603F and motion."""
        dev = self.device
        tx = dev.tx
        return {
            "nc": self.nc, "host": self.host, "time": time.time(), "cycle": self.cycle, "connected": self._ready,
            "rx_cycle": self.rx_cycle, "rx_count": self.rx_count, "silent_s": round(dev.silent, 6),
            "nc_silent": bool(self.rx_count == 0 or dev.silent >= self.timeout), "refused": self.refused,
            "overruns": self.overruns, "epoch": self.epoch, "stale_epoch": self.stale_epoch,
            "timeout_s": self.timeout, "takeover_limit_ms": self.takeover_limit_ms, "timeout_short": self.timeout_short,
            "bad_diagnostics": self.bad_diagnostics,
            "axes": [{"slot": i, "AxisId": int(self.ids[i]), "state": State(int(dev.state[i])).name,
                      "statusword": int(tx.statusword[i]), "error_code": int(dev.error_code[i]),
                      "position": float(dev.position[i]), "velocity": float(dev.velocity[i])}
                     for i in range(self.n)],
        }

    def write_status(self) -> None:
        st = self.status()
        if self._ready and self._status_pub is not None:
            try:
                self._status_pub.put(msgpack.packb(st))
            except Exception:
                pass
        if self.status_file:
            tmp = f"{self.status_file}.tmp"
            try:
                with open(tmp, "w", encoding="utf-8") as f:
                    json.dump(st, f)
                os.replace(tmp, self.status_file)
            except OSError as exc:
                log.warning("status file: %s", exc)


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="nc-drive-sim", description="Simulated CiA 402 drives that an NC reaches "
                                "over zenoh (the NC's axes with Drive = { backend = \"remote\", host = ... }).")
    p.add_argument("--host", required=True, help="this drive host's name (Drive.host in the NC's TOML)")
    p.add_argument("--config", help="the NC's TOML: NC name, endpoints, the axes whose Drive.host is --host")
    p.add_argument("--nc", help="the NC's name (default: the TOML's [nc] name, else nc1)")
    p.add_argument("--axes", type=int, help="without --config: this many axes with default parameters "
                                            "(AxisIds not checked)")
    p.add_argument("--connect", action="append", help="zenoh endpoint to connect to (repeatable; default: from "
                                                      "the TOML, else tcp/127.0.0.1:7447)")
    p.add_argument("--cycle-time", type=float, default=DEFAULT_CYCLE, help="drive cycle [s] (0.001)")
    p.add_argument("--timeout", type=float, default=None,
                   help="silence timeout [s]: no outputs for this long -> fault 0x8130 and quick stop (default: the "
                        "TOML's [drives.remote] timeout_ms, else 0.1, for a hot-standby pair's TOML its longest "
                        "takeover + 0.1); longer than a hot-standby pair's longest takeover")
    p.add_argument("--extrapolate", type=float, default=DEFAULT_EXTRAPOLATE,
                   help="longest extrapolation of the target between outputs [s] (0.01)")
    p.add_argument("--lease-ms", type=int, default=500, help="the session's transport lease [ms] (500)")
    p.add_argument("--tls-dir", help="certificate directory: mutual TLS with <dir>/<host>.pem")
    p.add_argument("--status-file", help="write the status as JSON here every 100 ms")
    p.add_argument("--log-level", default="INFO", help="DEBUG, INFO (default), WARNING, ERROR")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """``nc-drive-sim``: see the module docstring. Returns the exit code."""
    args = _parser().parse_args(argv)
    logging.basicConfig(level=getattr(logging, str(args.log_level).upper(), logging.INFO),
                        format="%(asctime)s nc-drive-sim %(levelname)s %(message)s", stream=sys.stderr)
    try:
        wire.check_host(args.host, "--host")
        toml_timeout: float | None = None
        pair: tuple[int, float, float] | None = None
        if args.config:
            if args.axes is not None:
                raise ConfigError("--axes", "give either --config or --axes")
            nc, params, ids, endpoints, toml_timeout, pair = load_config(args.config, args.host)
        else:
            if args.axes is None or not 1 <= args.axes <= 4096:
                raise ConfigError("--axes", "give --config (the NC's TOML) or --axes N (1..4096)")
            nc, params, ids, endpoints = "nc1", [AxisParams() for _ in range(args.axes)], [0] * args.axes, \
                ("tcp/127.0.0.1:7447",)
        nc = args.nc or nc
        timeout_key = "--timeout" if args.timeout is not None else \
            "drives.remote.timeout_ms" if toml_timeout is not None else f"--timeout (default {DEFAULT_TIMEOUT:g} s)"
        # (a hot-standby pair's takeover may take up to a second under load: its default is longer, docs/standby.md)
        default = DEFAULT_TIMEOUT if pair is None else pair_default_timeout(*pair)
        if args.timeout is None and toml_timeout is None and pair is not None:
            timeout_key = f"--timeout (default for this pair {default:g} s)"
        args.timeout = args.timeout if args.timeout is not None else \
            toml_timeout if toml_timeout is not None else default
        # (the timeout's errors name where it came from: --timeout, the TOML's timeout_ms, or the default)
        for name, v, lo, hi in (("--cycle-time", args.cycle_time, 1e-4, 1.0), (timeout_key, args.timeout, 1e-3, 3600.0),
                                ("--extrapolate", args.extrapolate, 0.0, 3600.0)):
            if not lo <= v <= hi:
                raise ConfigError(name, f"must be within {lo:g}..{hi:g} s, got {v:g} s")
        if args.timeout < 2 * args.cycle_time:
            raise ConfigError(timeout_key, f"the silence timeout ({args.timeout:g} s) must be at least two drive "
                                           f"cycles ({2 * args.cycle_time:g} s, --cycle-time)")
        if pair is not None:  # a hot-standby pair (the TOML's [redundancy]): the timeout must outlast its takeover
            check_timeout(args.timeout, pair[0], pair[1], timeout_key, pair[2])
        if args.connect:
            endpoints = tuple(args.connect)
        if not endpoints:
            raise ConfigError("--connect", "missing: the NC's TOML names no endpoint to connect to")
        link_config(endpoints, args.lease_ms, args.tls_dir, args.host)  # zenoh checks the endpoints now
    except (ConfigError, ValueError) as exc:
        print(f"nc-drive-sim: configuration error: {exc}", file=sys.stderr, flush=True)
        return 2
    except zenoh.ZError as exc:
        print(f"nc-drive-sim: configuration error: {exc}", file=sys.stderr, flush=True)
        return 2
    stop = threading.Event()

    def on_signal(signum: int, _frame: object) -> None:
        stop.set()

    for sig in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP):
        signal.signal(sig, on_signal)
    host = DriveHost(nc, args.host, params, ids, args.cycle_time, args.timeout, args.extrapolate, endpoints,
                     args.lease_ms, args.tls_dir, args.status_file)
    host.start()
    print(f"nc-drive-sim {args.host} ready: {len(params)} axes of {nc} (AxisIds {', '.join(map(str, ids))}), "
          f"cycle {args.cycle_time * 1e3:g} ms, timeout {args.timeout * 1e3:g} ms, connecting to "
          f"{', '.join(endpoints)}", flush=True)
    try:
        while not stop.wait(0.5):
            pass
    finally:
        host.stop()
    log.info("stopped after %d drive cycles", host.cycle)
    return 0


if __name__ == "__main__":
    sys.exit(main())
