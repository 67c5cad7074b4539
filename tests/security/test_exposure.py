"""What the defaults mean, said at start: nc-server's exposure line, nc-ads's write warning, and 0x723
texts that name the rule that refused."""
from __future__ import annotations

import logging
from pathlib import Path

import pytest

from nc_schema import error_text
from nc_schema.endpoints import endpoint_is_local, is_loopback_host
from nc_server.core import NcCore
from nc_server.security.exposure import exposure
from nc_server.server.app import NcServer
from nc_server.server.config import load_config

from test_config_security import ROLES, fake_certs


@pytest.mark.parametrize("endpoint, local", [
    ("tcp/127.0.0.1:7500", True), ("tcp/127.3.4.5:7500", True), ("tls/[::1]:7500", True),
    ("tcp/localhost:7500", True), ("udp/127.0.0.1:7500#iface=lo", True), ("tcp/[::ffff:127.0.0.1]:7500", True),
    ("unixsock-stream//tmp/nc.sock", True),
    ("tcp/0.0.0.0:7500", False), ("tcp/[::]:7500", False), ("tcp/192.0.2.7:7500", False),
    ("tls/nc1.plant.example:7500", False), ("quic/10.1.2.3:7500", False),
])
def test_endpoint_is_local(endpoint: str, local: bool) -> None:
    assert endpoint_is_local(endpoint) is local


def test_is_loopback_host() -> None:
    assert is_loopback_host("127.0.0.1") and is_loopback_host("::1") and is_loopback_host("LOCALHOST")
    assert not is_loopback_host("0.0.0.0") and not is_loopback_host("nc1") and not is_loopback_host("")


def test_exposure_levels() -> None:
    level, text = exposure(["tcp/127.0.0.1:7500", "tcp/0.0.0.0:7501"], None, False)  # type: ignore[misc]
    assert level == logging.WARNING
    assert "tcp/0.0.0.0:7501" in text and "tcp/127.0.0.1:7500" not in text  # names the exposed endpoint
    assert "--tls-dir" in text and "--roles" in text  # and the fix
    level, text = exposure(["tcp/127.0.0.1:7500"], None, False)  # type: ignore[misc]
    assert level == logging.INFO and "loopback" in text
    # TLS or roles: their own lines (half-configured) or nothing to say
    assert exposure(["tls/0.0.0.0:7500"], "/certs", True) is None
    assert exposure(["tcp/0.0.0.0:7500"], None, True) is None
    assert exposure([], None, False) is None  # client mode: listens nowhere


def _server_log(tmp_path: Path, caplog: pytest.LogCaptureFixture, **kw: object) -> list[logging.LogRecord]:
    cfg = load_config(**kw)  # type: ignore[arg-type]
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="nc_server"):
        srv = NcServer(cfg, NcCore(list(cfg.axes), cfg.cycle_time))  # zenoh is not opened by the constructor
        srv.frames.close()
    return [r for r in caplog.records if "TLS" in r.getMessage()]


def test_nc_server_says_what_its_defaults_mean(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    # beyond loopback, no TLS, no roles: one WARNING (the address is only formatted, never bound here)
    recs = _server_log(tmp_path, caplog, listen=["tcp/192.0.2.7:17500"])
    assert [r.levelno for r in recs] == [logging.WARNING], recs
    assert "192.0.2.7" in recs[0].getMessage() and "--roles" in recs[0].getMessage()
    # loopback: INFO only (the demo stays quiet at its default WARNING level)
    recs = _server_log(tmp_path, caplog, listen=["tcp/127.0.0.1:17500"])
    assert [r.levelno for r in recs] == [logging.INFO], recs
    # TLS + roles: no exposure line
    certs = fake_certs(tmp_path / "certs", "nc1")
    recs = _server_log(tmp_path, caplog, listen=["tls/127.0.0.1:17500"], roles=str(ROLES), tls_dir=str(certs))
    assert not [r for r in recs if "without TLS" in r.getMessage()], recs


def test_access_denied_table_text_names_no_rule() -> None:
    # the code's table text is generic: the rule that refused is the NC's detail, never a fixed guess
    assert error_text(0x723) == "access denied"



def test_nc_ads_says_who_may_write() -> None:
    from nc_ads.cli import write_exposure
    level, text = write_exposure("0.0.0.0", "operator", False)  # type: ignore[misc]
    assert level == logging.WARNING and "0.0.0.0" in text and "--allow-write" in text and "127.0.0.1" in text
    level, text = write_exposure("127.0.0.1", "engineer", False)  # type: ignore[misc]
    assert level == logging.INFO and "loopback" in text
    assert write_exposure("0.0.0.0", "observer", False) is None  # writes refused anyway (its role)
    assert write_exposure("0.0.0.0", "operator", True) is None  # the write policy decides
