"""Hosts as network namespaces (no Docker needed): NC, PLC client and router each in its own.

The test makes four namespaces (router, nc, plc, observer), veth pairs from the router's to each
other (10.77.x.y/30 addresses, only inside these namespaces), and runs real processes in them with
``ip netns exec``: ``nc-router``, ``nc-server --mode client`` (nc1), ``plc-run deploy/programs/plc2.py``
(holds nc1 axis 2) and ``observer.py`` (a status client writing JSON lines). Cuts: the PLC's and
the NC's link down and up (``ip link set``). Checks as in test_docker.py: the reaction (claims
released and the axis stopped; the NC's loss reported by the PLC's blocks), the recovery without
restarting anything, no axis moving on its own. Everything is removed in the end (process groups
killed, namespaces deleted).
"""
from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Callable, Iterator

import pytest

from znc_testing.hostlib import (FIGURES, ROOT, AxisSample, Event, cell_ok, errors_after, motion_on_its_own, parse_events,
                     wait_nc_lost, wait_plc_lost)
from znc_testing import wait_until

pytestmark = pytest.mark.timeout(600)

HOLDERS = {("nc1", 2): "plc2"}
PORT = 7451  # inside the router's namespace (its own port space)
NETS = {"nc": "10.77.1", "plc": "10.77.2", "obs": "10.77.3"}  # <net>.1 router side, <net>.2 the host's
RECOVER_TIMEOUT = 120.0


def netns_unavailable() -> str | None:
    """Why namespaces cannot be made here, or None."""
    if os.geteuid() != 0:
        return "network namespaces need root (ip netns add)"
    if shutil.which("ip") is None:
        return "no ip command (iproute2)"
    probe = f"zncprobe{os.getpid()}"
    r = subprocess.run(["ip", "netns", "add", probe], capture_output=True, text=True, timeout=30)
    if r.returncode != 0:
        return f"ip netns add failed: {r.stderr.strip()}"
    subprocess.run(["ip", "netns", "del", probe], capture_output=True, timeout=30)
    return None


def ip(*args: str) -> None:
    r = subprocess.run(["ip", *args], capture_output=True, text=True, timeout=30)
    if r.returncode != 0:
        raise AssertionError(f"ip {' '.join(args)}: {r.stderr.strip()}")


