"""Server configuration: the embedded default, overrides, and errors that name their key."""
from __future__ import annotations

from pathlib import Path

import pytest

from nc_server.core.params import ConfigError
from nc_server.server import cli
from nc_server.server.config import default_config_text, load_config

DEFAULT = default_config_text()


def write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "nc.toml"
    p.write_text(text)
    return p


def test_default_config() -> None:
    cfg = load_config()
    assert cfg.name == "nc1"
    assert cfg.cycle_time == 0.001
    assert cfg.watchdog_timeout == 0.5
    assert cfg.realtime == "auto"
    assert cfg.drive == "cia402-sim"
    assert cfg.zenoh.mode == "router"
    assert cfg.zenoh.listen == ("tcp/127.0.0.1:7447",)
    assert cfg.zenoh.lease_ms == 500  # a frozen NC is dropped by its peers within ~0.4 s
    assert [(a.AxisId, a.Name) for a in cfg.axes] == [(1, "X"), (2, "Y"), (3, "Z"), (4, "C")]
    c = cfg.axes[3].params
    assert c.Modulo and c.AxisEncoderModuloValue == 360.0
    assert not any(a.params.Modulo for a in cfg.axes[:3])
    assert any(a.params.AxisEnMinSoftPosLimit and a.params.AxisEnMaxSoftPosLimit for a in cfg.axes)


def test_default_is_package_data() -> None:
    # Shipped next to config.py and read through importlib.resources (works from a wheel too).
    assert "[[axis]]" in DEFAULT and 'name = "nc1"' in DEFAULT


def test_overrides(tmp_path: Path) -> None:
    cfg = load_config(listen=["tcp/127.0.0.1:17000", "tcp/127.0.0.1:17001"], name="mill", cycle_time=0.002,
                      realtime="off", watchdog_timeout=1.5)
    assert cfg.zenoh.listen == ("tcp/127.0.0.1:17000", "tcp/127.0.0.1:17001")
    assert (cfg.name, cfg.cycle_time, cfg.realtime, cfg.watchdog_timeout) == ("mill", 0.002, "off", 1.5)
    # --config replaces the default as a whole
    p = write(tmp_path, '[nc]\nname = "lathe"\n[[axis]]\nAxisId = 7\nName = "S"\n')
    cfg = load_config(p)
    assert cfg.name == "lathe" and [a.AxisId for a in cfg.axes] == [7]
    assert cfg.drive == "cia402-sim"  # the default when [nc] has no drive
    assert cfg.zenoh.listen == ("tcp/127.0.0.1:7447",)


@pytest.mark.parametrize("text, key", [
    ("[nc]\nname = 'x'\n[bogus]\n", "bogus"),
    ("[nc]\ncylce_time = 0.001\n", "nc.cylce_time"),
    ("[nc]\ncycle_time = 'fast'\n", "nc.cycle_time"),
    ("[nc]\ncycle_time = 0.0\n", "nc.cycle_time"),
    ("[nc]\nwatchdog_timeout = true\n", "nc.watchdog_timeout"),
    ("[nc]\nrealtime = 'always'\n", "nc.realtime"),
    ("[nc]\nrt_priority = 120\n", "nc.rt_priority"),
    ("[nc]\nname = 'a/b'\n", "nc.name"),
    ("[nc]\ndrive = 'ethercat'\n", "nc.drive"),
    ("[nc]\ndrive = 1\n", "nc.drive"),
    ("[zenoh]\nlisten = ['127.0.0.1:7447']\n", "zenoh.listen[0]"),
    ("[zenoh]\nlisten = ['tcp/127.0.0.1:99999']\n", "zenoh.listen[0]"),
    ("[zenoh]\nlisten = 'tcp/127.0.0.1:7447'\n", "zenoh.listen"),
    ("[zenoh]\nlisten = []\n", "zenoh.listen"),
    ("[zenoh]\nconnect = ['foo/bar']\n", "zenoh.connect[0]"),
    ("[zenoh]\nmode = 'server'\n", "zenoh.mode"),
    ("[zenoh]\nlease = 1.5\n", "zenoh.lease"),
    ("[zenoh]\nmulticast = true\n", "zenoh.multicast"),
    ("[nc]\npublisher = 'fork'\n", "nc.publisher"),
    ("[nc]\ncpu_affinity = [4096]\n", "nc.cpu_affinity"),
    ("[nc]\ncpu_affinity = ['1']\n", "nc.cpu_affinity"),
    ("[nc]\ncpu_affinity = true\n", "nc.cpu_affinity"),
])
def test_errors_name_the_key(tmp_path: Path, text: str, key: str) -> None:
    text += "\n[[axis]]\nAxisId = 1\n"
    with pytest.raises(ConfigError) as ei:
        load_config(write(tmp_path, text))
    assert ei.value.key == key, str(ei.value)
    assert key in str(ei.value)


