"""nc-status: a live table of every NC on a router, like ``halcmd show`` or TwinCAT's online view.

Per NC: alive or gone, cycle, its instance id (the NC process's token ``nc/<nc>/alive/<instance>``;
None for an older NC), the restarts seen (new NC instances: another instance id, or the cycle counter
going back in its frames, ``nc_schema.NcInstance``; a liveliness token that goes and comes back is
none), the epoch of its status frames (protocol 5; frames of a lower epoch than the highest seen, a hot-standby
pair's old active NC's, are dropped and counted), cycle time, timing
mode, missed cycles / overruns, work p99, the clients (and their roles) and the claims; per axis:
AxisId, MotionState (PLCopen), AxisState, SetPos / ActPos / SetVelo, ErrorCode with its name
(errors.json) and the drive's own error code (CiA 402 0x603F, from the stats' drive_errors; shown as
"(drive 0x2310)" after the axis error), the claim holder, the source of the last command and the link to its drive
(stats drive_link: a CANopen node's NMT state, heartbeat age and missed TPDOs, a remote drive host's round trip and
input age, and the drive's own 0x603F and last EMCY code when it has one; shown on a line of its own below the
axis).

Usable over a slow link: it never subscribes to the 1 kHz ``nc/<nc>/frame``. It reads only

* liveliness ``nc/*/alive`` (which NCs exist; NCs are also found by their stats) and ``nc/*/alive/*``
  (each NC process's instance id),
* ``nc/*/status`` (the newest frame's bytes, about 10 per second),
* ``nc/*/stats`` (msgpack, every 100 ms),
* ``nc/*/claims`` (msgpack, on every change and every second; holders, clients with roles, the
  last command per axis). Without it (an older NC) claims and clients come from the stats.

Usage::

    nc-status --connect tcp/127.0.0.1:7447              # refreshing table (Ctrl-C ends)
    nc-status --connect tcp/127.0.0.1:7447 --once       # one snapshot, for scripts
    nc-status --connect tcp/127.0.0.1:7447 --once --json
    nc-status --connect tcp/127.0.0.1:7447 --json       # one JSON document per refresh, one per line

Exit status: 0; 1 with ``--once`` when no NC (or not every ``--nc``) was found; 2 when the router
cannot be reached.
"""
from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import signal
import sys
import threading
import time
from dataclasses import dataclass
from typing import Any, Callable, Sequence, TextIO

import zenoh

from nc_schema import (
    AxisState, FrameFlags, NcInstance, decode_frame, error_name, frame_header, motion_state, parse_alive_instance,
    unpack,
)

from .common import add_connection_args, axis_key, nc_of, open_session

PROG = "nc-status"
#: data older than this is shown as stale [s]
STALE_AFTER = 1.5
#: an NC without liveliness and without data for this long is dropped from the table [s]
FORGET_AFTER = 30.0
#: how long ``--once`` waits for ``nc/<nc>/claims`` once the rest is in (it comes every second) [s]
CLAIMS_GRACE = 1.3
_MOTION_PREFIX = "MC_AXISSTATE_"


@dataclass
class _Raw:
    """The newest payload of one key and when it arrived (monotonic [s])."""

    data: bytes
    t: float


