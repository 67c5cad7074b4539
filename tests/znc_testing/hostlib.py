"""Helpers of the tests across hosts (tests/hosts/): a status client, PLC event logs, the checks.

The system under test is the one of ``deploy/compose.yaml`` (or the same processes in network
namespaces): a router, NCs ``nc1``/``nc2`` behind it, PLC clients running ``deploy/programs``:

* ``plc1`` holds nc1 axis 1 and nc2 axis 1; ``plc2`` holds nc1 axis 2 (and now and then commands
  nc1 axis 1). :data:`HOLDERS` says so.

What a test looks at:

* :class:`StatusClient`: a zenoh client session (explicit config: one endpoint, scouting off) that
  samples every NC's ``nc/<nc>/status`` (its newest frame, about 10 Hz; a ``RingChannel(1)`` polled
  by a thread) and asks each NC's ``Info`` (claims, clients) on demand.
* PLC event lines (``deploy/programs/shuttle.py``): ``<client> <unix time> <nc>:<axis> <event>``,
  parsed by :func:`parse_events` from ``docker logs`` or a process's stdout.
* :func:`motion_on_its_own`: the check "no axis moves on its own": after ``t0`` an axis that is at
  standstill must not move again before a PLC logged a new ``move ->`` for it.

Nothing here asserts speed: every wait is a condition with a generous deadline; times are
measured and printed.
"""
from __future__ import annotations

import dataclasses
import functools
import re
import shutil
import subprocess
import threading
import time
from collections import deque
from pathlib import Path
from typing import Any, Callable, Iterable

import msgpack
import numpy as np

from znc_testing.until import wait_until

ROOT = Path(__file__).resolve().parents[2]
BUILD_SH = ROOT / "deploy" / "images" / "build.sh"
#: Figures of this run (printed by conftest.py): "scenarios" rows {where, scenario, react_s, recover_s,
#: notes}, "builds" {seconds, log}.
FIGURES: dict[str, list[dict[str, Any]]] = {"scenarios": [], "builds": []}

#: (nc, axis) -> the client that holds it (claims it, supplies its PLCTONC).
HOLDERS: dict[tuple[str, int], str] = {("nc1", 1): "plc1", ("nc2", 1): "plc1", ("nc1", 2): "plc2"}
NCS = ("nc1", "nc2")
#: StateDWord bits.
BIT_CONTROL_LOOP_CLOSED = 1 << 20
BIT_ERROR = 1 << 31
#: |SetVelo| below this counts as standstill [u/s].
STANDSTILL = 1e-6
#: deadline of a reaction to a cut [s] (generous: a loaded 2-core machine)
REACT_TIMEOUT = 60.0
#: poll period of the waits across hosts [s] (their predicates may run docker or open sessions)
POLL = 0.05


def axes_of(client: str) -> list[tuple[str, int]]:
    """The (nc, axis) pairs ``client`` holds."""
    return sorted(k for k, v in HOLDERS.items() if v == client)


# ---- what can run here ----------------------------------------------------------------------
@functools.lru_cache(maxsize=1)
def compose_command() -> tuple[str, ...] | None:
    """``docker-compose`` (1.29, Debian's) or ``docker compose`` (v2), whichever works; None if neither."""
    for cmd in (["docker-compose"], ["docker", "compose"]):
        if shutil.which(cmd[0]) is None:
            continue
        try:
            if subprocess.run([*cmd, "version"], capture_output=True, timeout=300).returncode == 0:
                return tuple(cmd)
        except (OSError, subprocess.TimeoutExpired):
            continue
    return None


def docker_unavailable() -> str | None:
    """Why Docker tests cannot run here, or None."""
    if shutil.which("docker") is None:
        return "docker engine not reachable: no docker command"
    try:
        r = subprocess.run(["docker", "info", "--format", "{{.ServerVersion}}"], capture_output=True, text=True,
                           timeout=120)
    except (OSError, subprocess.TimeoutExpired) as exc:
        return f"docker engine not reachable: {exc}"
    if r.returncode != 0:
        return f"docker engine not reachable: {(r.stderr or r.stdout).strip().splitlines()[-1:]}"
    if compose_command() is None:
        return "docker engine reachable but no compose tool (docker-compose or docker compose)"
    return None


