"""The door rule on real processes with mutual TLS and the generated access control: nc-opcua (certificate
``opcua``, ``door = true`` in the roles file, role operator) acts for its users as ``opcua.<user>``; the NC
records that id as holder and commander with the door's role; the door never grants more than its role
(an engineer user gets BadUserAccessDenied for a parameter write); another certificate cannot use the door's
user ids, and the door's certificate cannot use a non-door client's ids. Unit checks of the rule first."""
from __future__ import annotations

import asyncio
import shutil
import subprocess
from pathlib import Path
from typing import Iterator

import pytest
import zenoh
from asyncua import ua

from nc_server.security.acl import access_control
from nc_server.security.roles import RolesError, door_of, parse_roles
from znc_testing import NcServerProcess, NcTestClient, free_port, nc_server_command, wait_until
from znc_testing.opcua_testing import NcOpcuaProcess, call, client, start_nc_opcua, until, value
from znc_testing.sec_testing import tls_config

REPO = Path(__file__).resolve().parents[2]
ROLES = """
[nc.nc1]
[client.opcua]
role = "operator"
door = true
[client.plc1]
role = "operator"
[client.status]
role = "observer"
"""


def test_door_rule_in_the_roles_file_and_the_acl() -> None:
    r = parse_roles({"client": {"opcua": {"role": "operator", "door": True}, "plc1": {"role": "engineer"}},
                     "nc": {"nc1": {}}})
    assert r.doors == ("opcua",)
    assert r.role_of("opcua.alice") == "operator" and r.classes_of("opcua.alice") == ("read", "op")
    assert r.role_of("plc1.x") is None and r.role_of("opcua.") is None and r.role_of("opcuax") is None
    assert door_of("a.b.c", ("a", "a.b")) == "a.b"
    with pytest.raises(RolesError, match=r"client\.opcua\.door: must be true or false"):
        parse_roles({"client": {"opcua": {"role": "operator", "door": "yes"}}})
    rules = {x["id"]: x["key_exprs"] for x in access_control(r)["rules"]}
    assert "nc/*/axis/*/cmd/op/opcua.$*" in rules["client:opcua:query"]
    assert "nc/*/axis/*/cmd/eng/opcua.$*" not in rules["client:opcua:query"]  # never above the door's role
    assert rules["client:opcua:token"] == ["nc/*/client/opcua", "nc/*/client/opcua.$*"]
    assert not any("$*" in k for k in rules["client:plc1:query"] + rules["client:plc1:token"])


@pytest.fixture(scope="module")
def pki(tmp_path_factory: pytest.TempPathFactory) -> Path:
    if shutil.which("openssl") is None:
        pytest.skip("openssl is not installed: deploy/certs/make-certs.sh cannot make the test certificates")
    out = tmp_path_factory.mktemp("zcerts")
    subprocess.run(["sh", str(REPO / "deploy" / "certs" / "make-certs.sh"), str(out), "--server", "nc1", "opcua",
                    "plc1", "status"], check=True, capture_output=True, timeout=120)
    (out / "roles.toml").write_text(ROLES)
    return out


@pytest.fixture(scope="module")
def tls_nc(tmp_path_factory: pytest.TempPathFactory, pki: Path) -> Iterator[NcServerProcess]:
    tmp = tmp_path_factory.mktemp("tlsnc")
    port = free_port()
    err = tmp / "nc.stderr"
    with open(err, "w") as f:
        proc = subprocess.Popen([*nc_server_command(), "--listen", f"tls/127.0.0.1:{port}", "--name", "nc1",
                                 "--tls-dir", str(pki), "--roles", str(pki / "roles.toml")],
                                stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=f, text=True,
                                start_new_session=True)
    h = NcServerProcess(proc, port, "nc1", err)
    try:
        h.wait_ready(90)
        yield h
    finally:
        h.kill()


@pytest.fixture(scope="module")
def door(tmp_path_factory: pytest.TempPathFactory, tls_nc: NcServerProcess, pki: Path,
         users_file: Path) -> Iterator[NcOpcuaProcess]:
    p = start_nc_opcua(tmp_path_factory.mktemp("door"), f"tls/127.0.0.1:{tls_nc.port}",
                       ["--users", str(users_file), "--tls-dir", str(pki), "--client-id", "opcua", "--nc", "nc1",
                        "--role", "operator"])
    try:
        yield p
    finally:
        p.stop()


def test_door_acts_as_its_users_under_tls_and_acl(door: NcOpcuaProcess, tls_nc: NcServerProcess, pki: Path) -> None:
    status = NcTestClient(tls_nc.port, client_id="status", token=False, config=tls_config(tls_nc.port, pki, "status"))
    try:
        async def body() -> None:
            async with client(door.url, "alice", "alice-pw") as c:
                await until(lambda: _has(c, "nc1.1.ActPos"), 60, "axis 1 served")
                await call(c, "nc1.1", "Reset")
                st, out = await call(c, "nc1.1", "Power", True, 100.0)
                assert st == 0, (hex(st), out)
                await until(lambda: value(c, "nc1.1.Enabled"), 20, "axis 1 enabled")
                start = float(await value(c, "nc1.1.ActPos"))
                st, out = await call(c, "nc1.1", "MoveRelative", 5.0, 50.0)
                assert st == 0, (hex(st), out)
                await until(lambda: _near(c, "nc1.1.ActPos", start + 5.0), 30, "the move")
                arb = status.request("Info")["Value"]["arbitration"]
                assert {int(a): h for a, h in arb["claims"].items()}.get(1) == "opcua.alice"
                assert arb["clients"]["opcua.alice"]["role"] == "operator"
                assert arb["last_command"][1]["client"] == "opcua.alice"
                assert (await call(c, "nc1.1", "Power", False, 100.0))[0] == 0
            async with client(door.url, "eve", "eve-pw") as c:  # an engineer user; the door is an operator
                st, out = await call(c, "nc1.1", "WriteParameter", "AxisVeloMax", 100.0)
                assert st == ua.StatusCodes.BadUserAccessDenied and "operator" in out[1], (hex(st), out)
        asyncio.run(asyncio.wait_for(body(), 240))
    finally:
        status.close()


async def _has(c: object, node: str) -> bool:
    try:
        await value(c, node)  # type: ignore[arg-type]
        return True
    except Exception:
        return False


async def _near(c: object, node: str, target: float) -> bool:
    return abs(float(await value(c, node)) - target) < 1e-6  # type: ignore[arg-type]


def test_other_certificates_cannot_use_door_user_ids(tls_nc: NcServerProcess, pki: Path) -> None:
    s = zenoh.open(tls_config(tls_nc.port, pki, "plc1"))
    try:
        wait_until(lambda: _info(s, "nc/nc1/cmd/read/plc1") is not None, 30, "plc1's own Info answered")
        assert _info(s, "nc/nc1/cmd/read/opcua.alice") is None  # the door's user id: denied by the router
        assert _info(s, "nc/nc1/cmd/read/plc1.alice") is None  # plc1 is no door
    finally:
        s.close()  # type: ignore[no-untyped-call]


def _info(s: zenoh.Session, key: str) -> dict[str, object] | None:
    from nc_schema import make_request, parse_reply
    client = key.rsplit("/", 1)[1]
    for r in s.get(key, payload=make_request("Info", 1, client), timeout=3.0):
        if r.ok is not None:
            return parse_reply(r.ok.payload.to_bytes())
    return None
