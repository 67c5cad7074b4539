"""nc-server configuration overrides: --config-overlay (partial TOML merged over the base) and
--set KEY=VALUE, typed and checked like a config file, errors naming the argument, nothing started."""
from __future__ import annotations

from pathlib import Path

import pytest

from nc_schema import error_name
from nc_server.core.params import ConfigError
from nc_server.server import cli
from nc_server.server.config import load_config


def write(tmp_path: Path, text: str, name: str = "over.toml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def params(cfg, axis_id):  # type: ignore[no-untyped-def]
    return next(a for a in cfg.axes if a.AxisId == axis_id).params


def test_set_axis_parameter_by_axis_id() -> None:
    base = load_config()
    cfg = load_config(sets=["axis.2.AxisVeloMax=300", "axis.2.AxisEnMinSoftPosLimit=false", "axis.4.AxisAcc=1e3",
                            "axis.1.Name=Spindle", "axis.3.ClientLossReaction=stop"])
    assert params(cfg, 2).AxisVeloMax == 300.0 and params(cfg, 2).AxisEnMinSoftPosLimit is False
    assert params(cfg, 4).AxisAcc == 1000.0 and cfg.axes[0].Name == "Spindle" and cfg.loss_reactions[2] == "stop"
    # everything else as in the default
    assert params(cfg, 1) == params(base, 1) and params(cfg, 3) == params(base, 3)
    assert params(cfg, 2).AxisAcc == params(base, 2).AxisAcc and len(cfg.axes) == 4
    # repeated: the last wins; an alias replaces the other spelling
    assert params(load_config(sets=["axis.1.AxisVeloMax=100", "axis.1.AxisVeloMax=200"]), 1).AxisVeloMax == 200.0
    assert params(load_config(sets=["axis.1.AxisMaxVelocity=150"]), 1).AxisVeloMax == 150.0


def test_set_nc_and_zenoh_keys() -> None:
    cfg = load_config(sets=["nc.cycle_time=0.002", "nc.name=mill", "nc.realtime=off", "zenoh.lease=800",
                            'zenoh.listen=["tcp/127.0.0.1:17010"]', "nc.watchdog_timeout=1"])
    assert (cfg.cycle_time, cfg.name, cfg.realtime, cfg.zenoh.lease_ms) == (0.002, "mill", "off", 800)
    assert cfg.zenoh.listen == ("tcp/127.0.0.1:17010",) and cfg.watchdog_timeout == 1.0
    # the dedicated option is applied last
    assert load_config(sets=["nc.cycle_time=0.002"], cycle_time=0.004).cycle_time == 0.004


@pytest.mark.parametrize("item, key, text", [
    ("axis.1.AxisVeloMax=abc", "--set axis.1.AxisVeloMax", "must be a number, got 'abc'"),
    ("axis.1.AxisVeloMax=-3", "--set axis.1.AxisVeloMax", "must be > 0"),
    ("axis.1.AxisVeloMax=1e12", "--set axis.1.AxisVeloMax", "(MC_AxisPara"),
    ("axis.1.AxisVeloMax=inf", "--set axis.1.AxisVeloMax", "must be finite"),
    ("axis.1.AxisEnMinSoftPosLimit=yes", "--set axis.1.AxisEnMinSoftPosLimit", "must be true or false"),
    ("axis.1.AxisVeloMaxx=3", "--set axis.1.AxisVeloMaxx", "unknown axis parameter (did you mean AxisVeloMax?)"),
    ("axis.7.AxisVeloMax=3", "--set axis.7.AxisVeloMax", "no axis with AxisId 7 (configured: 1, 2, 3, 4)"),
    ("axis.x.AxisVeloMax=3", "--set axis.x.AxisVeloMax", "AxisId must be an integer"),
    ("axis.1.AxisId=9", "--set axis.1.AxisId", "cannot be changed"),
    ("axis.1.AxisMinSoftPosLimit=5000", "--set axis.1.AxisMinSoftPosLimit", "must be below AxisMaxSoftPosLimit"),
    ("axis.1.ClientLossReaction=explode", "--set axis.1.ClientLossReaction", "must be one of"),
    ("nc.cycle_time=fast", "--set nc.cycle_time", "must be a number"),
    ("nc.cycletime=1", "--set nc.cycletime", "unknown key"),
    ("nc.rt_priority=1.5", "--set nc.rt_priority", "must be an integer"),
    ("zenoh.listen=tcp/nowhere", "--set zenoh.listen[0]", "invalid endpoint"),
    ("zenoh.listen=3", "--set zenoh.listen", "must be a list of endpoints"),
    ('zenoh.listen=["tcp/nowhere"]', "--set zenoh.listen[0]", "invalid endpoint"),
    ("axis.1.AxisVeloMax", "--set axis.1.AxisVeloMax", "expected KEY=VALUE"),
    ("axis.1=3", "--set axis.1", "expected axis.<AxisId>.<Parameter>=VALUE"),
    ("bogus.x=1", "--set bogus.x", "unknown section"),
])
def test_bad_set_names_the_argument(item: str, key: str, text: str) -> None:
    with pytest.raises(ConfigError) as ei:
        load_config(sets=[item])
    assert ei.value.key == key and text in str(ei.value), str(ei.value)


def test_a_bad_dedicated_option_is_not_blamed_on_a_set() -> None:
    with pytest.raises(ConfigError) as ei:
        load_config(sets=["nc.cycle_time=0.002"], cycle_time=5.0)
    assert ei.value.key == "nc.cycle_time"


def test_overlay_merges_over_the_default(tmp_path: Path) -> None:
    # (one file uses one of the two axis forms: TOML cannot mix [axis.2] and [[axis]])
    ov1 = write(tmp_path, "[nc]\ncycle_time = 0.002\n\n[axis.2]\nAxisVeloMax = 300.0\n", "over1.toml")
    ov = write(tmp_path, """
[[axis]]
AxisId = 3
AxisAcc = 1000.0

[[axis]]
AxisId = 9
Name = "Spindle"
Modulo = true
""")
    base = load_config()
    cfg = load_config(overlays=[ov1, ov])
    assert cfg.cycle_time == 0.002 and cfg.name == "nc1" and cfg.zenoh.listen == base.zenoh.listen
    assert params(cfg, 2).AxisVeloMax == 300.0 and params(cfg, 2).AxisAcc == params(base, 2).AxisAcc
    assert params(cfg, 3).AxisAcc == 1000.0 and params(cfg, 3).AxisVeloMax == params(base, 3).AxisVeloMax
    assert [(a.AxisId, a.Name) for a in cfg.axes] == [(1, "X"), (2, "Y"), (3, "Z"), (4, "C"), (9, "Spindle")]
    assert params(cfg, 9).Modulo
    # over --config too, then --set over the overlay
    p = write(tmp_path, '[[axis]]\nAxisId = 2\nName = "B"\nAxisVeloMax = 900.0\n', "base.toml")
    cfg = load_config(p, overlays=[ov1, ov], sets=["axis.2.AxisVeloMax=250"])
    assert [a.AxisId for a in cfg.axes] == [2, 3, 9] and params(cfg, 2).AxisVeloMax == 250.0
    assert cfg.axes[0].Name == "B"
    # overlays apply in order
    ov2 = write(tmp_path, "[axis.2]\nAxisVeloMax = 200.0\n", "over2.toml")
    assert params(load_config(overlays=[ov1, ov2]), 2).AxisVeloMax == 200.0
    assert params(load_config(overlays=[ov2, ov1]), 2).AxisVeloMax == 300.0


@pytest.mark.parametrize("text, key, message", [
    ("[axis.2]\nAxisVeloMax = 'fast'\n", "over.toml: axis.2.AxisVeloMax", "must be a number"),
    ("[axis.7]\nAxisVeloMax = 3.0\n", "over.toml: axis.7", "no axis with AxisId 7"),
    ("[[axis]]\nName = 'x'\n", "over.toml: axis[0].AxisId", "missing"),
    ("[[axis]]\nAxisId = 2\nAxisAcc = -1.0\n", "over.toml: axis[0].AxisAcc", "must be > 0"),
    ("[[axis]]\nAxisId = 8\nFoo = 1.0\n", "over.toml: axis[0].Foo", "unknown axis parameter"),
    ("[nc]\ncylce_time = 0.001\n", "over.toml: nc.cylce_time", "unknown key"),
    ("[bogus]\nx = 1\n", "over.toml: bogus", "unknown top-level key"),
    ("[nc\n", "--config-overlay", "TOML syntax error"),
])
def test_bad_overlay_names_the_file(tmp_path: Path, text: str, key: str, message: str) -> None:
    ov = write(tmp_path, text)
    with pytest.raises(ConfigError) as ei:
        load_config(overlays=[ov])
    got = ei.value.key.replace(str(ov), "over.toml")
    assert got == key and message in str(ei.value), str(ei.value)


def test_missing_overlay(tmp_path: Path) -> None:
    with pytest.raises(ConfigError) as ei:
        load_config(overlays=[tmp_path / "nope.toml"])
    assert ei.value.key == "--config-overlay" and "cannot read" in str(ei.value)


def test_cli_bad_set_exits_2_before_starting(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["--set", "axis.1.AxisVeloMax=abc", "--listen", "tcp/127.0.0.1:1"]) == 2
    err = capsys.readouterr().err
    assert err.strip() == ("nc-server: configuration error: --set axis.1.AxisVeloMax: must be a number, got 'abc' "
                           "[0x070B ADSERR_DEVICE_INVALIDPARM]")
    assert cli.main(["--set", "axis.5.AxisAcc=3"]) == 2
    assert "no axis with AxisId 5" in capsys.readouterr().err


def test_set_listen_takes_plain_endpoints() -> None:
    """``--set zenoh.listen=tcp/...`` needs no shell-quoted TOML list; commas separate several."""
    assert load_config(sets=["zenoh.listen=tcp/127.0.0.1:17011"]).zenoh.listen == ("tcp/127.0.0.1:17011",)
    cfg = load_config(sets=["zenoh.listen=tcp/127.0.0.1:17011, tcp/127.0.0.1:17012", "zenoh.connect=tcp/127.0.0.1:17013"])
    assert cfg.zenoh.listen == ("tcp/127.0.0.1:17011", "tcp/127.0.0.1:17012")
    assert cfg.zenoh.connect == ("tcp/127.0.0.1:17013",)


@pytest.mark.parametrize("sets, overlay, code", [
    (["axis.1.AxisVeloMax=1e12"], None, 0x070B),          # out of range: what MC_WriteParameter answers
    (["axis.1.AxisVeloMax=fast"], None, 0x070B),          # wrong type
    (["axis.1.Modulo=3"], None, 0x070B),
    (["axis.1.AxisMinSoftPosLimit=5000"], None, 0x070B),  # above the enabled max limit
    (["axis.1.AxisVeloMaxx=3"], None, 0x0703),            # unknown parameter, as an undefined MC_AxisPara number
    (["axis.7.AxisAcc=3"], None, 0x4012),                 # an axis the NC does not have
    (["axis.x.AxisAcc=3"], None, 0x4012),
    ([], "[axis.7]\nAxisAcc = 3.0\n", 0x4012),
    ([], "[[axis]]\nAxisId = 70000\n", 0x4012),
    ([], "[axis.2]\nAxisAcc = -3.0\n", 0x070B),
    ([], "[[axis]]\nAxisId = 2\nFoo = 1\n", 0x0703),
    (["nc.cycle_time=fast"], None, None),                 # not an axis entry: TwinCAT has no code for it
    (["axis.1.ClientLossReaction=x"], None, None),
])
def test_axis_errors_carry_the_twincat_code(tmp_path: Path, sets: list[str], overlay: str | None,
                                            code: int | None) -> None:
    ovs = [write(tmp_path, overlay)] if overlay else []
    with pytest.raises(ConfigError) as ei:
        load_config(overlays=ovs, sets=sets)
    e = ei.value
    assert e.code == code, str(e)
    if code is None:
        assert "[0x" not in str(e)
    else:
        assert str(e).endswith(f"{e.message} [0x{code:04X} {error_name(code)}]"), str(e)


def test_the_same_value_in_a_config_file_has_the_same_code(tmp_path: Path) -> None:
    p = write(tmp_path, "[[axis]]\nAxisId = 1\nAxisVeloMax = 1e12\n", "base.toml")
    with pytest.raises(ConfigError) as ei:
        load_config(p)
    assert ei.value.code == 0x070B and ei.value.key == "axis[0].AxisVeloMax"
    assert "(MC_AxisPara 1003)" in str(ei.value)  # the entry of the parameter's own name, not PLCopen's 8


def test_write_parameter_detail_has_no_doubled_code() -> None:
    from nc_schema import NcError
    from nc_server.core import NcCore
    from nc_server.core.params import AxisConfig
    core = NcCore([AxisConfig(AxisId=1)], cycle_time=0.001)
    with pytest.raises(NcError) as ei:
        core.write_parameter(0, 1003, 1e12)
    assert ei.value.code == 0x070B and "AxisVeloMax" in ei.value.detail and "0x070B" not in ei.value.detail


def test_overlay_axis_table_cannot_renumber_its_axis(tmp_path: Path) -> None:
    """[axis.1] AxisId = 5 is refused as --set axis.1.AxisId is (it silently renumbered axis 1 before)."""
    with pytest.raises(ConfigError) as ei:
        load_config(overlays=[write(tmp_path, "[axis.1]\nAxisId = 5\n")])
    assert ei.value.key.endswith(": axis.1.AxisId") and "cannot be changed" in str(ei.value)
    cfg = load_config(overlays=[write(tmp_path, "[axis.1]\nAxisId = 1\nAxisAcc = 300.0\n", "same.toml")])
    assert [a.AxisId for a in cfg.axes] == [1, 2, 3, 4] and cfg.axes[0].params.AxisAcc == 300.0