@pytest.mark.parametrize("axes, key", [
    ("", "axis"),
    ("[[axis]]\nName = 'X'\n", "axis[0].AxisId"),
    ("[[axis]]\nAxisId = 1\n[[axis]]\nAxisId = 1\n", "axis[1].AxisId"),
    ("[[axis]]\nAxisId = 1\nName = 'X'\n[[axis]]\nAxisId = 2\nName = 'X'\n", "axis[1].Name"),
    ("[[axis]]\nAxisId = 0\n", "axis[0].AxisId"),
    ("[[axis]]\nAxisId = 'one'\n", "axis[0].AxisId"),
    ("[[axis]]\nAxisId = 1\nAxisVeloMaxx = 5.0\n", "axis[0].AxisVeloMaxx"),
    ("[[axis]]\nAxisId = 1\nAxisVeloMax = -5.0\n", "axis[0].AxisVeloMax"),
    ("[[axis]]\nAxisId = 1\nModulo = 'yes'\n", "axis[0].Modulo"),
    ("[[axis]]\nAxisId = 1\nAxisEnMinSoftPosLimit = true\nAxisEnMaxSoftPosLimit = true\n"
     "AxisMinSoftPosLimit = 10.0\nAxisMaxSoftPosLimit = 0.0\n", "axis[0].AxisMinSoftPosLimit"),
    ("[[axis]]\nAxisId = 1\nClientLossReaction = 'halt'\n", "axis[0].ClientLossReaction"),
    ("[[axis]]\nAxisId = 1\nClientLossReaction = 1\n", "axis[0].ClientLossReaction"),
])
def test_axis_errors_name_the_key(tmp_path: Path, axes: str, key: str) -> None:
    with pytest.raises(ConfigError) as ei:
        load_config(write(tmp_path, "[nc]\nname = 'nc1'\n" + axes))
    assert ei.value.key == key, str(ei.value)


def test_file_errors(tmp_path: Path) -> None:
    with pytest.raises(ConfigError) as ei:
        load_config(tmp_path / "missing.toml")
    assert ei.value.key == "--config"
    with pytest.raises(ConfigError) as ei:
        load_config(write(tmp_path, "[nc\nname = 1\n"))
    assert ei.value.key == "--config" and "TOML" in str(ei.value)


