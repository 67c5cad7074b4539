"""The drive hosts' silence timeout must be longer than a hot-standby pair's takeover (issue 21, docs/standby.md):
refused where both are known (the NC's TOML with ``[drives.remote] timeout_ms``; ``nc-drive-sim --config`` with the
timeout it will use), warned where they are not (the NC without ``timeout_ms``; a drive host that learns the bound
from the NC's outputs)."""
from __future__ import annotations

import logging
import tomllib
from pathlib import Path

import numpy as np
import pytest

import nc_server.core  # noqa: F401  (first: nc_server.drives imports the core, which imports drives.base)
from nc_server.core.params import AxisParams, ConfigError
from nc_server.drives.cia402.image import RxImage
from nc_server.drives.remote import host as host_mod, wire
from nc_server.drives.remote.config import (check_timeout, pair_default_timeout, parse_options, takeover_bound,
                                            worst_takeover)
from nc_server.server.config import parse_config

TOML = """
[nc]
name = "nc1"
cycle_time = {cycle}

[zenoh]
listen = ["tcp/127.0.0.1:17999"]
{lease}

{redundancy}

[drives.remote]
max_age = 50
{timeout}

[[axis]]
AxisId = 1
Drive = {{ backend = "remote", host = "drives1" }}
"""


def _text(takeover: int | None = 100, timeout_ms: float | None = None, cycle: float = 0.001,
          lease: int | None = None) -> str:
    red = "" if takeover is None else f"[redundancy]\nenabled = true\ntakeover_cycles = {takeover}\n"
    return TOML.format(cycle=cycle, redundancy=red, timeout="" if timeout_ms is None else f"timeout_ms = {timeout_ms}",
                       lease="" if lease is None else f"lease = {lease}")


def test_the_bound_and_the_check() -> None:
    assert takeover_bound(15, 0.001) == pytest.approx(0.016)
    assert takeover_bound(250, 0.002) == pytest.approx(0.502)
    # the longest takeover the pair may publish: its limit grows under load up to 1 s or the lease, + 1 cycle
    assert worst_takeover(15, 0.001, 0.5) == pytest.approx(0.501)
    assert worst_takeover(15, 0.001, 2.0) == pytest.approx(1.001)
    assert worst_takeover(15, 0.002, 0.2) == pytest.approx(0.202)
    assert worst_takeover(2000, 0.001, 0.5) == pytest.approx(2.001)  # (takeover_cycles beyond: that)
    assert pair_default_timeout(15, 0.001, 0.5) == pytest.approx(0.601)
    check_timeout(0.6, 15, 0.001, "k", 0.5)
    check_timeout(0.25, 15, 0.001, "k", 0.2)
    with pytest.raises(ConfigError) as e:
        check_timeout(0.1, 15, 0.001, "drives.remote.timeout_ms", 0.5)  # the old check (16 ms) let it pass
    assert e.value.key == "drives.remote.timeout_ms" and "100 ms" in e.value.message and "501 ms" in e.value.message
    with pytest.raises(ConfigError) as e:
        check_timeout(0.501, 15, 0.001, "k", 0.5)  # not longer
    assert parse_options({"timeout_ms": 250}).timeout_ms == 250.0 and parse_options({}).timeout_ms is None
    for bad in (0, -5, True, "100", 4e6):
        with pytest.raises(ConfigError) as e:
            parse_options({"timeout_ms": bad})
        assert e.value.key == "drives.remote.timeout_ms"


def test_the_nc_refuses_a_timeout_not_longer_than_its_takeover() -> None:
    with pytest.raises(ConfigError) as e:
        parse_config(tomllib.loads(_text(takeover=100, timeout_ms=150)))  # (the old bound: 101 ms)
    assert e.value.key == "drives.remote.timeout_ms" and "501 ms" in e.value.message
    with pytest.raises(ConfigError) as e:
        parse_config(tomllib.loads(_text(takeover=60, timeout_ms=300, cycle=0.002, lease=300)))  # 302 ms
    assert e.value.key == "drives.remote.timeout_ms" and "302 ms" in e.value.message
    parse_config(tomllib.loads(_text(takeover=100, timeout_ms=600)))
    parse_config(tomllib.loads(_text(takeover=60, timeout_ms=310, cycle=0.002, lease=300)))
    parse_config(tomllib.loads(_text(takeover=None, timeout_ms=5)))  # no pair: nothing to outlast


