"""Fixtures of the security tests: certificates made by ``deploy/certs/make-certs.sh`` into a
temporary directory, TLS sessions as a given identity, and NC / router processes with TLS and the
access control of ``deploy/roles.toml`` (real processes on 127.0.0.1, free ports)."""
from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path
from typing import Callable, Iterator, Sequence

import pytest
import zenoh

from znc_testing.sec_testing import tls_config
from znc_testing import NcServerProcess, free_port, nc_router_command, nc_server_command

REPO = Path(__file__).resolve().parents[2]
MAKE_CERTS = REPO / "deploy" / "certs" / "make-certs.sh"
ROLES = REPO / "deploy" / "roles.toml"
#: the identities the tests use: deploy/roles.toml's, plus one with a valid certificate that is not listed
NAMES = ("nc1", "nc2", "plc1", "plc2", "eng1", "status", "stranger")
READY = 60.0


@pytest.fixture(scope="session")
def certs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A certificate directory: ca.pem, router and NAMES certificates, rogue/ (another CA)."""
    if shutil.which("openssl") is None:
        pytest.skip("openssl is not installed: deploy/certs/make-certs.sh cannot make the test certificates")
    out = tmp_path_factory.mktemp("certs")
    # nc1 and nc2 listen for their clients in some tests (start_tls_nc without connect): server certificates
    subprocess.run(["sh", str(MAKE_CERTS), str(out), "--server", "nc1", "--server", "nc2", *NAMES, "--rogue"],
                   check=True, capture_output=True, timeout=120)
    return out


def _start(cmd: list[str], tmp: Path, label: str, port: int, name: str) -> NcServerProcess:
    tmp.mkdir(parents=True, exist_ok=True)
    err_path = tmp / f"{label}-{port}.stderr"
    with open(err_path, "w") as err:
        proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=err, text=True,
                                start_new_session=True, env=dict(os.environ, PYTHONUNBUFFERED="1"))
    h = NcServerProcess(proc, port, name, err_path)
    try:
        h.wait_ready(READY)
    except BaseException:
        h.kill()
        raise
    return h


@pytest.fixture
def processes() -> Iterator[list[NcServerProcess]]:
    """Processes started by a test; their process groups are killed at the end, pass or fail."""
    started: list[NcServerProcess] = []
    try:
        yield started
    finally:
        for h in reversed(started):
            h.kill()


@pytest.fixture
def start_tls_nc(tmp_path: Path, certs: Path, processes: list[NcServerProcess]) -> Callable[..., NcServerProcess]:
    """``start_tls_nc(name="nc1", connect=None, extra=())``: nc-server with ``--tls-dir`` and ``--roles``
    (deploy/roles.toml), listening on ``tls/127.0.0.1:<free port>`` (or, with ``connect``, in client
    mode behind that router endpoint)."""
    def start(name: str = "nc1", connect: str | None = None, extra: Sequence[str] = ()) -> NcServerProcess:
        port = free_port() if connect is None else int(connect.rsplit(":", 1)[1])
        where = ["--listen", f"tls/127.0.0.1:{port}"] if connect is None else ["--mode", "client", "--connect", connect]
        cmd = [*nc_server_command(), *where, "--name", name, "--tls-dir", str(certs), "--roles", str(ROLES),
               "--watchdog-timeout", "3.0", *extra]
        h = _start(cmd, tmp_path / name, "nc-server", port, name)
        processes.append(h)
        return h
    return start


@pytest.fixture
def start_tls_router(tmp_path: Path, certs: Path, processes: list[NcServerProcess]) -> Callable[..., NcServerProcess]:
    """``start_tls_router(extra=())``: nc-router with ``--tls-dir`` and ``--roles`` on a free port."""
    def start(extra: Sequence[str] = ()) -> NcServerProcess:
        port = free_port()
        cmd = [*nc_router_command(), "--listen", f"tls/127.0.0.1:{port}", "--tls-dir", str(certs), "--roles",
               str(ROLES), *extra]
        h = _start(cmd, tmp_path / "router", "nc-router", port, "router")
        processes.append(h)
        return h
    return start


@pytest.fixture
def session_as(certs: Path) -> Iterator[Callable[..., zenoh.Session]]:
    """``session_as(port, identity, certs_dir=None)``: a TLS client session (closed at the end)."""
    opened: list[zenoh.Session] = []

    def open_(port: int, identity: str, certs_dir: Path | None = None) -> zenoh.Session:
        s = zenoh.open(tls_config(port, certs_dir or certs, identity))
        opened.append(s)
        return s

    try:
        yield open_
    finally:
        for s in reversed(opened):
            try:
                s.close()
            except Exception:
                pass