class NcWatch:
    """Keeps the newest status, stats and claims payload of every NC seen on a session.

    Callbacks run on zenoh threads and only store bytes; :meth:`snapshot` decodes.

    Args:
        session: an open zenoh session.
        ncs: only these NC names (None: all).
    """

    def __init__(self, session: zenoh.Session, ncs: set[str] | None = None) -> None:
        self.session = session
        self.only = ncs
        self._lock = threading.Lock()
        self.alive: dict[str, bool] = {}
        self.alive_t: dict[str, float] = {}
        self.raw: dict[tuple[str, str], _Raw] = {}  # (nc, "status" | "stats" | "claims")
        self.first_seen: dict[str, float] = {}
        self.instances: dict[str, NcInstance] = {}  # the restart rule, fed by the status frames and tokens
        self._decl: list[Any] = []

    def start(self, discover_timeout: float = 2.0) -> None:
        """Subscribe, then ask the router which NCs are alive now (waits up to ``discover_timeout`` s)."""
        s = self.session
        for what in ("status", "stats", "claims"):
            self._decl.append(s.declare_subscriber(f"nc/*/{what}", self._on_data(what)))
        self._decl.append(s.declare_subscriber("nc/*/ha/status/*", self._on_ha))
        self._decl.append(s.liveliness().declare_subscriber("nc/*/alive", self._on_alive, history=True))
        self._decl.append(s.liveliness().declare_subscriber("nc/*/alive/*", self._on_instance, history=True))
        try:
            for r in s.liveliness().get("nc/*/alive", timeout=discover_timeout):
                if r.ok is not None:
                    self._set_alive(nc_of(r.ok.key_expr), True)
            for r in s.liveliness().get("nc/*/alive/*", timeout=discover_timeout):
                if r.ok is not None:
                    self._on_instance(r.ok)
        except Exception:  # the subscribers' history gives the same, only later
            pass

    def close(self) -> None:
        for d in self._decl:
            try:
                d.undeclare()
            except Exception:
                pass
        self._decl.clear()

    def _wanted(self, nc: str) -> bool:
        return bool(nc) and (self.only is None or nc in self.only)

    def _set_alive(self, nc: str, alive: bool) -> None:
        if not self._wanted(nc):
            return
        with self._lock:
            now = time.monotonic()
            self.alive[nc] = alive
            self.alive_t[nc] = now
            self.first_seen.setdefault(nc, now)

    def _on_alive(self, sample: zenoh.Sample) -> None:
        self._set_alive(nc_of(sample.key_expr), sample.kind != zenoh.SampleKind.DELETE)

    def _on_instance(self, sample: zenoh.Sample) -> None:
        """An NC process's instance token appeared (its DELETE says what ``nc/<nc>/alive``'s does)."""
        parsed = parse_alive_instance(sample.key_expr)
        if sample.kind == zenoh.SampleKind.DELETE or parsed is None or not self._wanted(parsed[0]):
            return
        with self._lock:
            self.instances.setdefault(parsed[0], NcInstance()).token(parsed[1])

    def _on_data(self, what: str) -> Callable[[zenoh.Sample], None]:
        def on_sample(sample: zenoh.Sample) -> None:
            nc = nc_of(sample.key_expr)
            if not self._wanted(nc):
                return
            now = time.monotonic()
            data = sample.payload.to_bytes()
            with self._lock:
                self.first_seen.setdefault(nc, now)
                if what == "status":
                    try:
                        h = frame_header(data)
                    except ValueError:  # (a bad frame: nc_view reports it)
                        h = None
                    # the epoch rule (protocol 5): a frame of a lower epoch than the NC's followed is an old active
                    # NC's of a hot-standby pair (after a link cut): not shown, counted
                    if h is not None and not self.instances.setdefault(nc, NcInstance()).take(h.Cycle, h.Epoch,
                                                                                               now)[0]:
                        return
                self.raw[(nc, what)] = _Raw(data, now)
        return on_sample

    def _on_ha(self, sample: zenoh.Sample) -> None:
        """A hot-standby node's status (``nc/<nc>/ha/status/<node>``): the standby's replication lag is there only."""
        nc = nc_of(sample.key_expr)
        if not self._wanted(nc):
            return
        node = str(sample.key_expr).rsplit("/", 1)[-1]
        with self._lock:
            self.raw[(nc, "ha:" + node)] = _Raw(sample.payload.to_bytes(), time.monotonic())

    # ---- reading -------------------------------------------------------------------------------
    def names(self) -> list[str]:
        """NC names seen so far (alive, gone or only by their data), sorted."""
        with self._lock:
            return sorted(self.first_seen)

    def has(self, nc: str, what: str) -> bool:
        with self._lock:
            return (nc, what) in self.raw

    def snapshot(self) -> dict[str, Any]:
        """Everything known now as a JSON-ready map ``{"time", "ncs": [...]}`` (see :func:`nc_view`)."""
        now = time.monotonic()
        with self._lock:
            names = sorted(self.first_seen)
            raw = dict(self.raw)
            alive = dict(self.alive)
            alive_t = dict(self.alive_t)
            restarts = {nc: (i.restarts, i.instance) for nc, i in self.instances.items()}
            stale = {nc: i.stale_frames for nc, i in self.instances.items()}
        views = []
        for nc in names:
            newest = max([r.t for (n, _), r in raw.items() if n == nc] + [alive_t.get(nc, 0.0)])
            if not alive.get(nc, False) and now - newest > FORGET_AFTER:
                continue
            n_restarts, instance = restarts.get(nc, (0, None))
            nodes = [r for (n, w), r in sorted(raw.items()) if n == nc and w.startswith("ha:")]
            views.append(nc_view(nc, alive.get(nc), raw.get((nc, "status")), raw.get((nc, "stats")),
                                 raw.get((nc, "claims")), now, n_restarts, instance, nodes, stale.get(nc, 0)))
        return {"time": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="milliseconds"), "ncs": views}