# ---- status client ---------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class AxisSample:
    """One axis in one sampled frame (wall time of reception [s])."""

    t: float
    nc: str
    cycle: int
    axis: int
    state: int
    error: int
    act_pos: float
    set_velo: float

    @property
    def enabled(self) -> bool:
        return bool(self.state & BIT_CONTROL_LOOP_CLOSED)

    @property
    def moving(self) -> bool:
        return abs(self.set_velo) > STANDSTILL


def client_config(endpoint: str, tls_dir: str | None = None, identity: str = "status") -> Any:
    """The observer's zenoh config: the project's client config (nc_schema.zenoh_config), lease
    1 s, as ``identity`` with ``tls_dir`` (its certificate ``<tls_dir>/<identity>.pem``)."""
    from nc_schema.zenoh_config import client_config as shared

    return shared(endpoint, 1000, tls_dir, identity)


def info_key(nc: str, client: str) -> str:
    """The key of an NC-level ``Info`` query: the read class's key where the schema has classes."""
    from nc_schema.messages import Keys

    k = Keys(nc)
    return k.cmd("read", client) if callable(getattr(k, "cmd", None)) else k.cmd


class StatusClient:
    """Samples the NCs' frames through the router; ``info(nc)`` asks an NC who holds what.

    Args:
        endpoint: the router, e.g. ``tcp/127.0.0.1:7450``.
        ncs: NC names to watch.
        client_id: the id of this observer (its certificate's CN with TLS).
        tls_dir: certificate directory for mutual TLS as ``client_id`` (None: plain TCP).
        period: sampling period [s].
    """

    def __init__(self, endpoint: str, ncs: Iterable[str] = NCS, client_id: str = "status",
                 tls_dir: str | None = None, period: float = 0.02) -> None:
        import zenoh

        self.endpoint, self.ncs, self.client_id, self.period = endpoint, tuple(ncs), client_id, period
        self.samples: dict[tuple[str, int], deque[AxisSample]] = {}
        self.last_frame: dict[str, float] = {}  # nc -> wall time of the newest frame
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._ids = iter(range(1, 1 << 30))
        self.session = wait_until(lambda: zenoh.open(client_config(endpoint, tls_dir, client_id)), 60,
                                  f"a zenoh session to {endpoint}", interval=0.5)
        # nc/<nc>/status: the newest frame's bytes about 10 times a second (not the 1 kHz frame)
        self._subs = {nc: self.session.declare_subscriber(f"nc/{nc}/status", zenoh.handlers.RingChannel(1))
                      for nc in self.ncs}
        self._thread = threading.Thread(target=self._run, name="status-sampler", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        from nc_schema import decode_frame

        while not self._stop.wait(self.period):
            for nc, sub in self._subs.items():
                try:
                    s = sub.try_recv()
                except Exception:  # the session is closing
                    return
                if s is None:
                    continue
                t = time.time()
                try:
                    h, recs, _ = decode_frame(s.payload.to_bytes())
                except ValueError:
                    continue
                with self._lock:
                    self.last_frame[nc] = t
                    for r in recs:
                        key = (nc, int(r["AxisId"]))
                        self.samples.setdefault(key, deque(maxlen=50_000)).append(AxisSample(
                            t, nc, int(h["Cycle"]), key[1], int(r["StateDWord"]), int(r["ErrorCode"]),
                            float(r["ActPos"]), float(r["SetVelo"])))

    # -- reading ------------------------------------------------------------------------------
    def history(self, nc: str, axis: int, since: float = 0.0) -> list[AxisSample]:
        """Samples of one axis received at or after wall time ``since``."""
        with self._lock:
            return [s for s in self.samples.get((nc, axis), ()) if s.t >= since]

    def latest(self, nc: str, axis: int) -> AxisSample | None:
        with self._lock:
            d = self.samples.get((nc, axis))
            return d[-1] if d else None

    def frame_age(self, nc: str) -> float:
        """Seconds since the newest frame of ``nc`` (inf before the first)."""
        with self._lock:
            t = self.last_frame.get(nc)
        return float("inf") if t is None else time.time() - t

    def info(self, nc: str, timeout: float = 2.0) -> dict[str, Any] | None:
        """The NC's ``Info`` value (``claims`` {axis: client}, ``clients`` [...]), None without a reply."""
        req = {"id": next(self._ids), "cmd": "Info"}
        try:
            replies = self.session.get(info_key(nc, self.client_id), payload=msgpack.packb(req), timeout=timeout)
            for r in replies:
                if r.ok is not None:
                    rep = msgpack.unpackb(r.ok.payload.to_bytes(), raw=False, strict_map_key=False)
                    if rep.get("error") == 0:
                        v = rep.get("value", rep.get("Value"))
                        return v if isinstance(v, dict) else None
        except Exception:
            return None
        return None

    def claims(self, nc: str) -> dict[int, str] | None:
        v = self.info(nc)
        return None if v is None else {int(a): c for a, c in v.get("claims", {}).items()}

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5)
        try:
            self.session.close()
        except Exception:
            pass


