"""Helpers of the fail-safe integration tests (test_failsafe_*.py): an NC configuration with a
ClientLossReaction per axis, a recorder of every NCTOPLC sample of chosen axes, and a client
process (``failsafe_client.py``) to kill or freeze.

Everything on 127.0.0.1, free ports, explicit zenoh configs; processes run in their own process
groups and are killed in ``finally`` by the tests.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any, Callable, Iterable

import numpy as np
import zenoh

from nc_schema import NCTOPLC_DTYPE
from znc_testing import BIT_CONTROL_LOOP_CLOSED, kill_process_group, zenoh_client_config

CLIENT = Path(__file__).resolve().parents[1] / "integration" / "failsafe_client.py"
#: deadline of every wait [s]: generous, a loaded 2-core machine
T = 30.0


def failsafe_config(reactions: Iterable[str], name: str = "nc1", watchdog: float | None = None) -> str:
    """An nc-server TOML with one linear axis per entry of ``reactions`` (AxisId 1..n, no soft
    limits, 500 u/s, 5000 u/s^2), each with that ClientLossReaction."""
    out = [f'[nc]\nname = "{name}"\ncycle_time = 0.001\n'
           + (f"watchdog_timeout = {watchdog}\n" if watchdog is not None else "")
           + '[zenoh]\nlisten = ["tcp/127.0.0.1:7447"]\n']
    for i, r in enumerate(reactions, 1):
        out.append(f'[[axis]]\nAxisId = {i}\nName = "A{i}"\nClientLossReaction = "{r}"\nAxisVeloMax = 500.0\n'
                   'AxisAcc = 5000.0\nAxisDec = 5000.0\nAxisJerk = 50000.0\nAxisMaxPosLagValue = 5.0\n'
                   'AxisTargetPositionWindow = 0.02\n')
    return "\n".join(out)


class Sample:
    __slots__ = ("t", "sd", "err", "velo", "pos", "cycle")

    def __init__(self, t: float, rec: np.void, cycle: int) -> None:
        self.t = t
        self.sd = int(rec["StateDWord"])
        self.err = int(rec["ErrorCode"])
        self.velo = float(rec["SetVelo"])
        self.pos = float(rec["SetPos"])
        self.cycle = cycle

    @property
    def enabled(self) -> bool:
        return bool(self.sd & BIT_CONTROL_LOOP_CLOSED)

    def __repr__(self) -> str:
        return f"Sample(t={self.t:.3f}, en={self.enabled}, err=0x{self.err:X}, v={self.velo:.3f}, p={self.pos:.3f})"


class AxisWatch:
    """Every NCTOPLC sample of ``axes`` (per-axis keys ``nc/<nc>/axis/<id>/nctoplc``), time-stamped
    on arrival (monotonic), from an observer session (no liveliness token).

    Args:
        port: the port of the NC (or of its router) on 127.0.0.1.
    """

    def __init__(self, port: int, axes: Iterable[int], nc: str = "nc1", clients: Iterable[str] = ()) -> None:
        self.session = zenoh.open(zenoh_client_config(port))
        self.samples: dict[int, list[Sample]] = {a: [] for a in axes}
        #: arrival times of the PLCTONC frames of ``clients`` (did a client itself stall?)
        self.frames: dict[str, list[float]] = {c: [] for c in clients}
        self._cv = threading.Condition()
        self._subs = [self.session.declare_subscriber(f"nc/{nc}/axis/{a}/nctoplc", self._on(a)) for a in self.samples]
        for c in self.frames:
            self._subs.append(self.session.declare_subscriber(f"nc/{nc}/plctonc/{c}",
                                                              lambda s, c=c: self.frames[c].append(time.monotonic())))

    def frame_gaps(self, client: str, longer_than: float,
                   *outside: tuple[float, float]) -> list[float]:
        """Gaps between ``client``'s PLCTONC frames longer than ``longer_than`` [s] that overlap none of
        the windows ``outside`` (e.g. while the NC was frozen) [s]."""
        ts = list(self.frames[client])
        out = []
        for a, b in zip(ts, ts[1:]):
            if b - a > longer_than and all(b < w0 or a > w1 for w0, w1 in outside):
                out.append(b - a)
        return out

    def _on(self, axis: int) -> Callable[[zenoh.Sample], None]:
        def cb(s: zenoh.Sample) -> None:
            rec = np.frombuffer(s.payload.to_bytes(), dtype=NCTOPLC_DTYPE, count=1)[0]
            att = s.attachment.to_bytes() if s.attachment is not None else b""
            cycle = int.from_bytes(att[:8], "little") if len(att) >= 8 else 0
            with self._cv:
                self.samples[axis].append(Sample(time.monotonic(), rec, cycle))
                self._cv.notify_all()
        return cb

    def last(self, axis: int) -> Sample | None:
        with self._cv:
            s = self.samples[axis]
            return s[-1] if s else None

    def since(self, axis: int, t: float) -> list[Sample]:
        with self._cv:
            return [s for s in self.samples[axis] if s.t >= t]

    def wait(self, axis: int, pred: Callable[[Sample], bool], timeout: float = T, after: float = 0.0,
             what: str = "") -> Sample:
        """The first sample (arrived at or after ``after``) satisfying ``pred``."""
        deadline = time.monotonic() + timeout
        with self._cv:
            i = 0
            while True:
                recs = self.samples[axis]
                for s in recs[i:]:
                    if s.t >= after and pred(s):
                        return s
                i = len(recs)
                left = deadline - time.monotonic()
                if left <= 0:
                    raise AssertionError(f"axis {axis}: {what or 'condition'} not seen in {timeout} s; "
                                         f"last: {recs[-3:]}")
                self._cv.wait(min(left, 0.1))

    def close(self) -> None:
        for s in self._subs:
            try:
                s.undeclare()
            except Exception:
                pass
        self.session.close()


class ClientProcess:
    """``failsafe_client.py``: a zenoh client process (liveliness token ``client_id``) that claims and
    feeds ``hold`` axes (enabling PLCTONC every 10 ms), then sends ``commands`` (``[[cmd, axis,
    {args}], ...]``), prints one JSON line ``{"ready": true, "replies": [...]}`` and idles until
    killed (or frozen with SIGSTOP)."""

    def __init__(self, port: int, client_id: str, hold: Iterable[int] = (), commands: list[Any] | None = None,
                 lease_ms: int = 500, nc: str = "nc1") -> None:
        spec = {"port": port, "client": client_id, "hold": list(hold), "commands": commands or [], "lease_ms": lease_ms,
                "nc": nc}
        self.proc = subprocess.Popen([sys.executable, str(CLIENT), json.dumps(spec)], stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True, start_new_session=True,
                                     env=dict(os.environ, PYTHONUNBUFFERED="1"))
        self.client_id = client_id

    def wait_ready(self, timeout: float = 60.0) -> dict[str, Any]:
        assert self.proc.stdout is not None
        out: dict[str, Any] = {}
        done = threading.Event()

        def read() -> None:
            assert self.proc.stdout is not None
            line = self.proc.stdout.readline()
            try:
                out.update(json.loads(line))
            except ValueError:
                out["bad"] = line
            done.set()

        threading.Thread(target=read, daemon=True).start()
        if not done.wait(timeout) or "ready" not in out:
            err = self.proc.stderr.read() if self.proc.poll() is not None and self.proc.stderr else ""
            raise AssertionError(f"{self.client_id} not ready: {out} {err}")
        return out

    @property
    def pid(self) -> int:
        return self.proc.pid

    def signal(self, sig: int) -> float:
        """Send ``sig``; returns the monotonic time just before."""
        t = time.monotonic()
        os.kill(self.proc.pid, sig)
        return t

    def kill(self) -> None:
        resume_and_kill(self.proc)


#: SIGCONT then SIGKILL the process group of a Popen and reap it (idempotent; for finally blocks)
resume_and_kill = kill_process_group


class TcpProxy:
    """A TCP relay on 127.0.0.1 between clients and a zenoh endpoint: the "link" the tests cut.

    ``cut()`` drops every relayed connection (both sides see the TCP connection end, as when a
    host's network goes down and its stack resets the connections) and refuses new ones until
    :meth:`restore`; ``blackhole()`` keeps the connections but forwards nothing (a pulled cable:
    only the zenoh leases notice) and refuses new ones until :meth:`restore`.

    Args:
        target_port: where to relay to (127.0.0.1).
        port: the port to listen on (a free one by default).
    """

    def __init__(self, target_port: int, port: int | None = None) -> None:
        import socket

        from znc_testing import free_port

        self.target_port = target_port
        self.port = port or free_port()
        self.endpoint = f"tcp/127.0.0.1:{self.port}"
        self._socket = socket
        self._srv = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._srv.bind(("127.0.0.1", self.port))
        self._srv.listen(64)
        self._srv.settimeout(0.1)
        self._lock = threading.Lock()
        self._pairs: list[tuple[Any, Any]] = []
        self.state = "up"  # "up" | "cut" | "blackhole"
        self._stop = threading.Event()
        threading.Thread(target=self._accept, daemon=True, name=f"proxy-{self.port}").start()

    def _accept(self) -> None:
        sock = self._socket
        while not self._stop.is_set():
            try:
                c, _ = self._srv.accept()
            except (TimeoutError, OSError):
                continue
            if self.state != "up":
                c.close()  # refused while the link is down
                continue
            try:
                u = sock.create_connection(("127.0.0.1", self.target_port), timeout=2.0)
            except OSError:
                c.close()
                continue
            for s in (c, u):
                s.setsockopt(sock.IPPROTO_TCP, sock.TCP_NODELAY, 1)
                s.settimeout(None)
            with self._lock:
                self._pairs.append((c, u))
            threading.Thread(target=self._pump, args=(c, u), daemon=True).start()
            threading.Thread(target=self._pump, args=(u, c), daemon=True).start()

    def _pump(self, src: Any, dst: Any) -> None:
        try:
            while True:
                data = src.recv(65536)
                if not data:
                    break
                while self.state == "blackhole":
                    time.sleep(0.01)  # (held back, then dropped with the connection)
                if self.state == "cut":
                    break
                dst.sendall(data)
        except OSError:
            pass
        finally:
            for s in (src, dst):
                try:
                    s.shutdown(self._socket.SHUT_RDWR)
                except OSError:
                    pass
                try:
                    s.close()
                except OSError:
                    pass

    def _drop_all(self) -> None:
        with self._lock:
            pairs, self._pairs = self._pairs, []
        for pair in pairs:
            for s in pair:
                try:
                    s.shutdown(self._socket.SHUT_RDWR)
                except OSError:
                    pass
                try:
                    s.close()
                except OSError:
                    pass

    def cut(self) -> float:
        """The link goes down (connections reset); returns the monotonic time."""
        t = time.monotonic()
        self.state = "cut"
        self._drop_all()
        return t

    def blackhole(self) -> float:
        """The link stops carrying anything (connections kept); returns the monotonic time."""
        t = time.monotonic()
        self.state = "blackhole"
        return t

    def restore(self) -> float:
        """The link is up again (a blackholed connection is dropped: its peers gave up on it); returns the time."""
        if self.state == "blackhole":
            self.state = "cut"
            self._drop_all()
        t = time.monotonic()
        self.state = "up"
        return t

    def close(self) -> None:
        self._stop.set()
        self.state = "cut"
        self._drop_all()
        try:
            self._srv.close()
        except OSError:
            pass
