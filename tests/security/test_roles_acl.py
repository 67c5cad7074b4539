"""The roles file, the access control generated from it, the TLS section (no network)."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import zenoh

from nc_schema import Keys, new_instance_id
from nc_server.security.acl import NC_ALIVE, READ_KEYS, access_control, command_keys, main as nc_acl, with_local_publisher
from nc_server.security.roles import Roles, RolesError, load_roles, parse_roles
from nc_schema.tls import TlsError, apply_tls, check_tls_endpoints, tls_section

REPO = Path(__file__).resolve().parents[2]
EXAMPLE = REPO / "deploy" / "roles.toml"


def test_the_example_roles_file() -> None:
    r = load_roles(EXAMPLE)
    assert dict(r.clients) == {"plc1": "operator", "plc2": "operator", "eng1": "engineer", "status": "observer",
                               "opcua": "engineer", "web": "engineer"}
    assert r.doors == ("opcua", "web") and r.role_of("opcua.alice") == "engineer" and r.role_of("plc1.alice") is None
    assert r.role_of("web.bob") == "engineer"
    assert r.ncs == ("nc1", "nc2") and r.routers == ("router",)
    assert r.role_of("plc1") == "operator" and r.role_of("nobody") is None
    assert r.classes_of("eng1") == ("read", "op", "eng") and r.classes_of("status") == ("read",)
    assert r.classes_of("nobody") == ()


@pytest.mark.parametrize("text, key, words", [
    ("[client.a]\nrole = 'admin'\n", "client.a.role", "observer"),
    ("[client.a]\n", "client.a.role", "missing"),
    ("[client.a]\nrole = 'operator'\nncs = ['nc1']\n", "client.a.ncs", "unknown key"),
    ("[client.'a b']\nrole = 'operator'\n", "client.a b", "invalid client id"),
    ("[clients.a]\nrole = 'operator'\n", "clients", "unknown section"),
    ("[client.a]\nrole = 'operator'\n[nc.a]\n", "nc.a", "also [client.a]"),
    ("[nc.nc1]\nlisten = 'x'\n", "nc.nc1.listen", "allowed: masters"),
    ("[nc.nc2]\nmasters = ['nc2']\n", "nc.nc2.masters", "its own axes"),
    ("[nc.nc2]\nmasters = 'nc1'\n", "nc.nc2.masters", "list of NC names"),
    ("[router.r]\n", "", "lists no"),
    # a hot-standby node watches the active NC's frames as the client ha-<node> (docs/standby.md)
    ("[client.ha-b]\nrole = 'observer'\n", "client.ha-b", "reserved"),
    ("client = 3\n", "client", "must be a table"),
    ("[client]\na = 1\n", "client.a", "must be a table"),
    ("[nc.'n/1']\n", "nc.n/1", "invalid"),
    # the door's certificate may use every opcua.$* id: none may be listed (it could act as it)
    ("[client.opcua]\nrole = 'engineer'\ndoor = true\n[client.'opcua.visitor']\nrole = 'observer'\n",
     "client.opcua.visitor", "under door 'opcua'"),
    ("[client.'opcua.visitor']\nrole = 'engineer'\n[client.opcua]\nrole = 'observer'\ndoor = true\n",
     "client.opcua.visitor", "under door 'opcua'"),
    ("[client.opcua]\nrole = 'engineer'\ndoor = true\n[client.'opcua.web']\nrole = 'operator'\ndoor = true\n",
     "client.opcua.web", "nested in door 'opcua'"),
    ("[client.opcua]\nrole = 'engineer'\ndoor = true\n[drive.'opcua.h1']\nnc = 'nc1'\n",
     "drive.opcua.h1", "under door 'opcua'"),
])
def test_roles_errors_name_the_entry(tmp_path: Path, text: str, key: str, words: str) -> None:
    p = tmp_path / "roles.toml"
    p.write_text(text)
    with pytest.raises(RolesError) as ei:
        load_roles(p)
    e = ei.value
    assert e.file == str(p) and e.key == key and words in e.message, e
    assert str(e).startswith(str(p))


def test_unreadable_and_broken_files(tmp_path: Path) -> None:
    with pytest.raises(RolesError, match="cannot read"):
        load_roles(tmp_path / "missing.toml")
    (tmp_path / "bad.toml").write_text("[client.a\n")
    with pytest.raises(RolesError, match="TOML syntax error"):
        load_roles(tmp_path / "bad.toml")


def rules_of(acl: dict, subject: str) -> list[dict]:
    pol = next(p for p in acl["policies"] if p["subjects"] == [subject])
    by_id = {r["id"]: r for r in acl["rules"]}
    return [by_id[i] for i in pol["rules"]]


def allowed(acl: dict, subject: str, flow: str, message: str) -> set[str]:
    """The key expressions ``subject`` may use for ``message`` in ``flow``."""
    return {k for r in rules_of(acl, subject) if flow in r["flows"] and message in r["messages"] for k in r["key_exprs"]}


def test_generated_access_control() -> None:
    acl = access_control(load_roles(EXAMPLE))
    assert acl["enabled"] is True and acl["default_permission"] == "deny"
    assert all(r["permission"] == "allow" for r in acl["rules"])
    ids = [r["id"] for r in acl["rules"]]
    assert len(ids) == len(set(ids))
    subjects = {s["id"]: s for s in acl["subjects"]}
    assert set(subjects) == {"client:plc1", "client:plc2", "client:eng1", "client:status", "client:opcua", "client:web",
                             "nc:nc1", "nc:nc2", "router:router", "drive:drives1"}
    assert all(s["cert_common_names"] == [s["id"].split(":", 1)[1]] and set(s) == {"id", "cert_common_names"}
               for s in subjects.values())
    # everybody reads the cyclic data (and its own view: below)
    for c in ("plc1", "eng1", "status"):
        assert allowed(acl, f"client:{c}", "ingress", "declare_subscriber") >= set(READ_KEYS)
        assert allowed(acl, f"client:{c}", "egress", "put") >= set(READ_KEYS)
        # the NCs' tokens: reachable, and each NC process's instance token (how a restart is told from a flap)
        for msg in ("declare_liveliness_subscriber", "liveliness_query"):
            assert allowed(acl, f"client:{c}", "ingress", msg) == {"nc/*/alive", "nc/*/alive/*"}
        for msg in ("liveliness_token", "reply"):
            assert {"nc/*/alive", "nc/*/alive/*"} <= allowed(acl, f"client:{c}", "egress", msg)
    # queries: own keys of the role's classes only; replies on the same
    assert allowed(acl, "client:status", "ingress", "query") == set(command_keys("status", ["read"]))
    assert allowed(acl, "client:plc1", "ingress", "query") == set(command_keys("plc1", ["read", "op"]))
    assert allowed(acl, "client:eng1", "ingress", "query") == set(command_keys("eng1", ["read", "op", "eng"]))
    for c in ("status", "plc1", "eng1"):
        assert allowed(acl, f"client:{c}", "egress", "reply") >= allowed(acl, f"client:{c}", "ingress", "query")
    # PLCTONC and the liveliness token: operators/engineers, own keys only
    assert allowed(acl, "client:plc1", "ingress", "put") == {"nc/*/plctonc/plc1"}
    assert allowed(acl, "client:plc1", "ingress", "liveliness_token") == {"nc/*/client/plc1", "nc/*/select/plc1/**"}
    assert allowed(acl, "client:status", "ingress", "put") == set()
    # a door (door = true): also its users' ids <id>.<user>, with its own role's classes (docs/roles.md)
    assert allowed(acl, "client:opcua", "ingress", "query") == set(
        command_keys("opcua", ["read", "op", "eng"]) + command_keys("opcua.$*", ["read", "op", "eng"]))
    assert allowed(acl, "client:opcua", "ingress", "put") == {"nc/*/plctonc/opcua", "nc/*/plctonc/opcua.$*"}
    # the view (issue 19): every listed client, its own token and its own view only
    for c in ("status", "plc1", "eng1"):
        assert allowed(acl, f"client:{c}", "ingress", "declare_subscriber") == set(READ_KEYS) | {f"nc/*/view/{c}"}
        assert allowed(acl, f"client:{c}", "egress", "put") == set(READ_KEYS) | {f"nc/*/view/{c}"}
    assert allowed(acl, "client:status", "ingress", "liveliness_token") == {"nc/*/select/status/**"}
    # gotcha: the declared PLCTONC publisher must see the NC's subscriber nc/<nc>/plctonc/* (inclusion)
    assert "nc/*/plctonc/*" in allowed(acl, "client:plc1", "egress", "declare_subscriber")
    # no client may declare a queryable (impersonate an NC)
    for c in ("status", "plc1", "eng1"):
        assert allowed(acl, f"client:{c}", "ingress", "declare_queryable") == set()
    # an NC: only its own prefix
    assert allowed(acl, "nc:nc1", "ingress", "declare_queryable") == {"nc/nc1/**"}
    assert allowed(acl, "nc:nc1", "ingress", "put") == {"nc/nc1/**"}
    assert allowed(acl, "nc:nc1", "egress", "query") == {"nc/nc1/**"}
    # its one query: a hot-standby node's snapshot from the active node of its own NC (docs/standby.md)
    assert allowed(acl, "nc:nc1", "ingress", "query") == {"nc/nc1/ha/snapshot"}
    assert allowed(acl, "nc:nc2", "ingress", "query") == {"nc/nc2/ha/snapshot"}
    assert allowed(acl, "nc:nc1", "egress", "declare_subscriber") == {"nc/**"}
    # its liveliness tokens nc/nc1/alive and nc/nc1/alive/<instance>: below its own prefix only
    assert allowed(acl, "nc:nc1", "ingress", "liveliness_token") == {"nc/nc1/**"}
    assert allowed(acl, "nc:nc2", "ingress", "liveliness_token") == {"nc/nc2/**"}


def test_zenoh_accepts_it(tmp_path: Path) -> None:
    acl = access_control(parse_roles({"client": {"x": {"role": "observer"}}}))
    c = zenoh.Config()
    c.insert_json5("access_control", json.dumps(acl))  # unknown fields or message names would raise
    with pytest.raises(ValueError):
        access_control(Roles())


def test_nc_acl_prints_json(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    assert nc_acl([str(EXAMPLE)]) == 0
    assert json.loads(capsys.readouterr().out) == access_control(load_roles(EXAMPLE))
    (tmp_path / "r.toml").write_text("[client.a]\nrole = 'root'\n")
    assert nc_acl([str(tmp_path / "r.toml")]) == 2
    assert "client.a.role" in capsys.readouterr().err
    # and as a module (what the console script runs)
    out = subprocess.run([sys.executable, "-m", "nc_server.security.acl", str(EXAMPLE), "--indent", "0"],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and json.loads(out.stdout)["default_permission"] == "deny"


def test_tls_section(tmp_path: Path) -> None:
    with pytest.raises(TlsError, match="missing ca.pem, plc1.pem, plc1.key"):
        tls_section(tmp_path, "plc1")
    for n in ("ca.pem", "plc1.pem", "plc1.key"):
        (tmp_path / n).write_text("x")
    t = tls_section(tmp_path, "plc1")
    assert t["enable_mtls"] is True and t["verify_name_on_connect"] is True
    assert t["connect_certificate"] == t["listen_certificate"] == str((tmp_path / "plc1.pem").resolve())
    assert t["root_ca_certificate"] == str((tmp_path / "ca.pem").resolve())
    c = zenoh.Config()
    apply_tls(c, tmp_path, "plc1")
    assert json.loads(c.get_json("transport/link/protocols")) == ["tls"]
    check_tls_endpoints(["tls/127.0.0.1:1"], "x")
    with pytest.raises(TlsError, match="tcp/127.0.0.1:1"):
        check_tls_endpoints(["tls/127.0.0.1:1", "tcp/127.0.0.1:1"], "x")


def _includes(rule: str, key: str) -> bool:
    """A rule key expression of single-chunk wildcards (``*``) includes a concrete key."""
    r, k = rule.split("/"), key.split("/")
    return len(r) == len(k) and all(a == "*" or a == b for a, b in zip(r, k))


def test_keys_of_the_acl_are_the_protocols() -> None:
    """The generator's command keys include the ones Keys builds (zenoh matches by inclusion)."""
    k = Keys("nc1")
    pats = command_keys("plc1", ["read", "op"])
    for key in (k.axis_cmd(1, "op", "plc1"), k.cmd("read", "plc1"), k.axis_cmd(65535, "read", "plc1"),
                k.command_key("Info", None, "plc1"), k.command_key("MoveAbsolute", 3, "plc1")):
        assert any(_includes(p, key) for p in pats), key
    for key in (k.axis_cmd(1, "eng", "plc1"), k.axis_cmd(1, "op", "plc2"), k.command_key("WriteParameter", 1, "plc1")):
        assert not any(_includes(p, key) for p in pats), key
    assert _includes("nc/*/plctonc/plc1", k.plctonc_in("plc1")) and _includes("nc/*/client/plc1", k.client_alive("plc1"))
    assert [p for p in NC_ALIVE if _includes(p, k.alive)] == ["nc/*/alive"]
    assert [p for p in NC_ALIVE if _includes(p, k.alive_instance(new_instance_id()))] == ["nc/*/alive/*"]
    assert _includes("nc/*/alive/*", k.alive_instance_any)  # what the clients watch
    assert all(any(_includes(p, key) for p in READ_KEYS)
               for key in (k.frame, k.status, k.stats, k.claims, k.axis_nctoplc(2), k.axis_plctonc(2)))
    # the view: a client's token and view keys are included in its own rules, never in another's
    def zincludes(rule: str, key: str) -> bool:  # zenoh's own inclusion (the rules use "**")
        return bool(zenoh.KeyExpr(rule).includes(zenoh.KeyExpr(key)))
    assert zincludes("nc/*/select/plc1/**", k.view_select("plc1", 5, [1, 2, 300]))
    assert zincludes("nc/*/select/plc1/**", k.view_select("plc1", 0, []))
    assert not zincludes("nc/*/select/plc1/**", k.view_select("plc2", 5, [1]))
    assert zincludes("nc/*/view/plc1", k.view("plc1")) and not zincludes("nc/*/view/plc1", k.view("plc2"))
    assert zincludes("nc/nc1/**", k.view_select_any)  # what the NC's publisher watches: its own prefix
    assert zincludes(k.view_select_any, k.view_select("plc1", 5, [1, 2]))


def test_the_local_publisher_gets_exactly_its_ncs_rules() -> None:
    roles = parse_roles({"nc": {"nc1": {}, "nc2": {}}, "client": {"plc1": {"role": "operator"}}}, "t")
    acl = access_control(roles)
    out = with_local_publisher(acl, "nc1")
    sub = [s for s in out["subjects"] if s["id"] == "nc:nc1:local-publisher"]
    assert sub == [{"id": "nc:nc1:local-publisher", "link_protocols": ["unixsock-stream"]}]
    pol = [p for p in out["policies"] if p["subjects"] == ["nc:nc1:local-publisher"]]
    assert len(pol) == 1 and set(pol[0]["rules"]) == {"nc:nc1:in", "nc:nc1:out", "see:subscribers"}
    assert out["subjects"][:-1] == acl["subjects"] and acl["policies"] == out["policies"][:-1]  # nothing else
    with pytest.raises(ValueError, match="nc3"):
        with_local_publisher(acl, "nc3")
