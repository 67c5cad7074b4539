"""The deploy/ system in containers, cut in every way a network or a host fails.

One compose project per module (deploy/compose.yaml, a unique project name, its own networks, the
router published on a free 127.0.0.1 port, everything removed in the end): router, nc1, nc2, plc1
(nc1 axis 1 + nc2 axis 1), plc2 (nc1 axis 2; commands nc1 axis 1 now and then). The test process
watches through the router with :class:`hostlib.StatusClient` and reads the PLCs' event lines
(``docker logs``).

Each scenario: the system healthy (every claim held, every held axis enabled and moving), one cut
(network disconnect, docker stop / kill / pause) of a PLC, an NC or the router, the reaction
awaited (claims released and the axes stopped; the NC's loss seen by its PLCs as errors), the
cut undone, the recovery awaited (everything as before and moving again) with nothing else
restarted, and no axis moving on its own after the cut (:func:`hostlib.motion_on_its_own`).
Reaction and recovery times are measured and printed at the end of the run (conftest.py).
"""
from __future__ import annotations

import os
import shutil
import subprocess
import time
import uuid
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

import pytest

from znc_testing.hostlib import (FIGURES, HOLDERS, NCS, ROOT, StatusClient, cell_ok, compose_command, errors_after,
                     motion_on_its_own, parse_events, wait_nc_lost, wait_plc_lost)
from znc_testing import free_port, wait_until

# The cut scenarios are strict: every one passed in two consecutive full runs on the loaded 2-core
# machine after the fixes of issue 8's second fail-safe round (the NC behind the router retrying
# every 100-250 ms; tcp_retries2 in deploy/compose.yaml, without which a TLS link cut kept the lost
# client's token > 60 s).
pytestmark = [pytest.mark.timeout(1800)]  # the first test may build the images (minutes, cold)

SERVICES = ("router", "nc1", "nc2", "plc1", "plc2")
PLCS = ("plc1", "plc2")
COMPOSE_FILE = ROOT / "deploy" / "compose.yaml"
#: generous deadlines [s] (a loaded 2-core machine); nothing asserts speed
UP_TIMEOUT, RECOVER_TIMEOUT = 240.0, 120.0


def tls_available() -> bool:
    """TLS material and TLS-aware CLIs are in the tree (deploy/certs, deploy/roles.toml, nc-router --tls-dir)."""
    router_src = (ROOT / "nc_server" / "router.py").read_text()
    return ((ROOT / "deploy" / "certs" / "make-certs.sh").exists() and (ROOT / "deploy" / "roles.toml").exists()
            and "--tls-dir" in router_src)