def _unpack(r: _Raw | None) -> dict[str, Any] | None:
    if r is None:
        return None
    try:
        v = unpack(r.data)
    except Exception:
        return None
    return v if isinstance(v, dict) else None


def _error(code: int) -> str | None:
    return None if not code else error_name(code)


def nc_view(nc: str, alive: bool | None, status: _Raw | None, stats: _Raw | None, claims: _Raw | None,
            now: float, restarts: int = 0, instance: str | None = None,
            ha_nodes: Sequence[_Raw] = (), stale_epoch: int = 0) -> dict[str, Any]:
    """One NC's row set, decoded from its newest payloads (any of them may be missing or malformed);
    ``restarts``: the new NC instances seen so far; ``instance``: the id of the NC process followed
    (None: no instance token seen, e.g. an older NC); ``stale_epoch``: status frames dropped for a lower epoch.

    Returns:
        ``{"name", "alive", "state", "age_s": {status, stats, claims}, "cycle", "epoch" (the status frame's Epoch,
        protocol 5: 0 without redundancy; None without a frame), "stale_epoch_frames", "instance", "restarts",
        "cycle_time", "timing",
        "missed_cycles", "overruns", "work_us_p99", "clients": {id: {"alive", "role"}}, "claims": {axis: id},
        "axes": [{"AxisId", "MotionState", "AxisState", "SetPos", "ActPos", "SetVelo", "ErrorCode",
        "ErrorName", "DriveErrorCode", "DriveLink", "Holder", "LastCommand"}], "problems": [str]}``; DriveErrorCode: the
        drive's own error code (CiA 402 0x603F, stats ``drive_errors``; 0: none or not reported); DriveLink: the
        figures of the link to its drive (stats ``drive_link``; None: no link, an in-process drive);
        ``"remote_couplings"``: per slave of a master on another NC, {"AxisId", "master", "state", "ratio", "age_us",
        "phase_err", "phase_err_max", "phase_bound", "measured", "within"} (stats ``remote_couplings``).
    """
    problems: list[str] = []
    st = _unpack(stats)
    if stats is not None and st is None:
        problems.append("stats: not a msgpack map")
    cl = _unpack(claims)
    if claims is not None and cl is None:
        problems.append("claims: not a msgpack map")
    frame = None
    if status is not None:
        try:
            frame = decode_frame(status.data)
        except ValueError as exc:
            problems.append(f"status: {exc}")
    if status is None and stats is not None:
        problems.append("no nc/<nc>/status yet (an NC without it is older than this tool: no axis table)")
    ages = {k: (None if r is None else round(now - r.t, 3)) for k, r in
            (("status", status), ("stats", stats), ("claims", claims))}
    cycle = epoch = None
    if frame is not None:
        cycle, epoch = int(frame[0]["Cycle"]), int(frame[0]["Epoch"])
    if st is not None and isinstance(st.get("cycle"), int):
        cycle = max(cycle or 0, st["cycle"])
    shutting = frame is not None and bool(int(frame[0]["Flags"]) & int(FrameFlags.ShuttingDown))
    if alive is False or shutting:
        state = "GONE"
    elif status is None and stats is None:
        state = "NO DATA"
    elif min(a for a in (ages["status"], ages["stats"]) if a is not None) > STALE_AFTER:
        state = "STALE"
    else:
        state = "ALIVE"

    # claims and clients: nc/<nc>/claims when the NC publishes it, else the stats
    holders: dict[str, str] = {}
    clients: dict[str, dict[str, Any]] = {}
    last: dict[str, Any] = {}
    if cl is not None:
        for a, c in (cl.get("claims") or {}).items():
            holders[axis_key(a)] = str(c)
        for c, info in (cl.get("clients") or {}).items():
            info = info if isinstance(info, dict) else {}
            clients[str(c)] = {"alive": info.get("alive"), "role": info.get("role")}
        for a, lc in (cl.get("last_command") or {}).items():
            if isinstance(lc, dict):
                last[axis_key(a)] = {"client": lc.get("client"), "cmd": lc.get("cmd"), "cycle": lc.get("cycle")}
    elif st is not None:
        for a, c in (st.get("claims") or {}).items():
            holders[axis_key(a)] = str(c)
        for c in st.get("clients") or []:
            clients[str(c)] = {"alive": True, "role": None}

    drive_errors: dict[str, int] = {}  # the drives' own codes (CiA 402 0x603F) from the stats
    de = st.get("drive_errors") if st is not None else None
    if isinstance(de, dict):
        for a, c in de.items():
            if isinstance(c, int) and not isinstance(c, bool):
                drive_errors[axis_key(a)] = c
    elif de is not None:
        problems.append("stats: drive_errors is not a map")
    remote = _remote_couplings(st.get("remote_couplings") if st is not None else None, problems)
    links: dict[str, dict[str, Any]] = {}  # the links to the drives (CANopen, remote) from the stats
    dl = st.get("drive_link") if st is not None else None
    if isinstance(dl, dict):
        for a, f in dl.items():
            if isinstance(f, dict):
                links[axis_key(a)] = f
    elif dl is not None:
        problems.append("stats: drive_link is not a map")
    axes = []
    if frame is not None:
        for r in frame[1]:
            aid = int(r["AxisId"])
            code = int(r["ErrorCode"])
            try:
                axis_state = AxisState(int(r["AxisState"])).name
            except ValueError:
                axis_state = str(int(r["AxisState"]))
            axes.append({
                "AxisId": aid,
                "MotionState": motion_state(int(r["StateDWord"]), int(r["CoupleState"])).name,
                "AxisState": axis_state,
                "SetPos": float(r["SetPos"]), "ActPos": float(r["ActPos"]), "SetVelo": float(r["SetVelo"]),
                "ErrorCode": code, "ErrorName": _error(code),
                "DriveErrorCode": drive_errors.get(str(aid), 0),
                "DriveLink": links.get(str(aid)),
                "Holder": holders.get(str(aid)),
                "LastCommand": last.get(str(aid)),
            })
    get = (st or {}).get
    return {
        "name": nc, "alive": alive, "state": state, "age_s": ages, "cycle": cycle, "epoch": epoch,
        "stale_epoch_frames": stale_epoch, "instance": instance, "restarts": restarts,
        "cycle_time": get("cycle_time"), "timing": get("timing"),
        "missed_cycles": get("missed_cycles"), "overruns": get("overruns"), "work_us_p99": get("work_us_p99"),
        "clients": clients, "claims": holders, "claims_source": "claims" if cl is not None else
        ("stats" if st is not None else None), "axes": axes, "problems": problems, "remote_couplings": remote,
        "ha": _ha(st, ha_nodes, now),
    }