# ---- the system's state ------------------------------------------------------------------------
def cell_ok(status: StatusClient, holders: dict[tuple[str, int], str] = HOLDERS,
            moved_since: float | None = None) -> bool | str:
    """True when every NC is seen, every axis of ``holders`` is claimed by its holder, enabled
    without error and (with ``moved_since``) has moved after that wall time; else what is missing.
    """
    missing = []
    for nc in sorted({nc for nc, _ in holders}):
        if status.frame_age(nc) > 1.0:
            missing.append(f"{nc} frames")
            continue
        claims = status.claims(nc)
        if claims is None:
            missing.append(f"{nc} Info")
            continue
        for (n, axis), client in holders.items():
            if n != nc:
                continue
            s = status.latest(nc, axis)
            if claims.get(axis) != client:
                missing.append(f"{nc}:{axis} claim {claims.get(axis)}!={client}")
            elif s is None or not s.enabled or s.state & BIT_ERROR:
                missing.append(f"{nc}:{axis} not enabled" if s is None or not s.enabled else f"{nc}:{axis} error 0x{s.error:X}")
            elif moved_since is not None and not any(x.moving for x in status.history(nc, axis, moved_since)):
                missing.append(f"{nc}:{axis} not moved yet")
    return True if not missing else ", ".join(missing)


def wait_plc_lost(st: Any, plc: str, holders: dict[tuple[str, int], str] = HOLDERS,
                  timeout: float = REACT_TIMEOUT) -> None:
    """Wait until the NCs dropped ``plc`` (not among their clients, none of its claims left) and
    its axes stand still (``st``: a :class:`StatusClient` or alike)."""
    mine = sorted(k for k, v in holders.items() if v == plc)

    def gone() -> bool | str:
        for nc in sorted({nc for nc, _ in mine}):
            info = st.info(nc)
            if info is None:
                return f"{nc} Info"
            claims = {int(a): c for a, c in info.get("claims", {}).items()}
            if plc in info.get("clients", []) or plc in claims.values():
                return f"{nc} still has {plc}: clients {info.get('clients')}, claims {claims}"
        for nc, axis in mine:
            s = st.latest(nc, axis)
            if s is None or s.moving or st.frame_age(nc) > 1.0:
                return f"{nc}:{axis} still moving or not seen"
        return True
    wait_until(gone, timeout, f"the NCs releasing {plc}'s claims and stopping its axes", interval=0.1)


