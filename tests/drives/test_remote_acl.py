"""Remote drives with mutual TLS and access control, as deploy/compose.drives.yaml runs them: a router with
deploy/roles.toml (``[drive.drives1] nc = "nc1"``), nc1 behind it in client mode (its drive link a second client
with nc1's certificate), ``nc-drive-sim --host drives1`` with its own certificate. The drive host drives nc1's
axis; it may use its own drive keys only."""
from __future__ import annotations

import shutil
import subprocess
import time
from pathlib import Path
from typing import Any, Iterator

import pytest
import zenoh

from nc_server.security.acl import access_control
from nc_server.security.roles import RolesError, load_roles, parse_roles
from znc_testing import (
    NcServerProcess, NcTestClient, free_port, nc_router_command, start_nc_server,
    wait_until,
)
from znc_testing.sec_testing import tls_config

from test_remote_process import CONFIG, DriveSim, power  # noqa: E402  (tests/drives is on sys.path under pytest)

REPO = Path(__file__).resolve().parents[2]
ROLES = REPO / "deploy" / "roles.toml"
T = 30.0


def allowed(acl: dict[str, Any], subject: str, flow: str, message: str) -> set[str]:
    pol = next(p for p in acl["policies"] if subject in p["subjects"])
    out: set[str] = set()
    for r in acl["rules"]:
        if r["id"] in pol["rules"] and flow in r["flows"] and message in r["messages"]:
            out |= set(r["key_exprs"])
    return out


def test_a_drive_host_gets_its_own_drive_keys_only() -> None:
    acl = access_control(load_roles(ROLES))
    p = "nc/nc1/drive/drives1"
    assert allowed(acl, "drive:drives1", "ingress", "put") == {f"{p}/tx", f"{p}/status"}
    assert allowed(acl, "drive:drives1", "ingress", "declare_subscriber") == {f"{p}/rx"}
    assert allowed(acl, "drive:drives1", "ingress", "liveliness_token") == {f"{p}/alive"}
    assert allowed(acl, "drive:drives1", "egress", "put") == {f"{p}/rx"}
    for msg in ("query", "declare_queryable", "declare_liveliness_subscriber", "liveliness_query"):
        assert allowed(acl, "drive:drives1", "ingress", msg) == set()
    # the NC reaches them through its own prefix; observers read the drive status
    assert "nc/nc1/**" in allowed(acl, "nc:nc1", "ingress", "put")
    assert "nc/*/drive/*/status" in allowed(acl, "client:status", "ingress", "declare_subscriber")


@pytest.mark.parametrize("text, key", [
    ("[nc.nc1]\n[drive.d1]\n", "drive.d1.nc"),
    ("[nc.nc1]\n[drive.d1]\nnc = 'n/1'\n", "drive.d1.nc"),
    ("[nc.nc1]\n[drive.d1]\nnc = 'nc1'\nhost = 'x'\n", "drive.d1.host"),
    ("[nc.nc1]\n[drive.nc1]\nnc = 'nc1'\n", "drive.nc1"),
])
def test_bad_drive_entries_in_the_roles_file(text: str, key: str) -> None:
    import tomllib
    with pytest.raises(RolesError) as e:
        parse_roles(tomllib.loads(text))
    assert e.value.key == key


@pytest.fixture(scope="module")
def certs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    if shutil.which("openssl") is None:
        pytest.skip("openssl is not installed: deploy/certs/make-certs.sh cannot make the test certificates")
    out = tmp_path_factory.mktemp("certs")
    subprocess.run(["sh", str(REPO / "deploy" / "certs" / "make-certs.sh"), str(out), "nc1", "drives1", "plc1",
                    "stranger"], check=True, capture_output=True, timeout=120)
    return out


@pytest.fixture
def started() -> Iterator[list[Any]]:
    procs: list[Any] = []
    try:
        yield procs
    finally:
        for h in reversed(procs):
            h.kill()


def test_drives_behind_a_tls_router_with_access_control(tmp_path: Path, certs: Path, started: list[Any]) -> None:
    # the router
    port = free_port()
    err = tmp_path / "router.stderr"
    with open(err, "w") as e:
        proc = subprocess.Popen([*nc_router_command(), "--listen", f"tls/127.0.0.1:{port}", "--tls-dir", str(certs),
                                 "--roles", str(ROLES)], stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=e,
                                text=True, start_new_session=True)
    router = NcServerProcess(proc, port, "router", err)
    started.append(router)
    router.wait_ready(60)
    ep = f"tls/127.0.0.1:{port}"
    # nc1 behind it (its drive link connects to the router with nc1's certificate)
    text = CONFIG.format(port=port).replace('listen = ["tcp/127.0.0.1:{}"]'.format(port), "listen = []")
    nc = start_nc_server(tmp_path / "nc", text, name="nc1", connect=ep,
                         extra_args=["--tls-dir", str(certs), "--roles", str(ROLES)])
    started.append(nc)
    cfg = tmp_path / "nc.toml"
    cfg.write_text(text)
    sim = DriveSim(tmp_path, ["--config", str(cfg), "--host", "drives1", "--connect", ep, "--tls-dir", str(certs),
                              "--timeout", "1.0"])
    started.append(sim)
    wait_until(lambda: (s := sim.status()) is not None and s["connected"] and s["rx_count"] > 0, T,
               f"the drive host receives nc1's outputs through the router; stderr:\n{sim.stderr()}")
    # a PLC client (operator plc1) powers and moves the remote axis
    cl = NcTestClient(port, client_id="plc1", config=tls_config(port, certs, "plc1"))
    try:
        power(cl, [1])
        assert cl.request("MoveAbsolute", axis=1, Position=12.5, Velocity=100.0)["error"] == 0
        wait_until(lambda: abs(float(cl.nctoplc(1)["ActPos"]) - 12.5) < 0.02, T, "axis 1 at 12.5")
    finally:
        cl.close()
    # the drive host's certificate opens its own keys only: as drives1, outputs of another host reach nobody
    got: list[bytes] = []
    own: list[bytes] = []
    with zenoh.open(tls_config(port, certs, "nc1")) as watcher:
        sub = watcher.declare_subscriber("nc/nc1/drive/other/tx", lambda s: got.append(s.payload.to_bytes()))
        sub2 = watcher.declare_subscriber("nc/nc1/drive/drives1/status", lambda s: own.append(s.payload.to_bytes()))
        with zenoh.open(tls_config(port, certs, "drives1")) as intruder:
            for _ in range(20):
                intruder.put("nc/nc1/drive/other/tx", b"x")
                intruder.put("nc/nc1/plctonc/plc1", b"x")
                intruder.put("nc/nc1/drive/drives1/status", b"mine")
                time.sleep(0.02)
            wait_until(lambda: b"mine" in own, T, "drives1's put on its own status key (the control)")
        sub.undeclare()
        sub2.undeclare()
    assert got == [], "drives1 published on another host's key"
    assert sim.proc.poll() is None and nc.proc.poll() is None