class ComposeSystem:
    """One compose project of deploy/compose.yaml for a test module.

    Args:
        image: the app image tag.
        workdir: where the certificates and the roles file go (``ZNC_BUILD``).
        files: the compose files (default deploy/compose.yaml alone; an override such as compose.drives.yaml after it).
        services: the services started (and checked, diagnosed, stopped).
        plcs: the PLC services whose event lines :meth:`events` reads.
        identities: the certificates made besides the router's.
        env: environment for compose over the defaults below.
    """

    def __init__(self, image: str, workdir: Path, files: Sequence[Path] = (COMPOSE_FILE,),
                 services: Sequence[str] = SERVICES, plcs: Sequence[str] = PLCS,
                 identities: Sequence[str] = ("nc1", "nc2", "plc1", "plc2", "status"),
                 env: dict[str, str] | None = None) -> None:
        cmd = compose_command()
        assert cmd is not None
        self.project = f"znct{os.getpid()}{uuid.uuid4().hex[:6]}"
        self.port = free_port()
        self.workdir = workdir
        self.services, self.plcs = tuple(services), tuple(plcs)
        self.transport = os.environ.get("ZNC_HOSTS_TRANSPORT") or ("tls" if tls_available() else "tcp")
        self.compose_cmd = [*cmd, *(a for f in files for a in ("-f", str(f))), "-p", self.project]
        (workdir / "certs").mkdir(parents=True, exist_ok=True)
        (workdir / "etc").mkdir(parents=True, exist_ok=True)
        # each container mounts ca.pem and its own certificate and key (and the router the roles file):
        # made for tcp too, as deploy.sh does (a missing file would be mounted as an empty directory)
        if (ROOT / "deploy" / "certs" / "make-certs.sh").exists():  # it always makes the router's too
            subprocess.run([str(ROOT / "deploy" / "certs" / "make-certs.sh"), str(workdir / "certs"), *identities],
                           check=True, capture_output=True, timeout=300)
            shutil.copy(ROOT / "deploy" / "roles.toml", workdir / "etc" / "roles.toml")
            for key in (workdir / "certs").glob("*.key"):
                if key.name != "ca.key":  # the CA key stays unreadable to the containers
                    os.chown(key, -1, 10001)  # the image's uid:gid (deploy/images/Dockerfile)
                    key.chmod(0o640)
        self.env = dict(os.environ, ZNC_IMAGE=image, ZNC_ROUTER_PORT=str(self.port), ZNC_BUILD=str(workdir),
                        ZNC_TRANSPORT=self.transport, ZNC_RESTART="no", ZNC_REARM_S="0.5", ZNC_SHARE_S="6",
                        ZNC_WATCHDOG_S="2.0", ZNC_ROUTER_LEASE_MS="2000")  # lenient: a loaded 2-core machine (the cuts are seen by leases)
        self.env.update(env or {})
        self.status: StatusClient | None = None
        self.ids: dict[str, str] = {}

    # -- docker ---------------------------------------------------------------------------------
    def compose(self, *args: str, timeout: float = 300) -> subprocess.CompletedProcess[str]:
        return subprocess.run([*self.compose_cmd, *args], env=self.env, capture_output=True, text=True,
                              timeout=timeout)

    @staticmethod
    def docker(*args: str, timeout: float = 120, check: bool = True) -> str:
        for attempt in range(5):
            r = subprocess.run(["docker", *args], capture_output=True, text=True, timeout=timeout)
            # the freezer may not settle at once on a loaded machine ("unable to freeze"): again
            if r.returncode == 0 or "unable to freeze" not in r.stderr:
                break
            time.sleep(0.2)
        if check and r.returncode != 0:
            raise AssertionError(f"docker {' '.join(args)} failed: {r.stderr.strip()}")
        return r.stdout.strip()

    def cid(self, service: str) -> str:
        if service not in self.ids:
            out = self.docker("ps", "-aq", "--filter", f"label=com.docker.compose.project={self.project}",
                              "--filter", f"label=com.docker.compose.service={service}")
            assert out, f"no container of service {service}"
            self.ids[service] = out.splitlines()[0]
        return self.ids[service]

    def started(self, service: str) -> str:
        """StartedAt and RestartCount (changes whenever the container's process was restarted)."""
        return self.docker("inspect", "-f", "{{.State.StartedAt}} {{.RestartCount}}", self.cid(service))

    def health(self, service: str) -> str:
        # an exited container keeps the health it had ("starting"): its state first
        return self.docker("inspect", "-f", "{{if ne .State.Status \"running\"}}{{.State.Status}}{{else if .State.Health}}"
                           "{{.State.Health.Status}}{{else}}running{{end}}", self.cid(service), check=False)

    @property
    def network(self) -> str:
        return f"{self.project}_ncnet"

    def logs(self, service: str) -> str:
        r = subprocess.run(["docker", "logs", self.cid(service)], capture_output=True, text=True, timeout=60)
        return r.stdout + r.stderr

    def diagnosis(self) -> str:
        """One line (CI shows the first line of a failure): each service's state, restarts and last log lines;
        the full logs follow on the next lines."""
        parts, full = [], []
        for sv in self.services:
            restarts = self.docker("inspect", "-f", "{{.RestartCount}}", self.cid(sv), check=False)
            tail = [ln for ln in self.logs(sv).splitlines() if ln.strip()][-3:]
            parts.append(f"{sv}={self.health(sv)} restarts={restarts} log: {' | '.join(tail)[-400:]!r}")
            full.append(f"--- {sv}\n{self.logs(sv)[-3000:]}")
        return "; ".join(parts) + "\n" + "\n".join(full)

    def events(self) -> list[Any]:
        return [e for s in self.plcs for e in parse_events(self.logs(s))]

    def status_tls(self) -> str | None:
        """The certificate directory for the test's status client (identity ``status``), None for tcp."""
        return str(self.workdir / "certs") if self.transport == "tls" else None

    # -- life -----------------------------------------------------------------------------------
    def up(self) -> None:
        r = self.compose("up", "-d", *self.services)  # (not the OPC UA door: no scenario of its own here)
        assert r.returncode == 0, f"compose up failed:\n{r.stdout}\n{r.stderr}"

        # running is enough here: the system's own state (cell_ok) is what the tests wait for; the
        # healthchecks (a zenoh session each) can time out on a loaded machine and are only noted
        def running() -> bool | str:
            states = {s: self.health(s) for s in self.services}
            return all(v in ("healthy", "starting", "running") for v in states.values()) or f"{states}"
        try:
            wait_until(running, UP_TIMEOUT, "every service running", interval=1.0)
        except AssertionError as exc:
            logs = "\n".join(f"--- {s}\n{self.logs(s)[-1500:]}" for s in self.services)
            raise AssertionError(f"{exc}\n{logs}") from None

    def down(self) -> None:
        if self.status is not None:
            self.status.close()
        for s in self.services:  # a paused container cannot be stopped
            try:
                if self.docker("inspect", "-f", "{{.State.Paused}}", self.cid(s), check=False) == "true":
                    self.docker("unpause", self.cid(s), check=False)
            except AssertionError:
                pass
        r = self.compose("down", "-t", "5", "--remove-orphans")
        if r.returncode != 0:  # never leave containers or networks behind
            out = self.docker("ps", "-aq", "--filter", f"label=com.docker.compose.project={self.project}", check=False)
            if out:
                self.docker("rm", "-f", *out.split(), check=False)
            for net in ("ncnet", "edge"):
                self.docker("network", "rm", f"{self.project}_{net}", check=False)


