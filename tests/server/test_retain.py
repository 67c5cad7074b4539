"""The retain file (nc_server/server/retain.py): format, refusals, atomic writes, load and apply."""
from __future__ import annotations

import hashlib
import logging
import os
import random
import struct
from pathlib import Path
from typing import Any

import msgpack
import pytest

from nc_schema import ControlDWord, MC_AxisPara, make_request, parse_request
from nc_server.core import AxisConfig, AxisParams, NcCore
from nc_server.core.params import ConfigError
from nc_server.server.config import load_config
from nc_server.server.retain import (
    FORMAT_VERSION, MAGIC, AxisRetain, RetainData, RetainError, RetainKeeper, encode_retain, parse_retain,
    write_atomic,
)

ALL_ENABLES = int(ControlDWord.Enable | ControlDWord.FeedEnablePlus | ControlDWord.FeedEnableMinus)


def cmd(core: NcCore, name: str, axis: int, **args: Any) -> dict[str, Any]:
    """A command as the NC's request handler would run it."""
    return core.execute(parse_request(make_request(name, 1, "test", **args)), axis)


def power(core: NcCore, i: int, ctrl: int = ALL_ENABLES) -> None:
    rec = core.default_plctonc()
    rec["ControlDWord"] = ctrl
    core.set_plctonc(i, rec)


def run_until(core: NcCore, pred: Any, max_cycles: int = 100_000) -> None:
    for _ in range(max_cycles):
        core.step()
        if pred():
            return
    raise AssertionError(f"condition not reached within {max_cycles} cycles")

DATA = RetainData("nc1", {
    1: AxisRetain(123.456, True, {"AxisVeloMax": 400.0, "AxisEnMaxSoftPosLimit": False}),
    2: AxisRetain(None, None, {"AxisAcc": 1234.5}),
    4: AxisRetain(-7.25, False, {}),
}, saved_ns=1_700_000_000_000_000_000)
AXES = [1, 2, 3, 4]


def with_body(body: bytes, version: int = FORMAT_VERSION, magic: bytes = MAGIC) -> bytes:
    """A file around ``body`` with a correct length and checksum."""
    return struct.pack("<8sHI32s", magic, version, len(body), hashlib.sha256(body).digest()) + body


def doc(**over: Any) -> dict[str, Any]:
    d: dict[str, Any] = {"nc": "nc1", "saved_ns": 1, "axes": {1: {"position": 1.0, "homed": True}}}
    d.update(over)
    return d


def refused(raw: bytes, nc: str = "nc1", axes: list[int] = AXES) -> RetainError:
    with pytest.raises(RetainError) as ei:
        parse_retain(raw, nc, axes)
    return ei.value


# ---- format -----------------------------------------------------------------------------------
def test_round_trip() -> None:
    raw = encode_retain(DATA)
    assert raw.startswith(MAGIC)
    back = parse_retain(raw, "nc1", AXES)
    assert back == DATA and back.saved_ns == DATA.saved_ns
    assert back.axes[1].params == {"AxisVeloMax": 400.0, "AxisEnMaxSoftPosLimit": False}
    assert isinstance(back.axes[1].params["AxisEnMaxSoftPosLimit"], bool)
    # deterministic: the same content gives the same bytes
    assert encode_retain(RetainData("nc1", dict(reversed(list(DATA.axes.items()))), DATA.saved_ns)) == raw
    # nothing kept is a valid file too (no persistent axis, no parameter written)
    assert parse_retain(encode_retain(RetainData("nc1", {})), "nc1", AXES) == RetainData("nc1", {})


def test_truncated_anywhere_is_corrupt() -> None:
    raw = encode_retain(DATA)
    for n in range(len(raw)):
        e = refused(raw[:n])
        assert e.kind == "corrupt", (n, e)
    assert "truncated" in str(refused(raw[:-1]))
    assert "truncated or padded" in str(refused(raw + b"\0"))


def test_every_flipped_byte_is_refused() -> None:
    raw = encode_retain(DATA)
    for i in range(len(raw)):
        bad = bytearray(raw)
        bad[i] ^= 0x01
        e = refused(bytes(bad))
        if i >= 46:  # the body
            assert e.kind == "corrupt" and "checksum" in str(e), (i, e)
        elif 8 <= i < 10:  # the version field
            assert e.kind == "version", (i, e)
        else:
            assert e.kind == "corrupt", (i, e)