class RemoteStatus:
    """What observer.py wrote: the :class:`hostlib.StatusClient` API (history, latest, frame_age, info, claims)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._pos = 0
        self._buf = ""
        self.samples: dict[tuple[str, int], list[AxisSample]] = {}
        self._info: dict[str, Any] = {}

    def _read(self) -> None:
        try:
            with open(self.path) as f:
                f.seek(self._pos)
                chunk = f.read()
                self._pos = f.tell()
        except OSError:
            return
        self._buf += chunk
        *lines, self._buf = self._buf.split("\n")
        for line in lines:
            try:
                d = json.loads(line)
            except ValueError:
                continue
            for nc, axis, t, cycle, state, err, pos, velo in d.get("samples", []):
                self.samples.setdefault((nc, axis), []).append(AxisSample(t, nc, cycle, axis, state, err, pos, velo))
            if "info" in d:
                self._info = d["info"]

    def history(self, nc: str, axis: int, since: float = 0.0) -> list[AxisSample]:
        self._read()
        return [s for s in self.samples.get((nc, axis), []) if s.t >= since]

    def latest(self, nc: str, axis: int) -> AxisSample | None:
        self._read()
        h = self.samples.get((nc, axis))
        return h[-1] if h else None

    def frame_age(self, nc: str) -> float:
        self._read()
        ts = [h[-1].t for (n, _), h in self.samples.items() if n == nc and h]
        return time.time() - max(ts) if ts else float("inf")

    def info(self, nc: str, timeout: float = 0.0) -> dict[str, Any] | None:
        self._read()
        return self._info.get(nc)

    def claims(self, nc: str) -> dict[int, str] | None:
        v = self.info(nc)
        return None if v is None else {int(a): c for a, c in v.get("claims", {}).items()}


class NetnsHosts:
    """The namespaces, links and processes of one test module."""

    def __init__(self, workdir: Path) -> None:
        tag = str(os.getpid())[-6:]
        self.ns = {h: f"znc{tag}{h}" for h in ("router", "nc", "plc", "obs")}
        self.veth = {h: (f"zr{tag}{h[0]}", f"zh{tag}{h[0]}") for h in NETS}  # (router side, host side)
        self.workdir = workdir
        self.procs: dict[str, subprocess.Popen[bytes]] = {}
        self.status = RemoteStatus(workdir / "observer.out")

    def up(self) -> None:
        for ns in self.ns.values():
            ip("netns", "add", ns)
            ip("-n", ns, "link", "set", "lo", "up")
        r = self.ns["router"]
        for host, net in NETS.items():
            a, b = self.veth[host]
            ip("-n", r, "link", "add", a, "type", "veth", "peer", "name", b, "netns", self.ns[host])
            ip("-n", r, "addr", "add", f"{net}.1/30", "dev", a)
            ip("-n", self.ns[host], "addr", "add", f"{net}.2/30", "dev", b)
            ip("-n", r, "link", "set", a, "up")
            ip("-n", self.ns[host], "link", "set", b, "up")
        py = sys.executable
        env = dict(os.environ, PYTHONUNBUFFERED="1", ZNC_ID="plc2", ZNC_SHARE_S="0", ZNC_REARM_S="0.5")
        self.start("router", "router", [py, "-m", "nc_server.router", "--log-level", "WARNING", "--lease-ms", "2000",
                                        *(a for net in NETS.values() for a in ("--listen", f"tcp/{net}.1:{PORT}"))], env)
        self.wait_line("router", "nc-router ready")
        self.start("nc", "nc1", [py, "-m", "nc_server.server.cli", "--mode", "client", "--connect",
                                 f"tcp/{NETS['nc']}.1:{PORT}", "--name", "nc1", "--realtime", "off",
                                 "--watchdog-timeout", "2.0"], env)  # lenient (loaded machine): cuts are seen by leases
        self.wait_line("nc1", "nc-server nc1 ready")
        self.start("plc", "plc2", [py, "-m", "plc_client.cli", str(ROOT / "deploy" / "programs" / "plc2.py"),
                                   "--client-id", "plc2", "--nc", f"nc1=tcp/{NETS['plc']}.1:{PORT}"], env)
        self.start("obs", "observer", [py, str(Path(__file__).with_name("observer.py")),
                                       f"tcp/{NETS['obs']}.1:{PORT}", "nc1"], env)

    def start(self, host: str, name: str, argv: list[str], env: dict[str, str]) -> None:
        out = open(self.workdir / f"{name}.out", "wb")
        err = open(self.workdir / f"{name}.err", "wb")
        self.procs[name] = subprocess.Popen(["ip", "netns", "exec", self.ns[host], *argv], stdin=subprocess.DEVNULL,
                                            stdout=out, stderr=err, start_new_session=True, env=env, cwd=ROOT)

    def wait_line(self, name: str, text: str, timeout: float = 120.0) -> None:
        """Wait for ``text`` on the stdout of process ``name`` (its ready line)."""
        def seen() -> bool | str:
            if self.procs[name].poll() is not None:
                raise AssertionError(f"{name} exited with {self.procs[name].returncode}:\n{self.logs()}")
            return text in (self.workdir / f"{name}.out").read_text(errors="replace") or f"no {text!r} yet"
        wait_until(seen, timeout, f"{name} ready", interval=0.1)

    def events(self) -> list[Event]:
        return parse_events((self.workdir / "plc2.out").read_text(errors="replace"))

    def alive(self) -> dict[str, int | None]:
        return {n: p.poll() for n, p in self.procs.items()}

    def link(self, host: str, state: str) -> None:
        ip("-n", self.ns[host], "link", "set", self.veth[host][1], state)

    def down(self) -> None:
        for p in self.procs.values():
            try:
                os.killpg(p.pid, signal.SIGKILL)
            except (ProcessLookupError, PermissionError):
                pass
        for p in self.procs.values():
            try:
                p.wait(10)
            except subprocess.TimeoutExpired:
                pass
        for ns in self.ns.values():
            subprocess.run(["ip", "netns", "del", ns], capture_output=True, timeout=30)

    def logs(self) -> str:
        return "\n".join(f"--- {f.name}\n{f.read_text(errors='replace')[-1500:]}"
                         for f in sorted(self.workdir.glob("*.err")))


@pytest.fixture(scope="module")
def hosts(tmp_path_factory: pytest.TempPathFactory) -> Iterator[NetnsHosts]:
    reason = netns_unavailable()
    if reason:
        pytest.skip(reason)
    h = NetnsHosts(tmp_path_factory.mktemp("netns"))
    try:
        t0 = time.monotonic()
        h.up()
        t_up = time.time()
        try:
            wait_until(lambda: cell_ok(h.status, HOLDERS, moved_since=t_up), 180,
                       "plc2 holding nc1 axis 2 and moving it", interval=0.25)
        except AssertionError as exc:
            raise AssertionError(f"{exc}\nprocesses: {h.alive()}\n{h.logs()}") from None
        FIGURES["scenarios"].append({"where": "netns", "scenario": "start -> holding, moving", "react_s": None,
                                     "recover_s": round(time.monotonic() - t0, 2), "notes": "router+nc1+plc2+observer"})
        yield h
    finally:
        h.down()


def cut(h: NetnsHosts, name: str, host: str, reaction: Callable[[float], None]) -> None:
    wait_until(lambda: cell_ok(h.status, HOLDERS), RECOVER_TIMEOUT, f"healthy before {name}", interval=0.25)
    t_cut = time.time()
    h.link(host, "down")
    try:
        reaction(t_cut)
        t_react = time.time() - t_cut
    finally:
        t_restore = time.time()
        h.link(host, "up")
    wait_until(lambda: cell_ok(h.status, HOLDERS, moved_since=t_restore), RECOVER_TIMEOUT, f"recovery after {name}",
               interval=0.25)
    t_rec = time.time() - t_restore
    assert all(rc is None for rc in h.alive().values()), f"a process ended: {h.alive()}\n{h.logs()}"
    t_events = time.time()  # lines logged before this are in the events read now
    events = h.events()
    for nc, axis in HOLDERS:
        v = motion_on_its_own(h.status.history(nc, axis, t_cut - 10.0), events, t_cut,
                              until=t_events - 1.0)
        assert v is None, v
    errs = sorted({f"{e.client} {e.nc}:{e.axis} {e.text.split(' (')[0]}" for e in errors_after(events, t_cut)})
    FIGURES["scenarios"].append({"where": "netns", "scenario": name, "react_s": round(t_react, 2),
                                 "recover_s": round(t_rec, 2), "notes": "; ".join(errs[:3])})


def test_plc_link_down_up(hosts: NetnsHosts) -> None:
    cut(hosts, "plc link down/up (ip link)", "plc", lambda t: wait_plc_lost(hosts.status, "plc2", HOLDERS))


def test_nc_link_down_up(hosts: NetnsHosts) -> None:
    cut(hosts, "nc link down/up (ip link)", "nc",
        lambda t: wait_nc_lost(hosts.status, hosts.events, ["nc1"], t, HOLDERS))