@pytest.fixture(scope="module")
def system(znc_image: str, tmp_path_factory: pytest.TempPathFactory) -> Iterator[ComposeSystem]:
    s = ComposeSystem(znc_image, tmp_path_factory.mktemp("compose"))
    try:
        t0 = time.monotonic()
        s.up()
        s.status = StatusClient(f"{s.transport}/127.0.0.1:{s.port}", tls_dir=s.status_tls())
        t_up = time.time()
        try:
            wait_until(lambda: cell_ok(s.status, moved_since=t_up), UP_TIMEOUT,
                       "every claim held and every held axis moving", interval=0.25)
        except AssertionError as exc:
            try:
                routers = len(list(s.status.session.info.routers_zid()))
            except Exception as e:  # (diagnosis only)
                routers = repr(e)
            raise AssertionError(f"{exc}; status client's routers: {routers}; {s.diagnosis()}") from None
        health = " ".join(f"{x}={s.health(x)}" for x in SERVICES)
        FIGURES["scenarios"].append({"where": "docker", "scenario": "compose up -> claims held, moving",
                                     "react_s": None, "recover_s": round(time.monotonic() - t0, 2),
                                     "notes": f"project {s.project}, {s.transport}; {health}"})
        yield s
    finally:
        s.down()


def scenario(system: ComposeSystem, name: str, target: str, cut: Sequence[Sequence[str]],
             restore: Sequence[Sequence[str]], reaction: Callable[[float], Any], restarted: bool = False) -> None:
    """Run one cut: healthy -> cut -> reaction -> restore -> recovery; the checks; the figures.

    Args:
        name: scenario name (figures).
        target: the service cut.
        cut / restore: docker command lines (``{id}`` = the target's container id, ``{net}`` the network).
        reaction: waits for (asserts) the reaction, given the cut's wall time.
        restarted: the target's process is restarted by the scenario (stop/kill + start).
    """
    st = system.status
    assert st is not None
    wait_until(lambda: cell_ok(st), RECOVER_TIMEOUT, f"the system healthy before {name}", interval=0.25)
    others = {s: system.started(s) for s in SERVICES if s != target}
    mine = system.started(target)
    fmt = {"id": system.cid(target), "net": system.network, "alias": target}
    t_cut = time.time()
    done_restore = False
    try:
        for c in cut:
            system.docker(*(a.format(**fmt) for a in c))
        reaction(t_cut)
        t_react = time.time() - t_cut
        t_restore = time.time()
        for c in restore:
            system.docker(*(a.format(**fmt) for a in c))
        done_restore = True
        wait_until(lambda: cell_ok(st, moved_since=t_restore), RECOVER_TIMEOUT,
                   f"recovery after {name}", interval=0.25)
        t_rec = time.time() - t_restore
    finally:
        if not done_restore:
            for c in restore:
                system.docker(*(a.format(**fmt) for a in c), check=False)
    # nothing else was restarted; the target only where the scenario restarts it
    assert {s: system.started(s) for s in others} == others, "another container was restarted"
    assert (system.started(target) != mine) == restarted
    # no axis moves on its own after the cut
    t_events = time.time()  # lines logged before this are in the events read now
    events = system.events()
    for nc, axis in HOLDERS:
        v = motion_on_its_own(st.history(nc, axis, t_cut - 10.0), events, t_cut,
                              until=t_events - 1.0)
        if v is not None:
            lines = [f"{e.client} {e.t:.3f} {e.nc}:{e.axis} {e.text}" for e in events if e.t >= t_cut - 10.0]
            logs = "\n".join(f"--- {s}\n{system.logs(s)[-2500:]}" for s in ("nc1", "nc2") if s == target or s == nc)
            raise AssertionError(f"{v}\nPLC events since 10 s before the cut:\n" + "\n".join(lines[-60:]) + "\n" + logs)
    errs = sorted({f"{e.client} {e.nc}:{e.axis} {e.text.split(' (')[0]}" for e in errors_after(events, t_cut)})
    FIGURES["scenarios"].append({"where": "docker", "scenario": name, "react_s": round(t_react, 2),
                                 "recover_s": round(t_rec, 2), "notes": "; ".join(errs[:4])})