def wait_nc_lost(st: Any, events: Callable[[], list["Event"]], ncs: Iterable[str], t_cut: float,
                 holders: dict[tuple[str, int], str] = HOLDERS, timeout: float = REACT_TIMEOUT) -> None:
    """Wait until no frames of ``ncs`` arrive and every PLC holding axes of them logged an error
    (its blocks saw the loss) after ``t_cut``."""
    ncs = list(ncs)
    wait_until(lambda: all(st.frame_age(nc) > 1.5 for nc in ncs), timeout, f"no frames of {', '.join(ncs)}",
               interval=POLL)
    users = {(c, nc) for (nc, _), c in holders.items() if nc in ncs}

    def reported() -> bool | str:
        ev = events()
        missing = [f"{c} on {nc}" for c, nc in sorted(users)
                   if not any(e.client == c for e in errors_after(ev, t_cut, nc))]
        return True if not missing else "no error event of " + ", ".join(missing)
    wait_until(reported, timeout, "the PLCs' blocks reporting the NC's loss", interval=0.5)


# ---- PLC events --------------------------------------------------------------------------------
_EVENT_RE = re.compile(r"^(?P<client>[\w.-]+) (?P<t>\d+\.\d+) (?P<nc>[\w.-]+):(?P<axis>\d+) (?P<event>.*)$")


@dataclasses.dataclass(frozen=True)
class Event:
    client: str
    t: float
    nc: str
    axis: int
    text: str


def parse_events(text: str) -> list[Event]:
    """The event lines of deploy/programs/shuttle.py in ``text`` (other lines are ignored)."""
    out = []
    for line in text.splitlines():
        m = _EVENT_RE.match(line.strip().split("| ", 1)[-1])
        if m:
            out.append(Event(m["client"], float(m["t"]), m["nc"], int(m["axis"]), m["event"]))
    return out


def errors_after(events: Iterable[Event], t0: float, nc: str | None = None) -> list[Event]:
    """``error 0x...`` events after wall time ``t0`` (of axes of ``nc`` if given)."""
    return [e for e in events if e.t >= t0 and e.text.startswith("error 0x") and (nc is None or e.nc == nc)]


#: a command logged this long [s] before the last moving sample still explains a later restart
#: (its reply and first frames can lag that much behind on a loaded machine)
COMMAND_SLACK = 0.5


def motion_on_its_own(samples: list[AxisSample], events: Iterable[Event], t0: float,
                      until: float = float("inf")) -> str | None:
    """The check "no axis moves on its own" for one axis, for restarts at or after wall time ``t0``.

    A stop ramp is fine; what is not: the axis at standstill, then moving again at a sample after
    ``t0``, with no ``move ->`` event for it (from any PLC) logged since the axis last moved (less
    :data:`COMMAND_SLACK`). So a move commanded before the cut and replayed after it is caught,
    also when the PLC that sent it is back. Pass samples from some seconds before ``t0``; samples
    after ``until`` are not judged (pass a time safely before the events were read: a PLC's
    newest lines reach ``docker logs`` later than its commands reach the NC).
    Returns a description of the first violation, or None.
    """
    if not samples:
        return None
    nc, axis = samples[0].nc, samples[0].axis
    commands = sorted(e.t for e in events if e.nc == nc and e.axis == axis and e.text.startswith("move ->"))
    last_moving = float("-inf")
    stood: AxisSample | None = None
    for s in samples:
        if s.t > until:
            break
        if not s.moving:
            stood = stood or s
            continue
        if stood is not None and s.t >= t0 and not any(last_moving - COMMAND_SLACK <= c <= s.t for c in commands):
            return (f"{nc}:{axis} stood still at {stood.t:.3f} (cycle {stood.cycle}) and moved at {s.t:.3f} "
                    f"(cycle {s.cycle}, SetVelo {s.set_velo:g}) without a command since it last moved "
                    f"({last_moving:.3f}; cut at {t0:.3f})")
        stood, last_moving = None, s.t
    return None


def numbers(values: Iterable[float]) -> str:
    """'min/median/max' of recovery times [s]."""
    v = sorted(values)
    return "-" if not v else f"{v[0]:.2f}/{float(np.median(v)):.2f}/{v[-1]:.2f}"