def test_the_nc_without_timeout_ms_says_what_the_hosts_need(caplog: pytest.LogCaptureFixture) -> None:
    # (nc-drive-sim --config with the pair's TOML takes a long enough default: no warning, the figures in the log)
    with caplog.at_level(logging.INFO, logger="nc_server.config"):
        parse_config(tomllib.loads(_text(takeover=15)))
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING]
    assert any("501 ms" in r.getMessage() and "601 ms" in r.getMessage() and "--timeout" in r.getMessage()
               for r in caplog.records)


def _sim(tmp_path: Path, text: str, *args: str, capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    cfg = tmp_path / "nc.toml"
    cfg.write_text(text)
    rc = host_mod.main(["--config", str(cfg), "--host", "drives1", "--connect", "tcp/127.0.0.1:17999", *args])
    return rc, capsys.readouterr().err


@pytest.mark.parametrize("timeout_ms, args, key", [
    (None, ("--timeout", "0.05"), "--timeout"),
    (None, ("--timeout", "0.3"), "--timeout"),  # (longer than takeover_cycles + 1, not than the worst case)
    (80, (), "drives.remote.timeout_ms"),
])
def test_nc_drive_sim_with_the_pairs_toml_refuses_a_short_timeout(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], timeout_ms: float | None, args: tuple[str, ...],
        key: str) -> None:
    rc, err = _sim(tmp_path, _text(takeover=100, timeout_ms=timeout_ms), *args, capsys=capsys)
    assert rc == 2 and "configuration error" in err and key in err and "501 ms" in err, err


def test_nc_drive_sim_with_the_pairs_toml_takes_a_longer_default_timeout(tmp_path: Path) -> None:
    # (its default 100 ms is below any pair's longest takeover)
    cfg = tmp_path / "nc.toml"
    for lease, want in ((None, 0.601), (200, 0.301)):
        cfg.write_text(_text(takeover=15, lease=lease))
        *_, toml_timeout, pair = host_mod.load_config(str(cfg), "drives1")
        assert toml_timeout is None and pair is not None
        assert pair_default_timeout(*pair) == pytest.approx(want)
        check_timeout(pair_default_timeout(*pair), pair[0], pair[1], "k", pair[2])


def test_nc_drive_sim_learns_the_bound_from_the_outputs_and_warns_once(caplog: pytest.LogCaptureFixture) -> None:
    h = host_mod.DriveHost("nc1", "drives1", [AxisParams()], [1], 0.001, 0.1, 0.01, None)
    rx = RxImage.zeros(1)
    rx.cycle = 1
    msgs: list[wire.RxMessage] = []
    h._take_rx = lambda: msgs.pop(0) if msgs else None  # type: ignore[method-assign]
    for limit in (16.0, 150.0, 150.0):
        msgs.append(wire.decode_rx(wire.encode_rx(rx, None, np.array([1]), 0, limit)))
        with caplog.at_level(logging.WARNING, logger="nc_drive_sim"):
            h.step_once()
    assert h.takeover_limit_ms == 150.0 and h.timeout_short and h.status()["timeout_short"]
    assert h.status()["takeover_limit_ms"] == 150.0
    warned = [r for r in caplog.records if "takeover limit" in r.getMessage()]
    assert len(warned) == 1 and "150 ms" in warned[0].getMessage()
    # a malformed diagnostic value: the outputs are applied, the value ignored (the last kept) and counted
    import msgpack
    m = msgpack.unpackb(wire.encode_rx(rx, None, np.array([1]), 0, 20.0), raw=False)
    m["takeover_limit_ms"] = "x"
    rx.cycle = 2
    m["cycle"] = 2
    msgs.append(wire.decode_rx(msgpack.packb(m)))
    h.step_once()
    assert h.rx_cycle == 2 and h.takeover_limit_ms == 150.0 and h.bad_diagnostics == 1
    assert h.status()["bad_diagnostics"] == 1
    msgs.append(wire.decode_rx(wire.encode_rx(rx, None, np.array([1]), 0, 0.0)))  # no redundancy (any more)
    h.step_once()
    assert h.takeover_limit_ms == 0.0 and not h.timeout_short