def test_cli_exits_2_naming_the_key(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    p = write(tmp_path, DEFAULT.replace("AxisId = 3", "AxisId = 2"))
    assert cli.main(["--config", str(p)]) == 2
    err = capsys.readouterr().err
    assert "axis[2].AxisId" in err and "duplicate" in err
    assert err.count("\n") == 1  # one clear line, no traceback

    assert cli.main(["--listen", "tcp/127.0.0.1:70000"]) == 2
    assert "--listen[0]" in capsys.readouterr().err
    assert cli.main(["--cycle-time", "-1"]) == 2
    assert "nc.cycle_time" in capsys.readouterr().err
    with pytest.raises(SystemExit) as ei:
        cli.main(["--realtime", "sometimes"])
    assert ei.value.code == 2


class _FakeEntryPoint:
    def __init__(self, name: str, obj: object) -> None:
        self.name, self._obj = name, obj

    def load(self) -> object:
        return self._obj


def _install_drive(monkeypatch: pytest.MonkeyPatch, name: str, cls: type) -> None:
    import nc_server.drives as drives

    real = drives.entry_points
    monkeypatch.setattr(drives, "entry_points",
                        lambda group: [*real(group=group), _FakeEntryPoint(name, cls)] if group == drives.GROUP else [])


def test_unknown_drive_is_refused_naming_the_key_and_the_drives(tmp_path: Path,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(ConfigError) as ei:
        load_config(write(tmp_path, DEFAULT.replace('drive = "cia402-sim"', 'drive = "ethercat"')))
    assert ei.value.key == "nc.drive"
    assert "'ethercat'" in str(ei.value) and "sim" in str(ei.value)
    assert cli.main(["--config", str(tmp_path / "nc.toml")]) == 2
    err = capsys.readouterr().err
    assert "configuration error: nc.drive" in err and "sim" in err and err.count("\n") == 1


def test_drive_is_chosen_by_the_config(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from nc_server.drives import SimDrive, drive_class, drive_names

    built: list[tuple[int, float]] = []

    class RefusingDrive(SimDrive):  # refuses its parameters: nc-server exits 2 before zenoh starts
        def __init__(self, params, cycle_time):  # type: ignore[no-untyped-def]
            built.append((len(params), cycle_time))
            raise ConfigError("axis[0].AxisVeloMax", "above what this drive can do")

    class MissingDrive(SimDrive):  # its hardware is absent: a start failure, exit 1
        def __init__(self, params, cycle_time):  # type: ignore[no-untyped-def]
            raise OSError("no EtherCAT master")

    _install_drive(monkeypatch, "refusing", RefusingDrive)
    assert {"refusing", "sim"} <= set(drive_names()) and drive_class("refusing") is RefusingDrive
    cfg = load_config(write(tmp_path, DEFAULT.replace('drive = "cia402-sim"', 'drive = "refusing"')))
    assert cfg.drive == "refusing"
    assert cli._run(cfg) == 2 and built == [(4, 0.001)]

    _install_drive(monkeypatch, "missing", MissingDrive)
    assert cli._run(load_config(write(tmp_path, DEFAULT.replace('drive = "cia402-sim"', 'drive = "missing"')))) == 1


def test_client_mode_behind_a_router() -> None:
    """``--mode client --connect EP``: the NC listens nowhere and connects to the router."""
    cfg = load_config(None, mode="client", connect=["tcp/127.0.0.1:7450"])
    assert cfg.zenoh.mode == "client" and cfg.zenoh.listen == () and cfg.zenoh.connect == ("tcp/127.0.0.1:7450",)


@pytest.mark.parametrize("kwargs, msg", [
    ({"mode": "client", "listen": ["tcp/127.0.0.1:7451"], "connect": ["tcp/127.0.0.1:7450"]}, "listens nowhere"),
    ({"mode": "client"}, "at least one listen or connect"),
])
def test_client_mode_errors(kwargs: dict, msg: str) -> None:
    with pytest.raises(ConfigError, match=msg):
        load_config(None, **kwargs)


def test_router_cli_rejects_a_bad_endpoint(capsys: pytest.CaptureFixture[str]) -> None:
    from nc_server import router
    assert router.main(["--listen", "tcp/127.0.0.1"]) == 2
    assert "--listen[0]" in capsys.readouterr().err


def test_client_loss_reaction_per_axis_and_lease(tmp_path: Path) -> None:
    """ClientLossReaction per [[axis]] (default stop_disable), in axis order; --lease-ms overrides."""
    cfg = load_config(write(tmp_path, "[nc]\nname = 'nc1'\n[zenoh]\nlease = 300\n"
                                      "[[axis]]\nAxisId = 1\nClientLossReaction = 'keep_others'\n"
                                      "[[axis]]\nAxisId = 2\n[[axis]]\nAxisId = 3\nClientLossReaction = 'stop'\n"))
    assert cfg.loss_reactions == ("keep_others", "stop_disable", "stop")
    assert cfg.zenoh.lease_ms == 300
    assert load_config(lease_ms=200).zenoh.lease_ms == 200


def test_publisher_and_cpu_affinity(tmp_path: Path) -> None:
    d = load_config()
    assert d.publisher == "process" and d.cpu_affinity == ()
    import os
    cpu = min(os.sched_getaffinity(0))
    cfg = load_config(write(tmp_path, f"[nc]\npublisher = 'thread'\ncpu_affinity = [{cpu}, {cpu}]\n[[axis]]\nAxisId = 1\n"))
    assert cfg.publisher == "thread" and cfg.cpu_affinity == (cpu,)
    assert load_config(sets=[f"nc.cpu_affinity={cpu}", "nc.publisher=thread"]).cpu_affinity == (cpu,)


def test_a_start_failure_closes_the_drive(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The listen endpoint in use: nc-server exits 1 and releases its drive (a CANopen node left OPERATIONAL,
    a remote link's opener thread retrying otherwise); so does a failure building the core."""
    import signal
    import socket

    from nc_server.drives import SimDrive

    closed: list[str] = []

    class ClosingDrive(SimDrive):
        def close(self) -> None:
            closed.append("closed")
            super().close()

    _install_drive(monkeypatch, "closing", ClosingDrive)
    monkeypatch.setattr(signal, "signal", lambda *a: None)  # (not _run's handlers in the test process)
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        cfg = load_config(write(tmp_path, DEFAULT.replace('drive = "cia402-sim"', 'drive = "closing"')
                                .replace("tcp/127.0.0.1:7447", f"tcp/127.0.0.1:{port}")
                                .replace('realtime = "auto"', 'realtime = "off"')))
        assert cfg.zenoh.listen == (f"tcp/127.0.0.1:{port}",)
        assert cli._run(cfg) == 1
    assert closed == ["closed"]

    import nc_server.core

    def broken(*args: object, **kwargs: object) -> None:
        raise RuntimeError("a bug building the core")
    monkeypatch.setattr(nc_server.core, "NcCore", broken)
    with pytest.raises(RuntimeError):
        cli._run(load_config(write(tmp_path, DEFAULT.replace('drive = "cia402-sim"', 'drive = "closing"'))))
    assert closed == ["closed", "closed"]