# ---- reactions -----------------------------------------------------------------------------------
def plc_lost(system: ComposeSystem, plc: str) -> Callable[[float], None]:
    return lambda t_cut: wait_plc_lost(system.status, plc)


def nc_lost(system: ComposeSystem, ncs: Sequence[str]) -> Callable[[float], None]:
    return lambda t_cut: wait_nc_lost(system.status, system.events, ncs, t_cut)


# ---- scenarios ---------------------------------------------------------------------------------
DISCONNECT = [["network", "disconnect", "{net}", "{id}"]]
CONNECT = [["network", "connect", "--alias", "{alias}", "{net}", "{id}"]]


def test_plc_link_down_up(system: ComposeSystem) -> None:
    scenario(system, "plc1 link down/up", "plc1", DISCONNECT, CONNECT, plc_lost(system, "plc1"))


def test_plc_kill(system: ComposeSystem) -> None:
    scenario(system, "plc1 docker kill / start", "plc1", [["kill", "{id}"]], [["start", "{id}"]],
             plc_lost(system, "plc1"), restarted=True)


def test_plc_pause(system: ComposeSystem) -> None:
    scenario(system, "plc1 docker pause / unpause", "plc1", [["pause", "{id}"]], [["unpause", "{id}"]],
             plc_lost(system, "plc1"))


def test_plc_stop(system: ComposeSystem) -> None:
    scenario(system, "plc2 docker stop / start", "plc2", [["stop", "-t", "10", "{id}"]], [["start", "{id}"]],
             plc_lost(system, "plc2"), restarted=True)


def test_nc_link_down_up(system: ComposeSystem) -> None:
    scenario(system, "nc1 link down/up", "nc1", DISCONNECT, CONNECT, nc_lost(system, ["nc1"]))


def test_nc_pause(system: ComposeSystem) -> None:
    scenario(system, "nc1 docker pause / unpause", "nc1", [["pause", "{id}"]], [["unpause", "{id}"]],
             nc_lost(system, ["nc1"]))


def test_nc_kill(system: ComposeSystem) -> None:
    scenario(system, "nc2 docker kill / start", "nc2", [["kill", "{id}"]], [["start", "{id}"]],
             nc_lost(system, ["nc2"]), restarted=True)


def test_nc_stop(system: ComposeSystem) -> None:
    scenario(system, "nc2 docker stop / start", "nc2", [["stop", "-t", "10", "{id}"]], [["start", "{id}"]],
             nc_lost(system, ["nc2"]), restarted=True)


def test_router_kill(system: ComposeSystem) -> None:
    scenario(system, "router docker kill / start", "router", [["kill", "{id}"]], [["start", "{id}"]],
             nc_lost(system, list(NCS)), restarted=True)


def test_router_pause(system: ComposeSystem) -> None:
    scenario(system, "router docker pause / unpause", "router", [["pause", "{id}"]], [["unpause", "{id}"]],
             nc_lost(system, list(NCS)))


def test_router_stop(system: ComposeSystem) -> None:
    scenario(system, "router docker stop / start", "router", [["stop", "-t", "10", "{id}"]], [["start", "{id}"]],
             nc_lost(system, list(NCS)), restarted=True)