def test_wrong_magic() -> None:
    e = refused(b"PK\x03\x04" + encode_retain(DATA)[4:])
    assert e.kind == "corrupt" and "not a zenoh-nc retain file" in str(e)
    assert refused(b"").kind == "corrupt"
    assert refused(with_body(msgpack.packb(doc()), magic=b"ZNCRTN\n\n")).kind == "corrupt"


def test_foreign_nc() -> None:
    raw = encode_retain(DATA)
    e = refused(raw, nc="nc2")
    assert e.kind == "foreign" and "'nc1'" in str(e) and "'nc2'" in str(e)
    e = refused(raw, axes=[7, 8])
    assert e.kind == "foreign" and "none of its axes" in str(e)
    # one matching axis is enough (the others are reported when applied)
    assert parse_retain(raw, "nc1", [4, 9]) == DATA


def test_future_version() -> None:
    body = msgpack.packb(doc())
    e = refused(with_body(body, version=FORMAT_VERSION + 1))
    assert e.kind == "version" and f"version {FORMAT_VERSION + 1}" in str(e)
    # the version is judged before anything that may differ in a future layout
    e = refused(MAGIC + struct.pack("<H", 7) + b"whatever follows")
    assert e.kind == "version"


def test_garbage_msgpack_with_a_valid_checksum() -> None:
    for body in (b"\xc1", b"\x92\x01", b"\xde\xff\xff", b"\x81\xa1a\x01\x02"):  # reserved, short, short, extra data
        e = refused(with_body(body))
        assert e.kind == "corrupt" and ("not msgpack" in str(e) or "structure" in str(e)), (body, e)


@pytest.mark.parametrize("d, what", [
    ([1, 2], "expected a map"),
    (doc(extra=1), "keys"),
    ({"nc": "nc1", "axes": {}}, "keys"),
    (doc(nc=""), "nc must be"),
    (doc(nc=3), "nc must be"),
    (doc(saved_ns=-1), "saved_ns"),
    (doc(saved_ns=True), "saved_ns"),
    (doc(axes=[]), "axes must be a map"),
    (doc(axes={0: {}}), "axis id"),
    (doc(axes={True: {}}), "axis id"),
    (doc(axes={"1": {}}), "axis id"),
    (doc(axes={70000: {}}), "axis id"),
    (doc(axes={1: []}), "axis 1"),
    (doc(axes={1: {"speed": 1.0}}), "axis 1"),
    (doc(axes={1: {"position": float("nan")}}), "position"),
    (doc(axes={1: {"position": 1e12}}), "position"),
    (doc(axes={1: {"position": "1"}}), "position"),
    (doc(axes={1: {"homed": 1}}), "homed"),
    (doc(axes={1: {"params": [1]}}), "params"),
    (doc(axes={1: {"params": {1: 1.0}}}), "parameter name"),
    (doc(axes={1: {"params": {"AxisAcc": float("inf")}}}), "AxisAcc"),
    (doc(axes={1: {"params": {"AxisAcc": None}}}), "AxisAcc"),
])
def test_wrong_structure(d: Any, what: str) -> None:
    e = refused(with_body(msgpack.packb(d, use_bin_type=True)))
    assert e.kind == "corrupt" and "structure" in str(e) and what in str(e), e


def test_hostile_bytes_only_ever_raise_retain_error() -> None:
    rnd = random.Random(8)
    raw = encode_retain(DATA)
    for _ in range(3000):
        kind = rnd.randrange(3)
        if kind == 0:
            data = bytes(rnd.randrange(256) for _ in range(rnd.randrange(80)))
        elif kind == 1:  # a random body with a valid header: exercises the msgpack and structure checks
            data = with_body(bytes(rnd.randrange(256) for _ in range(rnd.randrange(1, 60))))
        else:
            b = bytearray(raw)
            for _ in range(rnd.randrange(1, 4)):
                b[rnd.randrange(len(b))] = rnd.randrange(256)
            data = bytes(b)
        try:
            parse_retain(data, "nc1", AXES)
        except RetainError:
            pass
    # deep nesting and huge declared sizes
    for body in (b"\x91" * 100_000, b"\xdf\xff\xff\xff\xff", b"\xdb\xff\xff\xff\xff"):
        assert refused(with_body(body)).kind == "corrupt"


