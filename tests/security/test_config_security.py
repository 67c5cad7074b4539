"""``--roles`` / ``--tls-dir`` of nc-server, nc-router and plc-run: checked before anything opens."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

from nc_server import router
from nc_server.core.params import ConfigError
from nc_server.server.config import load_config
from plc_client import cli as plc_cli
from plc_client.runtime import PlcRuntime

REPO = Path(__file__).resolve().parents[2]
ROLES = REPO / "deploy" / "roles.toml"


def fake_certs(d: Path, *names: str) -> Path:
    """Files with the names make-certs.sh writes (the config checks only that they exist)."""
    d.mkdir(parents=True, exist_ok=True)
    (d / "ca.pem").write_text("x")
    for n in names:
        (d / f"{n}.pem").write_text("x")
        (d / f"{n}.key").write_text("x")
    return d


def test_nc_server_roles_and_tls(tmp_path: Path) -> None:
    certs = fake_certs(tmp_path / "certs", "nc1")
    cfg = load_config(listen=["tls/127.0.0.1:17447"], roles=str(ROLES), tls_dir=str(certs))
    assert cfg.roles is not None and cfg.roles.role_of("plc1") == "operator"
    assert cfg.zenoh.tls_dir == str(certs.resolve())
    assert load_config().roles is None and load_config().zenoh.tls_dir is None  # the default: neither
    # relative paths, also in a config file, are the working directory's (as nc.retain_file)
    (tmp_path / "conf").mkdir()
    (tmp_path / "conf" / "roles.toml").write_text(ROLES.read_text())
    fake_certs(tmp_path / "conf" / "c", "lathe")
    p = tmp_path / "conf" / "nc.toml"
    p.write_text('[nc]\nname = "lathe"\n[zenoh]\nlisten = ["tls/127.0.0.1:1"]\nroles = "conf/roles.toml"\n'
                 'tls_dir = "conf/c"\n[[axis]]\nAxisId = 1\n')
    old_cwd = os.getcwd()
    os.chdir(tmp_path)
    try:
        with pytest.raises(ConfigError) as ei:  # lathe is not an [nc.*] of the roles file
            load_config(p)
        assert ei.value.key == "zenoh.roles" and "[nc.lathe]" in str(ei.value)
        (tmp_path / "conf" / "roles.toml").write_text(ROLES.read_text() + "\n[nc.lathe]\n")
        cfg = load_config(p)
    finally:
        os.chdir(old_cwd)
    assert cfg.zenoh.tls_dir == str((tmp_path / "conf" / "c").resolve()) and "lathe" in cfg.roles.ncs


@pytest.mark.parametrize("kw, key, words", [
    ({"tls_dir": "missing-dir", "listen": ["tls/127.0.0.1:1"]}, "zenoh.tls_dir", "missing ca.pem, nc1.pem, nc1.key"),
    ({"tls_dir": "certs"}, "zenoh.tls_dir", "tcp/127.0.0.1:7447"),  # the default tcp listen endpoint
    ({"roles": "nope.toml"}, "zenoh.roles", "cannot read"),
    ({"roles": "bad.toml"}, "zenoh.roles", "client.x.role"),
])
def test_nc_server_security_errors(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, kw: dict, key: str,
                                   words: str) -> None:
    monkeypatch.chdir(tmp_path)
    fake_certs(tmp_path / "certs", "nc1")
    (tmp_path / "bad.toml").write_text("[client.x]\nrole = 'god'\n[nc.nc1]\n")
    with pytest.raises(ConfigError) as ei:
        load_config(**kw)
    assert ei.value.key == key and words in str(ei.value), str(ei.value)


def test_nc_server_cli_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from nc_server.server import cli
    assert cli.main(["--roles", str(tmp_path / "none.toml")]) == 2
    assert "zenoh.roles" in capsys.readouterr().err


def test_nc_router_security_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    certs = fake_certs(tmp_path / "certs", "router")
    assert router.main(["--listen", "tls/127.0.0.1:1", "--roles", str(ROLES)]) == 2
    assert "needs --tls-dir" in capsys.readouterr().err
    assert router.main(["--listen", "tcp/127.0.0.1:1", "--tls-dir", str(certs)]) == 2
    assert "tls/" in capsys.readouterr().err
    assert router.main(["--listen", "tls/127.0.0.1:1", "--tls-dir", str(tmp_path)]) == 2
    assert "missing" in capsys.readouterr().err
    (tmp_path / "r.toml").write_text("[client.a]\nrole = 'root'\n")
    assert router.main(["--listen", "tls/127.0.0.1:1", "--tls-dir", str(certs), "--roles", str(tmp_path / "r.toml")]) == 2
    assert "client.a.role" in capsys.readouterr().err
    extra = router.security_extra(str(certs), "router", str(ROLES), ["tls/127.0.0.1:1"])
    assert set(extra) == {"transport/link/tls", "transport/link/protocols", "access_control"}
    assert extra["transport/link/tls"]["listen_certificate"].endswith("router.pem")


def test_plc_run_tls_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    certs = fake_certs(tmp_path / "certs", "plc1")
    with pytest.raises(ValueError, match="missing ca.pem, plc2.pem, plc2.key|missing plc2.pem"):
        PlcRuntime(None, {"nc1": "tls/127.0.0.1:1"}, client_id="plc2", tls_dir=str(certs))
    with pytest.raises(ValueError, match="tcp/127.0.0.1:1"):
        PlcRuntime(None, {"nc1": "tcp/127.0.0.1:1"}, client_id="plc1", tls_dir=str(certs))
    rt = PlcRuntime(None, {"nc1": "tls/127.0.0.1:1"}, client_id="plc1", tls_dir=str(certs))
    assert rt.tls_dir == str(certs)
    prog = tmp_path / "p.py"
    prog.write_text("def cycle(plc):\n    pass\n")
    assert plc_cli.main([str(prog), "--client-id", "plc9", "--nc", "nc1=tls/127.0.0.1:1", "--tls-dir", str(certs)]) == 2
    assert "plc9.pem" in capsys.readouterr().err


def _ext(pem: Path) -> str:
    import subprocess

    return subprocess.run(["openssl", "x509", "-in", str(pem), "-noout", "-ext", "extendedKeyUsage,subjectAltName"],
                          capture_output=True, text=True, check=True, timeout=30).stdout


def test_make_certs_client_certificates_are_client_only(certs: Path) -> None:
    """make-certs.sh: a client's certificate carries EKU clientAuth only and no localhost SAN (it
    serves no listener); the router's and the --server ids' (nc1, nc2 here) serve one too."""
    for name in ("plc1", "plc2", "eng1", "status", "stranger"):
        ext = _ext(certs / f"{name}.pem")
        assert "TLS Web Client Authentication" in ext and "Server Authentication" not in ext, (name, ext)
        assert f"DNS:{name}" in ext and "localhost" not in ext and "127.0.0.1" not in ext, (name, ext)
    for name in ("router", "nc1", "nc2"):
        ext = _ext(certs / f"{name}.pem")
        assert "TLS Web Server Authentication" in ext and "TLS Web Client Authentication" in ext, (name, ext)
        assert "DNS:localhost" in ext and "IP Address:127.0.0.1" in ext, (name, ext)
    assert "Server Authentication" not in _ext(certs / "rogue" / "plc1.pem")