def _remote_couplings(rc: Any, problems: list[str]) -> list[dict[str, Any]]:
    """The stats' ``remote_couplings`` (protocol 4: slaves of masters on other NCs) as a list by slave AxisId."""
    if rc is None:
        return []
    if not isinstance(rc, dict):
        problems.append("stats: remote_couplings is not a map")
        return []
    out = []
    for a, v in sorted(rc.items(), key=lambda kv: str(kv[0])):
        if isinstance(v, dict):
            out.append({"AxisId": axis_key(a), **{k: v.get(k) for k in (
                "master", "state", "ratio", "age_us", "phase_err", "phase_err_max", "phase_bound", "measured", "within")}})
    return out


def _ha(st: dict[str, Any] | None, nodes: Sequence[_Raw] = (), now: float = 0.0) -> dict[str, Any] | None:
    """The hot-standby part of the stats (docs/standby.md: role, epoch, takeovers), or None; with ``nodes``: the
    other nodes' ha status (``nc/<nc>/ha/status/<node>``, newer than STALE_AFTER): node, role, in_step, lag_cycles
    (the replication lag is the standby's figure: the active NC's stats do not have it)."""
    ha = st.get("ha") if st is not None else None
    if not isinstance(ha, dict):
        return None
    keys = ("node", "role", "epoch", "peer_in_step", "lag_cycles", "takeovers", "takeover_ms", "demotions")
    out: dict[str, Any] = {k: ha.get(k) for k in keys}
    peers = []
    for r in nodes:
        d = _unpack(r)
        if d is None or d.get("node") == out["node"] or now - r.t > STALE_AFTER:
            continue
        peers.append({k: d.get(k) for k in ("node", "role", "in_step", "lag_cycles")})
        if d.get("refused"):  # (a standby that will not get in step: other NC software, docs/standby.md)
            peers[-1]["refused"] = d["refused"]
    out["standbys"] = peers
    return out