# ---- write_atomic -------------------------------------------------------------------------------
def test_write_atomic_replaces(tmp_path: Path) -> None:
    p = tmp_path / "nc1.retain"
    write_atomic(p, b"one")
    write_atomic(p, b"two")
    assert p.read_bytes() == b"two"
    assert sorted(x.name for x in tmp_path.iterdir()) == ["nc1.retain"]


@pytest.mark.parametrize("fail", ["replace", "fsync", "write"])
def test_crash_mid_write_leaves_the_old_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, fail: str) -> None:
    p = tmp_path / "nc1.retain"
    old = encode_retain(DATA)
    write_atomic(p, old)

    def boom(*_a: Any, **_k: Any) -> Any:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, fail, boom)
    with pytest.raises(OSError):
        write_atomic(p, encode_retain(RetainData("nc1", {1: AxisRetain(9.0, False)})))
    monkeypatch.undo()
    assert p.read_bytes() == old
    assert parse_retain(p.read_bytes(), "nc1", AXES) == DATA
    assert not (tmp_path / "nc1.retain.tmp").exists()


def test_a_stale_temporary_file_does_not_matter(tmp_path: Path) -> None:
    # a SIGKILL between writing the temporary file and the rename: the old file stays, the next write wins
    p = tmp_path / "nc1.retain"
    write_atomic(p, b"old")
    (tmp_path / "nc1.retain.tmp").write_bytes(b"half-writ")
    assert p.read_bytes() == b"old"
    write_atomic(p, b"new")
    assert p.read_bytes() == b"new" and not (tmp_path / "nc1.retain.tmp").exists()


# ---- keeper: snapshot, load, apply (an in-process core, no server) ---------------------------------
def make_core(persistent: tuple[int, ...] = (1,), **params: Any) -> NcCore:
    axes = [AxisConfig(i, f"A{i}", AxisParams(AxisEnDataPersistence=i in persistent, AxisEnMinSoftPosLimit=True,
                                             AxisMinSoftPosLimit=-10.0, AxisEnMaxSoftPosLimit=True,
                                             AxisMaxSoftPosLimit=1000.0, **params))
            for i in (1, 2, 3)]
    core = NcCore(axes, cycle_time=0.001)
    core.step()
    return core


def keep(tmp_path: Path, core: NcCore) -> RetainKeeper:
    return RetainKeeper(tmp_path / "nc1.retain", "nc1", core)


def test_data_persistence_is_a_twincat_parameter() -> None:
    core = make_core(persistent=())
    n = int(MC_AxisPara.AxisEnDataPersistence)
    assert n == 1037
    assert core.read_parameter(0, n) is False
    assert cmd(core, "WriteParameter", 1, ParameterNumber=n, Value=True)["error"] == 0
    assert core.read_parameter(0, n) is True and core.params[0].AxisEnDataPersistence


def test_snapshot_keeps_persistent_positions_homed_and_written_parameters(tmp_path: Path) -> None:
    core = make_core(persistent=(1, 3))
    k = keep(tmp_path, core)
    assert k.data_of(k._snapshot(core)) == RetainData("nc1", {1: AxisRetain(0.0, False), 3: AxisRetain(0.0, False)})
    assert cmd(core, "SetActualPosition", 1, Position=50.0)["error"] == 0
    assert cmd(core, "SetActualPosition", 2, Position=60.0)["error"] == 0  # not persistent: not kept
    assert cmd(core, "SetReferenceFlag", 1, ReferenceFlag=True)["error"] == 0
    assert cmd(core, "SetReferenceFlag", 2, ReferenceFlag=True)["error"] == 0
    assert cmd(core, "WriteParameter", 2, ParameterNumber=int(MC_AxisPara.AxisVeloMax), Value=300.0)["error"] == 0
    assert cmd(core, "WriteParameter", 3, ParameterNumber=int(MC_AxisPara.AxisAcc), Value=5000.0)["error"] == 0
    core.step()
    data = k.data_of(k._snapshot(core))
    assert data == RetainData("nc1", {1: AxisRetain(50.0, True), 2: AxisRetain(None, None, {"AxisVeloMax": 300.0}),
                                      3: AxisRetain(0.0, False)})  # AxisAcc 5000 is the configured value: not kept
    # written back to the configured value: not kept any more
    assert cmd(core, "WriteParameter", 2, ParameterNumber=int(MC_AxisPara.AxisVeloMax), Value=1000.0)["error"] == 0
    assert 2 not in k.data_of(k._snapshot(core)).axes