def test_the_wire_carries_takeover_limit_ms() -> None:
    rx = RxImage.zeros(2)
    ids = np.array([1, 2])
    assert wire.decode_rx(wire.encode_rx(rx, None, ids)).takeover_limit_ms == 0.0
    assert wire.decode_rx(wire.encode_rx(rx, None, ids, 3, 101.0)).takeover_limit_ms == 101.0
    import msgpack
    m = msgpack.unpackb(wire.encode_rx(rx, None, ids, 3, 101.0), raw=False)
    assert "takeover_limit_ms" in m and "takeover_ms" not in m  # (not the ha status's measured takeover_ms)
    for bad in ("x", -1.0, True, None, [1]):
        m["takeover_limit_ms"] = bad
        got = wire.decode_rx(msgpack.packb(m))  # a diagnostic: the outputs stay usable
        assert got.takeover_limit_ms is None and got.epoch == 3


def test_nc_drive_sim_names_where_a_too_short_timeout_came_from(tmp_path: Path,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    rc, err = _sim(tmp_path, _text(takeover=None, timeout_ms=1.5), capsys=capsys)
    assert rc == 2 and "drives.remote.timeout_ms" in err and "two drive cycles" in err, err
    rc, err = _sim(tmp_path, _text(takeover=None), "--timeout", "0.0015", capsys=capsys)
    assert rc == 2 and "--timeout" in err and "drives.remote.timeout_ms" not in err and "two drive cycles" in err, err


def test_max_age_ms_beyond_the_cycle_limit_is_refused() -> None:
    """``max_age_ms`` of more than 100000 NC cycles is a ConfigError, as ``max_age`` > 100000 is (was: capped)."""
    from nc_server.drives.base import DriveContext
    from nc_server.drives.remote.drive import RemoteDrive
    from nc_server.server.config import ZenohSettings
    with pytest.raises(ConfigError) as e:
        RemoteDrive.from_config([AxisParams()], 0.001, [{"host": "d1"}],
                                DriveContext(options={"max_age_ms": 200_000, "connect": ["tcp/127.0.0.1:17999"]},
                                             zenoh=ZenohSettings()))
    assert e.value.key == "drives.remote.max_age_ms" and "200000 NC cycles" in e.value.message
    with pytest.raises(ConfigError):
        parse_options({"max_age": 100_001})


def test_max_age_as_a_time() -> None:
    """``[drives.remote] max_age_ms``: the same limit as a time, in whole NC cycles (rounded up), not with max_age."""
    o = parse_options({"max_age_ms": 50})
    assert o.max_age_cycles(0.001) == 50 and o.max_age_cycles(0.002) == 25 and o.max_age_cycles(0.004) == 13
    assert parse_options({"max_age_ms": 0.3}).max_age_cycles(0.001) == 1
    assert parse_options({"max_age": 7}).max_age_cycles(0.002) == 7
    for bad, text in (({"max_age_ms": 50, "max_age": 50}, "not both"), ({"max_age_ms": 0}, "> 0"),
                      ({"max_age_ms": "50"}, "> 0"), ({"max_age_ms": True}, "> 0")):
        with pytest.raises(ConfigError) as e:
            parse_options(bad)
        assert e.value.key == "drives.remote.max_age_ms" and text in e.value.message
    from nc_server.drives.base import DriveContext
    from nc_server.drives.remote.drive import RemoteDrive
    from nc_server.server.config import ZenohSettings
    d = RemoteDrive.from_config([AxisParams()], 0.002, [{"host": "d1"}],
                                DriveContext(options={"max_age_ms": 30, "connect": ["tcp/127.0.0.1:17999"]},
                                             zenoh=ZenohSettings()))
    try:
        assert d.max_age == 15
    finally:
        d.close()
