"""Each axis's drive backend from the NC's TOML (``Drive``, ``[drives.<backend>]``) and the group that serves
axes of several backends behind one DriveABC (nc_server/drives/group.py)."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from nc_server.core import AxisConfig, AxisParams, NcCore
from nc_server.core.params import ConfigError
from nc_server.drives import SimDrive
from nc_server.drives.base import DriveContext
from nc_server.drives.group import DriveGroup, build_drives
from nc_server.server import cli
from nc_server.server.config import apply_set, default_config_text, load_config, merge_overlay, parse_config

from znc_testing.nc_core import cmd, power, run_until

DEFAULT = default_config_text()


class _FakeEntryPoint:
    def __init__(self, name: str, cls: type) -> None:
        self.name, self._cls = name, cls

    def load(self) -> type:
        return self._cls


def _install(monkeypatch: pytest.MonkeyPatch, **classes: type) -> None:
    import nc_server.drives as drives

    real = drives.entry_points
    fakes = [_FakeEntryPoint(n.replace("_", "-"), c) for n, c in classes.items()]
    monkeypatch.setattr(drives, "entry_points",
                        lambda group: [*real(group=group), *fakes] if group == drives.GROUP else [])


class OptionDrive(SimDrive):
    """A backend with options: it records them and refuses a bad one as a real backend would."""

    seen: list[tuple[list[dict[str, Any]], dict[str, Any], str]] = []

    @classmethod
    def from_config(cls, params, cycle_time, axis_options, context):  # type: ignore[no-untyped-def,override]
        for k, o in enumerate(axis_options):
            if "node_id" not in o:
                raise ConfigError(f"axis[{k}].node_id", "missing (1..127)")
        if context.options.get("channel") == "bad":
            raise ConfigError("drives.option.channel", "no such channel")
        cls.seen.append(([dict(o) for o in axis_options], dict(context.options), context.nc_name))
        drive = cls(params, cycle_time)
        drive.simulated = False
        return drive


def _config(text: str, tmp_path: Path) -> Any:
    p = tmp_path / "nc.toml"
    p.write_text(text)
    return load_config(p)


def test_without_drive_tables_every_axis_uses_the_nc_default() -> None:
    cfg = load_config()
    assert cfg.axis_drives == tuple(("cia402-sim", {}) for _ in cfg.axes) and cfg.drive_options == {}


def test_an_axis_drive_by_name_or_table_and_backend_sections(tmp_path: Path,
                                                             monkeypatch: pytest.MonkeyPatch) -> None:
    _install(monkeypatch, option=OptionDrive)
    text = DEFAULT.replace('Name = "Y"', 'Name = "Y"\nDrive = { backend = "option", node_id = 3 }', 1)
    text = text.replace('Name = "X"', 'Name = "X"\nDrive = "sim"', 1)
    text += '\n[drives.option]\nchannel = "vcan"\n'
    cfg = _config(text, tmp_path)
    assert cfg.axis_drives[0] == ("sim", {}) and cfg.axis_drives[1] == ("option", {"node_id": 3})
    assert cfg.drive_options == {"option": {"channel": "vcan"}}


@pytest.mark.parametrize("edit, key, words", [
    (('Name = "Y"', 'Name = "Y"\nDrive = "ethercat"'), "axis[1].Drive.backend", ["'ethercat'", "sim"]),
    (('Name = "Y"', 'Name = "Y"\nDrive = 7'), "axis[1].Drive", ["backend name"]),
    (('[zenoh]', '[drives.ethercat]\nx = 1\n\n[zenoh]'), "drives.ethercat", ["unknown drive backend"]),
    (('[zenoh]', '[drives]\nsim = 3\n\n[zenoh]'), "drives.sim", ["must be a table"]),
])
def test_bad_drive_entries_name_their_key(tmp_path: Path, edit: tuple[str, str], key: str, words: list[str]) -> None:
    with pytest.raises(ConfigError) as ei:
        _config(DEFAULT.replace(*edit, 1), tmp_path)
    assert ei.value.key == key
    for w in words:
        assert w in str(ei.value)


def test_set_and_overlay_reach_drive_entries(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    _install(monkeypatch, option=OptionDrive)
    import tomllib

    data = tomllib.loads(DEFAULT)
    apply_set(data, "axis.2.Drive=option")
    apply_set(data, "drives.option.channel=can0")
    apply_set(data, "drives.option.bitrate=500000")
    merge_overlay(data, {"drives": {"option": {"channel": "can1"}}, "axis": {"2": {"Drive": {
        "backend": "option", "node_id": 4}}}}, "over.toml")
    cfg = parse_config(data)
    assert cfg.axis_drives[1] == ("option", {"node_id": 4})
    assert cfg.drive_options["option"] == {"channel": "can1", "bitrate": 500000}
    with pytest.raises(ConfigError, match="drives.<backend>.<key>"):
        apply_set(data, "drives.option=1")


def _params(n: int) -> list[AxisParams]:
    return [AxisParams() for _ in range(n)]


def test_one_backend_is_served_directly_and_several_by_a_group(monkeypatch: pytest.MonkeyPatch) -> None:
    _install(monkeypatch, option=OptionDrive)
    OptionDrive.seen.clear()
    one = build_drives(_params(3), 0.001, ["sim"] * 3, [{}] * 3, {})
    assert type(one) is SimDrive
    group = build_drives(_params(3), 0.001, ["option", "sim", "option"], [{"node_id": 1}, {}, {"node_id": 2}],
                         {"option": {"channel": "c"}}, nc_name="ncx")
    assert isinstance(group, DriveGroup)
    assert OptionDrive.seen == [([{"node_id": 1}, {"node_id": 2}], {"channel": "c"}, "ncx")]
    assert group.simulated_axes.tolist() == [False, True, False] and not group.simulated


def test_a_backends_error_names_the_ncs_axis_and_section(monkeypatch: pytest.MonkeyPatch) -> None:
    _install(monkeypatch, option=OptionDrive)
    with pytest.raises(ConfigError) as ei:  # the backend's axis[0] is the NC's axis[2]
        build_drives(_params(3), 0.001, ["sim", "sim", "option"], [{}, {}, {}], {})
    assert ei.value.key == "axis[2].node_id"
    with pytest.raises(ConfigError) as ei:
        build_drives(_params(1), 0.001, ["option"], [{"node_id": 1}], {"option": {"channel": "bad"}})
    assert ei.value.key == "drives.option.channel"
    with pytest.raises(ConfigError) as ei:  # a section no axis uses is a mistake worth naming
        build_drives(_params(1), 0.001, ["sim"], [{}], {"option": {"channel": "c"}})
    assert ei.value.key == "drives.option"
    with pytest.raises(ConfigError) as ei:  # a backend without options refuses them
        build_drives(_params(1), 0.001, ["sim"], [{"node_id": 1}], {})
    assert ei.value.key == "axis[0].Drive" and "node_id" in str(ei.value)


def test_the_server_refuses_bad_drive_options_before_zenoh_starts(tmp_path: Path,
                                                                  monkeypatch: pytest.MonkeyPatch,
                                                                  capsys: pytest.CaptureFixture[str]) -> None:
    _install(monkeypatch, option=OptionDrive)
    cfg = _config(DEFAULT.replace('Name = "Y"', 'Name = "Y"\nDrive = "option"', 1), tmp_path)
    assert cli._run(cfg) == 2
    err = capsys.readouterr().err
    assert "configuration error: axis[1].node_id" in err


def _core(drive: Any, n: int = 3) -> NcCore:
    return NcCore([AxisConfig(AxisId=i + 1) for i in range(n)], cycle_time=0.001, drive=drive)


def test_a_group_moves_its_axes_exactly_as_one_backend_would() -> None:
    """The same moves on three SimDrives in one piece and split 2 + 1 over a group: bit-identical actuals."""
    params = _params(3)
    whole = _core(SimDrive(params, 0.001))
    split = _core(DriveGroup(3, 0.001, [(SimDrive([params[0], params[2]], 0.001), np.array([0, 2])),
                                        (SimDrive([params[1]], 0.001), np.array([1]))]))
    for core in (whole, split):
        for i in range(3):
            power(core, i)
        core.step()
        for i, target in enumerate((50.0, -20.0, 7.5)):
            assert cmd(core, "MoveAbsolute", axis=i + 1, Position=target, Velocity=100.0)["error"] == 0
        run_until(core, lambda c=core: not c.moving.any(), max_cycles=20_000)
    assert np.array_equal(whole.act_pos, split.act_pos)
    assert np.allclose(split.act_pos, [50.0, -20.0, 7.5], atol=0.02)
    assert split.nctoplc["OpModeDWord"].tolist() == whole.nctoplc["OpModeDWord"].tolist()


def test_a_group_forwards_axis_methods_to_the_owner() -> None:
    a, b = SimDrive(_params(1), 0.001), SimDrive(_params(2), 0.001)
    group = DriveGroup(3, 0.001, [(a, np.array([1])), (b, np.array([0, 2]))])
    b.set_device_error(1, True)  # axis 2 of the NC
    group.step(np.ones(3, dtype=bool), np.zeros(3), np.zeros(3), np.zeros(3))
    assert group.device_error.tolist() == [False, False, True] and group.faulty
    assert group.ready.tolist() == [True, True, False]
    group.set_probe_signal(1, True, 0.0)  # goes to a's axis 0
    group.step(np.ones(3, dtype=bool), np.zeros(3), np.zeros(3), np.zeros(3))
    assert group.probe_input().tolist() == [False, True, False]
    with pytest.raises(IndexError):
        group.set_probe_signal(3, True, 0.0)
    with pytest.raises(NotImplementedError):
        group.set_stall(0, True)


def test_a_group_hands_out_new_arrays_each_step() -> None:
    """The NC's stats read ``error_code`` etc. from another thread: an array once handed out never changes."""
    a, b = SimDrive(_params(1), 0.001), SimDrive(_params(2), 0.001)
    group = DriveGroup(3, 0.001, [(a, np.array([1])), (b, np.array([0, 2]))])
    on = np.ones(3, dtype=bool)
    group.step(on, np.zeros(3), np.zeros(3), np.zeros(3))
    names = ("ready", "io_valid", "device_error", "following", "comm_error", "error_code")
    held = {k: getattr(group, k) for k in names}
    before = {k: v.copy() for k, v in held.items()}
    b.set_device_error(1, True)
    group.step(on, np.zeros(3), np.zeros(3), np.zeros(3))
    assert group.device_error.tolist() == [False, False, True]
    for k in names:
        assert np.array_equal(held[k], before[k]), f"{k} changed in place"