def test_load_applies_through_the_commands(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    core = make_core(persistent=(1,))
    data = RetainData("nc1", {
        1: AxisRetain(50.5, True, {"AxisVeloMax": 300.0}),
        # not persistent (AxisEnDataPersistence FALSE in the config): position and homed flag are not restored
        2: AxisRetain(70.0, True, {"AxisJerk": 12345.0}),
        # made persistent at run time: the parameter comes first, then position and homed flag
        3: AxisRetain(-5.0, True, {"AxisEnDataPersistence": True}),
        9: AxisRetain(1.0, True),  # not configured
    })
    write_atomic(tmp_path / "nc1.retain", encode_retain(data))
    k = keep(tmp_path, core)
    with caplog.at_level(logging.INFO, "nc_server.server"):
        assert k.load(core) == data
    core.step()
    pos = core.nctoplc["ActPos"]
    assert pos[0] == pytest.approx(50.5) and pos[1] == 0.0 and pos[2] == pytest.approx(-5.0)
    assert core.nctoplc["SetPos"][0] == pytest.approx(50.5)
    assert core.axes.homed.tolist() == [True, False, True]
    assert core.params[0].AxisVeloMax == 300.0 and core.params[1].AxisJerk == 12345.0
    assert core.params[2].AxisEnDataPersistence
    text = caplog.text
    assert "axis 9 is not configured" in text and "axis 2 is not persistent" in text and "loaded" in text
    # the applied parameters are not the base: the next snapshot keeps them
    again = k.data_of(k._snapshot(core))
    assert again.axes[1] == AxisRetain(pytest.approx(50.5), True, {"AxisVeloMax": 300.0})
    assert again.axes[3].params == {"AxisEnDataPersistence": True}


def test_parameters_the_config_rejects_are_skipped(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    core = make_core(persistent=())
    data = RetainData("nc1", {1: AxisRetain(None, None, {
        # order-dependent: written MinSoftPosLimit first at run time; applied in any order
        "AxisMaxSoftPosLimit": -100.0, "AxisMinSoftPosLimit": -200.0,
        "AxisVeloMax": -1.0,                  # rejected by the validation of WriteParameter
        "AxisMaxPosLagValue": True,           # wrong type
        "NoSuchParameter": 1.0,               # unknown
        "SimTimeConstant": 0.5,               # a stored parameter without an MC_AxisPara number
        "AxisAcc": 2000.0,
    })})
    write_atomic(tmp_path / "nc1.retain", encode_retain(data))
    with caplog.at_level(logging.WARNING, "nc_server.server"):
        assert keep(tmp_path, core).load(core) == data
    p = core.params[0]
    assert (p.AxisMinSoftPosLimit, p.AxisMaxSoftPosLimit, p.AxisAcc) == (-200.0, -100.0, 2000.0)
    assert p.AxisVeloMax == AxisParams().AxisVeloMax and p.AxisMaxPosLagValue == AxisParams().AxisMaxPosLagValue
    for name in ("AxisVeloMax", "AxisMaxPosLagValue", "NoSuchParameter", "SimTimeConstant"):
        assert f"parameter {name}" in caplog.text, name
    assert "0x070B" in caplog.text and "0x0703" in caplog.text


def test_a_refused_file_is_set_aside(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    path = tmp_path / "nc1.retain"
    for n, raw in enumerate((b"garbage", encode_retain(RetainData("nc2", {1: AxisRetain(1.0, True)})))):
        core = make_core()
        path.write_bytes(raw)
        caplog.clear()
        with caplog.at_level(logging.INFO, "nc_server.server"):
            assert keep(tmp_path, core).load(core) is None
        errors = [r for r in caplog.records if r.levelno >= logging.ERROR]
        assert len(errors) == 1 and "0x4002" in errors[0].getMessage() and "starts with its configuration" in \
            errors[0].getMessage(), caplog.text
        aside = tmp_path / ("nc1.retain.rejected" + ("" if n == 0 else ".1"))
        assert aside.read_bytes() == raw and not path.exists()
        assert core.nctoplc["ActPos"][0] == 0.0 and not core.axes.homed.any()
    assert (tmp_path / "nc1.retain.rejected").read_bytes() == b"garbage"  # never overwritten


def test_missing_file_is_the_first_start(tmp_path: Path) -> None:
    core = make_core()
    assert keep(tmp_path, core).load(core) is None


def test_the_thread_writes_changes_and_the_final_state(tmp_path: Path) -> None:
    core = make_core(persistent=(1,))
    k = keep(tmp_path, core)
    path = tmp_path / "nc1.retain"
    k.start()
    try:
        k.tick(core)
        wait_for(lambda: path.exists() and parse_retain(path.read_bytes(), "nc1", AXES).axes.get(1) == AxisRetain(0.0, False))
        n = k.writes
        for _ in range(300):  # nothing changes: no more writes
            core.step()
            k.tick(core)
        assert k.writes == n
        power(core, 0, ALL_ENABLES)
        core.step()
        assert cmd(core, "MoveAbsolute", 1, Position=20.0, Velocity=100.0)["error"] == 0
        run_until(core, lambda: core.nctoplc["ActPos"][0] > 5.0)
        k.tick(core)  # (the period is kept: tick() only hands one over every 100 cycles)
        k._due = 0
        k.tick(core)
        wait_for(lambda: parse_retain(path.read_bytes(), "nc1", AXES).axes[1].position > 5.0)
        run_until(core, lambda: not core.moving[0], 10_000)
    finally:
        k.stop(core)
    final = parse_retain(path.read_bytes(), "nc1", AXES)
    assert final.axes[1].position == pytest.approx(20.0, abs=0.02)


def test_write_failures_are_reported_once(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    core = make_core()
    k = RetainKeeper(tmp_path / "gone" / "nc1.retain", "nc1", core)  # (the config refuses this; here: a lost disk)
    with caplog.at_level(logging.ERROR, "nc_server.server"):
        k._write(k._snapshot(core))
        k._write(k._snapshot(core))
    assert k.write_errors == 2 and caplog.text.count("cannot write") == 1


def wait_for(pred: Any, timeout: float = 30.0) -> None:
    import time
    deadline = time.monotonic() + timeout
    while True:
        try:
            if pred():
                return
        except (OSError, RetainError, KeyError):
            pass
        assert time.monotonic() < deadline, "condition not reached"
        time.sleep(0.01)


# ---- configuration ----------------------------------------------------------------------------
def test_config_keys(tmp_path: Path) -> None:
    assert load_config().retain_file is None
    cfg = load_config(retain_file=str(tmp_path / "a.retain"))
    assert cfg.retain_file == str(tmp_path / "a.retain")
    conf = tmp_path / "nc.toml"
    conf.write_text(f'[nc]\nretain_file = "{tmp_path / "b.retain"}"\n[[axis]]\nAxisId = 1\nAxisEnDataPersistence = true\n')
    cfg = load_config(conf)
    assert cfg.retain_file == str(tmp_path / "b.retain") and cfg.axes[0].params.AxisEnDataPersistence
    for bad in (str(tmp_path / "nodir" / "x.retain"), str(tmp_path), ""):
        with pytest.raises(ConfigError) as ei:
            load_config(retain_file=bad)
        assert ei.value.key == "nc.retain_file"
    conf.write_text('[nc]\nretain_file = 1\n[[axis]]\nAxisId = 1\n')
    with pytest.raises(ConfigError) as ei:
        load_config(conf)
    assert ei.value.key == "nc.retain_file"