# ---- text ----------------------------------------------------------------------------------------
def link_text(f: dict[str, Any]) -> str:
    """One line for the figures of a drive's link (stats ``drive_link``)."""
    def v(k: str, fmt: str = "") -> str:
        x = f.get(k)
        return "-" if x is None else format(x, fmt) if fmt and isinstance(x, (int, float)) else str(x)
    def code(k: str, what: str) -> str:  # the drive's own codes (0x603F, EMCY): shown when there is one
        x = f.get(k)
        return f", {what} 0x{x:04X}" if isinstance(x, int) and not isinstance(x, bool) and x else ""
    kind = f.get("link")
    drive = code("error_code", "drive error") + code("emcy", "EMCY")
    if kind == "canopen":
        return (f"canopen node {v('node_id')} {v('nmt')} ({v('monitoring')} {v('heartbeat_age_ms', '.0f')} ms ago"
                f"{'' if f.get('alive') else ', LOST'}), TPDOs late {v('tpdo_late')} missed {v('tpdo_missed')}, "
                f"set-ups {v('setups')}, bus tx errors {v('tx_errors')}{drive}")
    if kind == "remote":
        return (f"remote host {v('host')}{'' if f.get('alive') else ' LOST'}, round trip {v('round_trip')} cycles, "
                f"input age {v('age')} cycles{drive}")
    if kind == "local":
        return f"in-process drive{drive}"
    return ", ".join(f"{k} {x}" for k, x in sorted(f.items()))


def _num(v: Any, fmt: str, none: str = "-") -> str:
    return none if v is None else format(v, fmt)