def test_default_from_config_builds_the_backend() -> None:
    d = SimDrive.from_config(_params(2), 0.002, [{}, {}], DriveContext())
    assert isinstance(d, SimDrive) and d.cycle_time == 0.002


def test_the_age_of_the_drive_inputs_reaches_the_stats() -> None:
    """Stale inputs (a fieldbus or a remote drive late) show in the stats' drive_input_age, fresh ones do not."""
    from types import SimpleNamespace

    from nc_server.drives.cia402.sim import Cia402SimDrive
    from nc_server.server.app import NcServer

    params = _params(3)
    group = DriveGroup(3, 0.001, [(Cia402SimDrive([params[0], params[2]], 0.001), np.array([0, 2])),
                                  (SimDrive([params[1]], 0.001), np.array([1]))])
    core = _core(group)
    core.step()
    assert NcServer._drive_input_age(SimpleNamespace(core=core)) == {}  # type: ignore[arg-type]
    group.parts[0][0].set_io_invalid(1, True)  # the group's axis 3: its inputs stop arriving
    held = group.input_age
    for _ in range(3):
        core.step()
    ages = NcServer._drive_input_age(SimpleNamespace(core=core))  # type: ignore[arg-type]
    assert list(ages) == [3] and ages[3] > 0
    assert held.tolist() == [0, 0, 0]  # an array handed out earlier never changes (another thread reads it)


def test_the_links_of_the_drives_reach_the_stats() -> None:
    """drive_link: {AxisId: figures} of the axes whose drive has a link, gathered through a DriveGroup to the right
    AxisIds; in-process drives have none; a backend whose figures fail costs the stats nothing else."""
    from types import SimpleNamespace

    from nc_server.server.app import NcServer

    class Linked(SimDrive):
        def link_figures(self) -> dict[int, dict[str, Any]]:
            return {1: {"link": "remote", "host": "h", "alive": True, "age": 0, "round_trip": 2}}

    params = _params(3)
    group = DriveGroup(3, 0.001, [(Linked([params[0], params[2]], 0.001), np.array([0, 2])),
                                  (SimDrive([params[1]], 0.001), np.array([1]))])
    core = _core(group)
    core.step()
    assert NcServer._drive_link(SimpleNamespace(core=core)) == {  # type: ignore[arg-type]
        3: {"link": "remote", "host": "h", "alive": True, "age": 0, "round_trip": 2}}
    assert NcServer._drive_link(SimpleNamespace(core=_core(SimDrive(params, 0.001)))) == {}  # type: ignore[arg-type]

    class Broken(SimDrive):
        def link_figures(self) -> dict[int, dict[str, Any]]:
            raise RuntimeError("bug")
    assert NcServer._drive_link(SimpleNamespace(core=_core(Broken(params, 0.001)))) == {}  # type: ignore[arg-type]