def render(snap: dict[str, Any]) -> str:
    """The snapshot as a text table (no escape codes)."""
    out: list[str] = []
    if not snap["ncs"]:
        return f"{snap['time']}  no NC seen yet\n"
    for v in snap["ncs"]:
        ct = v["cycle_time"]
        out.append(f"{v['name']}  {v['state']}  cycle {_num(v['cycle'], 'd')}  "
                   f"{_num(None if ct is None else ct * 1e3, '.3f')} ms  {v['timing'] or '-'}  "
                   f"missed {_num(v['missed_cycles'], 'd')}  overruns {_num(v['overruns'], 'd')}  "
                   f"work p99 {_num(v['work_us_p99'], '.0f')} us  instance {v['instance'] or '-'}  "
                   f"restarts {v['restarts']}  epoch {_num(v.get('epoch'), 'd')}"
                   + (f" ({v['stale_epoch_frames']} frames of lower epochs dropped)" if v.get("stale_epoch_frames")
                      else ""))
        ha = v.get("ha")
        if ha:
            out.append(f"  ha: {ha.get('role')} node {ha.get('node')} epoch {ha.get('epoch')}  standby in step "
                       f"{'yes' if ha.get('peer_in_step') else 'no'}  takeovers {ha.get('takeovers')} (last "
                       f"{ha.get('takeover_ms')} ms)  demotions {ha.get('demotions')}"
                       + "".join(f"  {p.get('role')} {p.get('node')} lag {p.get('lag_cycles')} cycles"
                                 f"{'' if p.get('in_step') else ' (not in step)'}"
                                 + (f" REFUSED: {p['refused']}" if p.get("refused") else "")
                                 for p in ha.get("standbys") or []))
        if v["clients"]:
            parts = []
            for c, info in sorted(v["clients"].items()):
                extra = [x for x in (info.get("role"), None if info.get("alive", True) else "gone") if x]
                parts.append(f"{c} ({', '.join(extra)})" if extra else c)
            out.append("  clients: " + ", ".join(parts))
        else:
            out.append("  clients: none")
        for p in v["problems"]:
            out.append(f"  ! {p}")
        if v["axes"]:
            out.append(f"  {'Axis':>4}  {'MotionState':<18} {'AxisState':<19} {'SetPos':>12} {'ActPos':>12} "
                       f"{'SetVelo':>10}  {'ErrorCode':<30} {'Holder':<12} Last command")
            for a in v["axes"]:
                err = "0" if not a["ErrorCode"] else f"0x{a['ErrorCode']:04X} {a['ErrorName']}"
                if a.get("DriveErrorCode"):
                    err += f" (drive 0x{a['DriveErrorCode']:04X})"
                lc = a["LastCommand"]
                lct = "-" if not lc else f"{lc.get('cmd')} by {lc.get('client')} @{lc.get('cycle')}"
                out.append(f"  {a['AxisId']:>4}  {a['MotionState'].removeprefix(_MOTION_PREFIX):<18} "
                           f"{a['AxisState']:<19} {a['SetPos']:>12.4f} {a['ActPos']:>12.4f} {a['SetVelo']:>10.3f}  "
                           f"{err:<30} {a['Holder'] or '-':<12} {lct}")
                if a.get("DriveLink"):
                    out.append(f"        drive link: {link_text(a['DriveLink'])}")
        else:
            out.append("  (no status frame yet)")
        for r in v.get("remote_couplings") or []:  # coupling across NCs (docs/coupling-across-ncs.md)
            n, w = r.get("measured") or 0, r.get("within") or 0
            out.append(f"  remote coupling: axis {r['AxisId']} <- {r.get('master')} x {_num(r.get('ratio'), 'g')}  "
                       f"AxisState {_num(r.get('state'), 'd')}  age {_num(r.get('age_us'), 'd')} us  "
                       f"phase error {_num(r.get('phase_err'), '.3g')} (max {_num(r.get('phase_err_max'), '.3g')}, "
                       f"bound {_num(r.get('phase_bound'), '.3g')}) u  within the bound {w}/{n}")
        out.append("")
    return "\n".join(out)


# ---- main --------------------------------------------------------------------------------------
def _complete(w: NcWatch, wanted: set[str] | None, started: float) -> bool:
    """--once: every NC (every wanted one) has status and stats, and claims or their grace passed."""
    names = w.names()
    if not names or (wanted is not None and not wanted <= set(names)):
        return False
    for nc in names:
        if not (w.has(nc, "status") and w.has(nc, "stats")):
            return False
        if not w.has(nc, "claims") and time.monotonic() - started < CLAIMS_GRACE:
            return False
    return True


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog=PROG, description="Live table of every zenoh-nc NC on a router.")
    add_connection_args(p, "zenoh router, e.g. tcp/127.0.0.1:7447")
    p.add_argument("--nc", action="append", metavar="NAME", help="only this NC (repeatable; default: all)")
    p.add_argument("--once", action="store_true", help="print one snapshot and exit")
    p.add_argument("--json", action="store_true", help="JSON instead of the table (one document per line)")
    p.add_argument("--interval", type=float, default=0.5, metavar="S", help="refresh period [s] (default 0.5)")
    p.add_argument("--timeout", type=float, default=10.0, metavar="S",
                   help="--once: how long to wait for the NCs' data [s] (default 10)")
    a = p.parse_args(argv)
    if a.interval <= 0 or a.timeout <= 0:
        p.error("--interval and --timeout must be > 0")
    return a


def main(argv: list[str] | None = None, out: TextIO | None = None) -> int:
    """Run nc-status; returns the exit status. As the program (``argv`` None) it ends with ``os._exit`` once its
    session is closed: the interpreter's own clean-up waited on zenoh's threads once (CI, under load, more than
    60 s after Ctrl-C), and there is nothing left for it to do."""
    rc = _main(argv, out)
    if argv is None:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(rc)
    return rc


def _main(argv: list[str] | None, out: TextIO | None) -> int:
    a = parse_args(argv)
    out = out or sys.stdout
    wanted = set(a.nc) if a.nc else None
    stop = threading.Event()
    prev = signal.signal(signal.SIGINT, lambda *_: stop.set())
    session = open_session(a.connect, PROG, a.tls_dir, a.client_id)
    w = NcWatch(session, wanted)
    try:
        started = time.monotonic()
        w.start()
        if a.once:
            deadline = started + a.timeout
            while not _complete(w, wanted, started) and time.monotonic() < deadline and not stop.is_set():
                time.sleep(0.02)
            snap = w.snapshot()
            out.write(json.dumps(snap) + "\n" if a.json else render(snap))
            out.flush()
            found = {v["name"] for v in snap["ncs"]}
            if not found or (wanted is not None and not wanted <= found):
                missing = sorted(wanted - found) if wanted else []
                print(f"{PROG}: no data from {', '.join(missing) or 'any NC'} on {a.connect} within {a.timeout:g} s",
                      file=sys.stderr)
                return 1
            return 0
        tty = out.isatty() and not a.json
        if tty:
            out.write("\x1b[H\x1b[2J")
        while not stop.is_set():
            snap = w.snapshot()
            if a.json:
                out.write(json.dumps(snap) + "\n")
            elif tty:  # home, each line cleared to its end, then the rest of the screen
                text = f"{PROG} {a.connect}  {snap['time']}\n\n" + render(snap)
                out.write("\x1b[H" + "\x1b[K\n".join(text.split("\n")) + "\x1b[J")
            else:
                out.write(f"--- {snap['time']}\n" + render(snap))
            out.flush()
            stop.wait(a.interval)
        if tty:
            out.write("\n")
        return 0
    except BrokenPipeError:  # e.g. piped into head
        return 0
    finally:
        signal.signal(signal.SIGINT, prev)
        _close_bounded(w, session)


#: How long nc-status waits for its zenoh session to close at exit [s].
CLOSE_TIMEOUT = 5.0


def _close_bounded(w: "NcWatch", session: Any) -> None:
    """Undeclare and close, but never hang the exit on it: once (in CI, under load) closing did not return
    within a minute after Ctrl-C. After CLOSE_TIMEOUT the process ends without waiting any longer."""
    def close() -> None:
        try:
            w.close()
        finally:
            try:
                session.close()
            except Exception:
                pass
    t = threading.Thread(target=close, daemon=True)
    t.start()
    t.join(CLOSE_TIMEOUT)
    if t.is_alive():
        print(f"{PROG}: the zenoh session did not close within {CLOSE_TIMEOUT:g} s; exiting anyway", file=sys.stderr)
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(0)


if __name__ == "__main__":
    sys.exit(main())
