"""The retain file (nc_server/server/retain.py): format, refusals, bounded parsing, atomic writes, the
lock, load and apply (after the first drive read), standstill flags, the write rate, the retain thread."""
from __future__ import annotations

import errno
import hashlib
import logging
import os
import random
import stat
import struct
import threading
import time
import tracemalloc
from pathlib import Path
from typing import Any

import msgpack
import pytest

from nc_schema import ControlDWord, MC_AxisPara, decode_frame, make_request, parse_request
from nc_server.core import AxisConfig, AxisParams, NcCore
from nc_server.core.params import ConfigError
from nc_server.drives.sim import SimDrive
from nc_server.server import retain as R
from nc_server.server.config import load_config
from nc_server.server.retain import (
    BODY_PER_AXIS, FORMAT_VERSION, MAGIC, MAX_STR, AxisRetain, RetainData, RetainError, RetainKeeper,
    RetainLockError, encode_retain, max_body, parse_retain, write_atomic,
)
from znc_testing import wait_until
from znc_testing.nc_core import run_until

ALL_ENABLES = int(ControlDWord.Enable | ControlDWord.FeedEnablePlus | ControlDWord.FeedEnableMinus)
VELO_MAX = int(MC_AxisPara.AxisVeloMax)
#: deadline of a wait for the retain thread [s] (generous; no timing is asserted)
T = 60.0


def cmd(core: NcCore, name: str, axis: int, **args: Any) -> dict[str, Any]:
    """A command as the NC's request handler would run it."""
    return core.execute(parse_request(make_request(name, 1, "test", **args)), axis)


def ok(reply: dict[str, Any]) -> dict[str, Any]:
    assert reply["error"] == 0, reply
    return reply


def power(core: NcCore, i: int, ctrl: int = ALL_ENABLES) -> None:
    rec = core.default_plctonc()
    rec["ControlDWord"] = ctrl
    core.set_plctonc(i, rec)


DATA = RetainData("nc1", {
    1: AxisRetain("A1", 123.456, True, True, 0.0,
                  {"AxisVeloMax": (400.0, 1000.0), "AxisEnMaxSoftPosLimit": (False, True)}),
    2: AxisRetain("A2", params={"AxisAcc": (1234.5, 5000.0)}),
    4: AxisRetain("A4", -7.25, False, False, 360.0),
}, saved_ns=1_700_000_000_000_000_000)
AXES = [1, 2, 3, 4]


def with_body(body: bytes, version: int = FORMAT_VERSION, magic: bytes = MAGIC) -> bytes:
    """A file around ``body`` with a correct length and checksum."""
    return struct.pack("<8sHI32s", magic, version, len(body), hashlib.sha256(body).digest()) + body


def axis_doc(**over: Any) -> dict[str, Any]:
    d: dict[str, Any] = {"name": "A1", "position": 1.0, "homed": True, "standstill": True, "modulo": 0.0}
    d.update(over)
    return d


def doc(**over: Any) -> dict[str, Any]:
    d: dict[str, Any] = {"nc": "nc1", "saved_ns": 1, "axes": {1: axis_doc()}}
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
    assert back.axes[1].params == {"AxisVeloMax": (400.0, 1000.0), "AxisEnMaxSoftPosLimit": (False, True)}
    assert isinstance(back.axes[1].params["AxisEnMaxSoftPosLimit"][0], bool)
    assert back.axes[4].modulo == 360.0 and back.axes[4].standstill is False
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
    # a hostile NC name is cut in the message
    e = refused(with_body(msgpack.packb(doc(nc="x" * 200))))
    assert e.kind == "foreign" and len(str(e)) < 120


def test_other_versions() -> None:
    body = msgpack.packb(doc())
    e = refused(with_body(body, version=FORMAT_VERSION + 1))
    assert e.kind == "version" and f"version {FORMAT_VERSION + 1}" in str(e)
    # the version is judged before anything that may differ in a future layout
    e = refused(MAGIC + struct.pack("<H", 7) + b"whatever follows")
    assert e.kind == "version"
    # version 1 (no names, standstill flags, configured values) is not read: refused, set aside
    v1 = msgpack.packb({"nc": "nc1", "saved_ns": 1, "axes": {1: {"position": 1.0, "homed": True}}})
    assert refused(with_body(v1, version=1)).kind == "version"


def test_garbage_msgpack_with_a_valid_checksum() -> None:
    for body in (b"\xc1", b"\x92\x01", b"\xde\xff\xff", b"\x81\xa1a\x01\x02"):  # reserved, short, short, extra data
        e = refused(with_body(body))
        assert e.kind == "corrupt" and ("not msgpack" in str(e) or "structure" in str(e)), (body, e)


@pytest.mark.parametrize("d, what", [
    (doc(extra=1), "keys"),
    ({"nc": "nc1", "axes": {}}, "keys"),
    (doc(nc=""), "nc must be"),
    (doc(nc=3), "nc must be"),
    (doc(saved_ns=-1), "saved_ns"),
    (doc(saved_ns=True), "saved_ns"),
    (doc(axes=1), "axes must be a map"),
    (doc(axes={0: axis_doc()}), "axis id"),
    (doc(axes={True: axis_doc()}), "axis id"),
    (doc(axes={"1": axis_doc()}), "axis id"),
    (doc(axes={70000: axis_doc()}), "axis id"),
    (doc(axes={1: 1}), "axis 1"),
    (doc(axes={1: axis_doc(speed=1.0)}), "axis 1"),
    (doc(axes={1: {"position": 1.0, "homed": True, "standstill": True, "modulo": 0.0}}), "name"),
    (doc(axes={1: axis_doc(name=1)}), "name"),
    (doc(axes={1: {"name": "A1", "position": 1.0, "homed": True}}), "come together"),
    (doc(axes={1: axis_doc(position="1")}), "position"),
    (doc(axes={1: axis_doc(position=None)}), "position"),
    (doc(axes={1: axis_doc(homed=1)}), "homed"),
    (doc(axes={1: axis_doc(standstill=None)}), "standstill"),
    (doc(axes={1: axis_doc(modulo=True)}), "modulo"),
    (doc(axes={1: axis_doc(params=1)}), "params"),
    (doc(axes={1: axis_doc(params={1: {"value": 1.0, "configured": 1.0}})}), "parameter name"),
    (doc(axes={1: axis_doc(params={"AxisAcc": 1.0})}), "value and configured"),
    (doc(axes={1: axis_doc(params={"AxisAcc": {"value": 1.0}})}), "value and configured"),
    (doc(axes={1: axis_doc(params={"AxisAcc": {"value": None, "configured": 1.0}})}), "AxisAcc"),
    (doc(axes={1: axis_doc(params={f"P{i}": {"value": 1.0, "configured": 2.0} for i in range(200)})}),
     "parameters, an axis has"),
])
def test_wrong_structure(d: Any, what: str) -> None:
    e = refused(with_body(msgpack.packb(d, use_bin_type=True)))
    assert e.kind == "corrupt" and "structure" in str(e) and what in str(e), e


@pytest.mark.parametrize("d", [
    [1, 2],                                                  # an array: the format has none
    doc(axes={1: axis_doc(params=[1])}),
    doc(nc=b"nc1"),                                          # bin
    doc(axes={1: axis_doc(name="x" * (MAX_STR + 1))}),       # a string above MAX_STR bytes
])
def test_msgpack_limits(d: Any) -> None:
    e = refused(with_body(msgpack.packb(d, use_bin_type=True)))
    assert e.kind == "corrupt" and "not msgpack of this format" in str(e), e


def test_values_out_of_range_are_a_per_axis_matter() -> None:
    # the parser takes any number; apply() judges it for that axis alone (see test_out_of_range_...)
    for pos in (float("nan"), float("inf"), 1e12, -1e9):
        d = parse_retain(with_body(msgpack.packb(doc(axes={1: axis_doc(position=pos)}))), "nc1", AXES)
        assert d.axes[1].position == pos or (pos != pos and d.axes[1].position != d.axes[1].position)


def test_unknown_parameter_names_are_dropped() -> None:
    long = "Axis" + "X" * 200
    d = parse_retain(with_body(msgpack.packb(doc(axes={1: axis_doc(params={
        "AxisAcc": {"value": 2000.0, "configured": 5000.0}, "NoSuchParameter": {"value": 1.0, "configured": 2.0},
        long: {"value": True, "configured": False}})}))), "nc1", AXES)
    assert d.axes[1].params == {"AxisAcc": (2000.0, 5000.0)}
    assert d.axes[1].unknown == ("NoSuchParameter", long)


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
    for body in (b"\x91" * 50_000, b"\x81\x01" * 40_000, b"\xdf\xff\xff\xff\xff", b"\xdb\xff\xff\xff\xff"):
        assert refused(with_body(body)).kind == "corrupt"


def _peak(fn: Any) -> int:
    """Peak Python memory [bytes] while ``fn()`` runs."""
    tracemalloc.start()
    try:
        tracemalloc.reset_peak()
        base = tracemalloc.get_traced_memory()[0]
        fn()
        return tracemalloc.get_traced_memory()[1] - base
    finally:
        tracemalloc.stop()


def test_hostile_files_cost_bounded_memory(tmp_path: Path) -> None:
    limit = max_body(len(AXES))
    assert limit < 256 * 1024  # a few axes: a small bound
    # the review's bomb (1 MB of arrays of empty maps: ~80 MB decoded; 1.2 GB at the old 16 MB bound)
    per = (1 << 20) - 1
    review = b"\x81\xa1x\xdd" + struct.pack(">I", 1) + b"\xdd" + struct.pack(">I", per) + b"\x80" * per
    n = min(65535, (limit - 40) // 4)  # the same idea within the bound: a map of empty maps, 4 bytes each
    maps = (b"\x83\xa2nc\xa3nc1\xa8saved_ns\x01\xa4axes\xdf" + struct.pack(">I", n)
            + b"".join(b"\xcd" + struct.pack(">H", k) + b"\x80" for k in range(1, n + 1)))
    bombs = {"review": review, "arrays": b"\xdd" + struct.pack(">I", limit // 2) + b"\x80" * (limit // 2),
             "maps": maps, "nesting": b"\x81\x01" * (limit // 2 - 4), "strings": b"\x81\xd9\xff" + b"a" * 255}
    peaks = {}
    for name, body in bombs.items():
        raw = with_body(body)

        def parse() -> None:
            try:
                parse_retain(raw, "nc1", AXES)
            except RetainError:
                pass
        peaks[name] = _peak(parse)
    assert len(maps) <= limit and refused(with_body(maps)).kind == "corrupt"  # (axis 1..n: no names)
    print("peak memory [bytes]:", peaks)
    assert all(p < 32 * 1024 * 1024 for p in peaks.values()), peaks  # generous: measured ~4 MB for "maps"
    # a huge file on disk is read only up to the bound
    path = tmp_path / "nc1.retain"
    with open(path, "wb") as f:
        f.write(struct.pack("<8sHI32s", MAGIC, FORMAT_VERSION, 0xFFFFFFFF, b"\0" * 32))
        f.truncate(1 << 30)  # sparse: 1 GiB
    core = make_core()
    k = RetainKeeper(path, "nc1", core)
    assert _peak(lambda: k.load()) < 4 * 1024 * 1024
    assert k.status == "refused" and (tmp_path / "nc1.retain.rejected").exists()
    k.close()


def test_the_body_bound_fits_what_the_nc_writes(tmp_path: Path) -> None:
    # an axis with every writable parameter changed and a 64-character non-ASCII Name
    name = "Ä" * 64
    core = NcCore([AxisConfig(1, name, AxisParams(AxisEnDataPersistence=True))], 0.001)
    core.step()
    k = RetainKeeper(tmp_path / "r", "nc1", core)
    changed = {f: (not v if isinstance(v, bool) else v + 1.0) for f, v in vars(core.params[0]).items()}
    changed["AxisEncoderEncoderMask"] = 2147483647.0  # (2^k - 1 only: one bit less, as many digits)
    changed["AxisDelayTimeVeloPosition"] = 0.05  # (at most 0.1 s: its default 0 + 1 is not one)
    core.params[0] = AxisParams(**{**changed, "AxisEnDataPersistence": True,
                                   "AxisEnMinSoftPosLimit": False, "AxisEnMaxSoftPosLimit": False,
                                   "AxisOverrideType": 3.0})  # (1..4: its default 4 + 1 is not one)
    raw = encode_retain(k.data_of(k._snapshot(core)))
    assert len(raw) - 46 < BODY_PER_AXIS, len(raw)
    assert parse_retain(raw, "nc1", [1]).axes[1].name == name


# ---- write_atomic -------------------------------------------------------------------------------
def temporaries(d: Path) -> list[str]:
    return sorted(x.name for x in d.iterdir() if x.name.endswith(".tmp"))


def test_write_atomic_replaces(tmp_path: Path) -> None:
    p = tmp_path / "nc1.retain"
    assert write_atomic(p, b"one") is True
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
        write_atomic(p, encode_retain(RetainData("nc1", {1: AxisRetain("A1", 9.0, False, True, 0.0)})))
    monkeypatch.undo()
    assert p.read_bytes() == old
    assert parse_retain(p.read_bytes(), "nc1", AXES) == DATA
    assert temporaries(tmp_path) == []


def test_stale_temporary_files_are_removed_at_load(tmp_path: Path) -> None:
    # a SIGKILL between writing the temporary file and the rename: the old file stays; the next NC
    # (holding the lock: no other writer exists) removes what is left
    p = tmp_path / "nc1.retain"
    write_atomic(p, encode_retain(RetainData("nc1", {1: AxisRetain("A1", 5.0, False, True, 0.0)})))
    for n in ("nc1.retain.tmp", "nc1.retain.k3j9x_a1.tmp"):
        (tmp_path / n).write_bytes(b"half-writ")
    (tmp_path / "other.retain.abc.tmp").write_bytes(b"not ours")
    core = make_core()
    k = RetainKeeper(p, "nc1", core)
    assert k.load() is not None
    assert temporaries(tmp_path) == ["other.retain.abc.tmp"]
    k.close()


def test_two_writers_never_share_a_temporary_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # (the review's reproduction) writer A has written its temporary file, B writes and renames before A
    # renames: with one fixed <file>.tmp, A's rename failed (B had renamed A's file away)
    p = tmp_path / "nc1.retain"
    long = encode_retain(RetainData("nc1", {i: AxisRetain(f"A{i}", float(i), True, True, 0.0) for i in range(1, 40)}))
    short = encode_retain(RetainData("nc1", {1: AxisRetain("A1", 1.0, True, True, 0.0)}))
    a_written, b_done = threading.Event(), threading.Event()
    real_fsync = os.fsync

    def fsync(fd: int) -> None:
        if threading.current_thread().name == "A" and not b_done.is_set():
            a_written.set()
            b_done.wait(60)
        real_fsync(fd)

    monkeypatch.setattr(os, "fsync", fsync)
    errs: dict[str, BaseException] = {}

    def run(name: str, data: bytes) -> None:
        try:
            write_atomic(p, data)
        except BaseException as e:
            errs[name] = e
        finally:
            if name == "B":
                b_done.set()

    ta = threading.Thread(target=run, args=("A", long), name="A")
    ta.start()
    assert a_written.wait(60)
    tb = threading.Thread(target=run, args=("B", short), name="B")
    tb.start()
    tb.join(60)
    ta.join(60)
    assert errs == {}
    assert p.read_bytes() == long  # the last rename wins, whole
    assert temporaries(tmp_path) == []


def test_an_unsupported_directory_fsync_is_one_warning(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                       caplog: pytest.LogCaptureFixture) -> None:
    real_fsync = os.fsync
    err = [errno.EINVAL]

    def fsync(fd: int) -> None:
        if stat.S_ISDIR(os.fstat(fd).st_mode):
            raise OSError(err[0], os.strerror(err[0]))
        real_fsync(fd)

    monkeypatch.setattr(os, "fsync", fsync)
    p = tmp_path / "nc1.retain"
    assert write_atomic(p, b"x") is False and p.read_bytes() == b"x"
    core = make_core(persistent=(1,))
    k = keeper(tmp_path, core)
    with caplog.at_level(logging.WARNING, "nc_server.server"):
        for pos in (1.0, 2.0, 3.0):
            ok(cmd(core, "SetActualPosition", 1, Position=pos))
            core.step()
            k._write(k._snapshot(core))
    assert k.writes == 3 and k.write_errors == 0
    assert caplog.text.count("cannot fsync the directory") == 1
    assert parse_retain(p.read_bytes(), "nc1", AXES).axes[1].position == 3.0
    err[0] = errno.EIO  # any other failure is a failed write (the file is in place; retried on the next change)
    with pytest.raises(OSError):
        write_atomic(p, b"y")
    assert p.read_bytes() == b"y"
    k.close()


# ---- keeper: snapshot, load, apply (an in-process core, no server) ---------------------------------
def make_core(persistent: tuple[int, ...] = (1,), drive: type | None = None, **params: Any) -> NcCore:
    """Axes 1..3 (Names A1..A3, soft limits -10..1000), stepped once unless ``drive`` is given."""
    axes = [AxisConfig(i, f"A{i}", AxisParams(AxisEnDataPersistence=i in persistent, AxisEnMinSoftPosLimit=True,
                                             AxisMinSoftPosLimit=-10.0, AxisEnMaxSoftPosLimit=True,
                                             AxisMaxSoftPosLimit=1000.0, **params))
            for i in (1, 2, 3)]
    if drive is not None:
        return NcCore(axes, cycle_time=0.001, drive=drive([a.params for a in axes], 0.001))
    core = NcCore(axes, cycle_time=0.001)
    core.step()
    return core


def keeper(tmp_path: Path, core: NcCore, load: bool = True) -> RetainKeeper:
    """A keeper on tmp_path/nc1.retain, loaded and applied (the core has been stepped)."""
    k = RetainKeeper(tmp_path / "nc1.retain", "nc1", core)
    if load:
        k.load()
        k.apply(core)
    return k


def restart(tmp_path: Path, persistent: tuple[int, ...] = (1,), **params: Any) -> tuple[NcCore, RetainKeeper]:
    """A new NC on the same file: load, the first step, apply, one more step (NCTOPLC shows it)."""
    core = make_core(persistent, drive=SimDrive, **params)
    k = RetainKeeper(tmp_path / "nc1.retain", "nc1", core)
    k.load()
    core.step()
    k.apply(core)
    core.step()
    return core, k


def stored(tmp_path: Path) -> RetainData:
    return parse_retain((tmp_path / "nc1.retain").read_bytes(), "nc1", AXES)


def save(tmp_path: Path, data: RetainData) -> None:
    write_atomic(tmp_path / "nc1.retain", encode_retain(data))


def test_data_persistence_is_a_twincat_parameter() -> None:
    core = make_core(persistent=())
    n = int(MC_AxisPara.AxisEnDataPersistence)
    assert n == 1037
    assert core.read_parameter(0, n) is False
    assert cmd(core, "WriteParameter", 1, ParameterNumber=n, Value=True)["error"] == 0
    assert core.read_parameter(0, n) is True and core.params[0].AxisEnDataPersistence


def test_snapshot_keeps_persistent_positions_homed_and_written_parameters(tmp_path: Path) -> None:
    core = make_core(persistent=(1, 3))
    k = keeper(tmp_path, core)
    assert k.data_of(k._snapshot(core)) == RetainData("nc1", {1: AxisRetain("A1", 0.0, False, True, 0.0),
                                                             3: AxisRetain("A3", 0.0, False, True, 0.0)})
    ok(cmd(core, "SetActualPosition", 1, Position=50.0))
    ok(cmd(core, "SetActualPosition", 2, Position=60.0))  # not persistent: not kept
    ok(cmd(core, "SetReferenceFlag", 1, ReferenceFlag=True))
    ok(cmd(core, "SetReferenceFlag", 2, ReferenceFlag=True))
    ok(cmd(core, "WriteParameter", 2, ParameterNumber=VELO_MAX, Value=300.0))
    ok(cmd(core, "WriteParameter", 3, ParameterNumber=int(MC_AxisPara.AxisAcc), Value=5000.0))
    core.step()
    data = k.data_of(k._snapshot(core))
    assert data == RetainData("nc1", {1: AxisRetain("A1", 50.0, True, True, 0.0),
                                      2: AxisRetain("A2", params={"AxisVeloMax": (300.0, 1000.0)}),
                                      # AxisAcc 5000 is the configured value: not kept
                                      3: AxisRetain("A3", 0.0, False, True, 0.0)})
    # written back to the configured value: not kept any more
    ok(cmd(core, "WriteParameter", 2, ParameterNumber=VELO_MAX, Value=1000.0))
    assert 2 not in k.data_of(k._snapshot(core)).axes
    k.close()


def test_load_applies_through_the_commands(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    data = RetainData("nc1", {
        1: AxisRetain("A1", 50.5, True, True, 0.0, {"AxisVeloMax": (300.0, 1000.0)}),
        # not persistent (AxisEnDataPersistence FALSE in the config): position and homed flag are not restored
        2: AxisRetain("A2", 70.0, True, True, 0.0, {"AxisJerk": (12345.0, 50000.0)}),
        # made persistent at run time: the parameter comes first, then position and homed flag
        3: AxisRetain("A3", -5.0, True, True, 0.0, {"AxisEnDataPersistence": (True, False)}),
        9: AxisRetain("A9", 1.0, True, True, 0.0),  # not configured
    })
    save(tmp_path, data)
    with caplog.at_level(logging.INFO, "nc_server.server"):
        core, k = restart(tmp_path)
    assert k.loaded == data and k.status == "loaded"
    pos = core.nctoplc["ActPos"]
    assert pos[0] == pytest.approx(50.5) and pos[1] == 0.0 and pos[2] == pytest.approx(-5.0)
    assert core.nctoplc["SetPos"][0] == pytest.approx(50.5)
    assert core.axes.homed.tolist() == [True, False, True]
    assert core.params[0].AxisVeloMax == 300.0 and core.params[1].AxisJerk == 12345.0
    assert core.params[2].AxisEnDataPersistence
    text = caplog.text
    assert "not configured here, skipped: [9]" in text and "axis 2 'A2': not persistent" in text and "loaded" in text
    assert "axis 1 parameter AxisVeloMax = 300.0 (configured 1000.0)" in text
    assert "axis 2 parameter AxisJerk = 12345.0 (configured 50000.0)" in text
    assert "0x4002" not in text
    # the applied parameters are not the base: the next snapshot keeps them, with the configured values
    again = k.data_of(k._snapshot(core))
    assert again.axes[1] == AxisRetain("A1", pytest.approx(50.5), True, True, 0.0, {"AxisVeloMax": (300.0, 1000.0)})
    assert again.axes[3].params == {"AxisEnDataPersistence": (True, False)}
    k.close()


class EncoderAt5000(SimDrive):
    """A drive whose first read (the first step) reports 5000 u more than its initial act_pos."""

    simulated = False

    def __init__(self, params: Any, ct: float) -> None:
        super().__init__(params, ct)
        self._first = True

    def step(self, enabled: Any, set_pos: Any, set_velo: Any, set_acc: Any) -> None:
        if self._first:
            self._first = False
            self.act_pos = self.act_pos + 5000.0
            return
        super().step(enabled, set_pos, set_velo, set_acc)


def test_positions_are_applied_after_the_first_drive_read(tmp_path: Path) -> None:
    # (the review's reproduction: applied before the first step, the offset was computed against the
    # unread 0 and the axis came back at 5130)
    save(tmp_path, RetainData("nc1", {1: AxisRetain("A1", 130.0, True, True, 0.0)}))
    core = make_core(drive=EncoderAt5000)
    k = RetainKeeper(tmp_path / "nc1.retain", "nc1", core)
    k.load()
    with pytest.raises(RuntimeError, match="core.step"):
        k.apply(core)
    k.tick(core)  # nothing before apply: no snapshot could overwrite the file
    assert k.handed == 0
    core.step()
    k.apply(core)
    core.step()
    assert core.act_pos[0] == pytest.approx(130.0) and core.axes.homed[0]
    k.close()


def test_parameters_the_config_rejects_are_skipped(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    base = AxisParams()
    data = RetainData("nc1", {1: AxisRetain("A1", params={
        # order-dependent: written MinSoftPosLimit first at run time; applied in any order
        "AxisMaxSoftPosLimit": (-100.0, 1000.0), "AxisMinSoftPosLimit": (-200.0, -10.0),
        "AxisVeloMax": (-1.0, base.AxisVeloMax),                      # rejected by WriteParameter's validation
        "AxisMaxPosLagValue": (True, base.AxisMaxPosLagValue),        # wrong type
        "SimTimeConstant": (0.5, base.SimTimeConstant),               # a stored parameter without an MC_AxisPara number
        "AxisAcc": (2000.0, base.AxisAcc),
    })})
    body = msgpack.unpackb(encode_retain(data)[46:], strict_map_key=False)
    for name in ("NoSuchParameter", "Axis" + "Q" * 200):  # names this NC does not know (a newer NC's?)
        body["axes"][1]["params"][name] = {"value": 1.0, "configured": 2.0}
    (tmp_path / "nc1.retain").write_bytes(with_body(msgpack.packb(body)))
    with caplog.at_level(logging.WARNING, "nc_server.server"):
        core, k = restart(tmp_path, persistent=())
    p = core.params[0]
    assert (p.AxisMinSoftPosLimit, p.AxisMaxSoftPosLimit, p.AxisAcc) == (-200.0, -100.0, 2000.0)
    assert p.AxisVeloMax == base.AxisVeloMax and p.AxisMaxPosLagValue == base.AxisMaxPosLagValue
    for name in ("AxisVeloMax", "AxisMaxPosLagValue", "SimTimeConstant"):
        assert f"parameter {name}" in caplog.text, name
    assert "'NoSuchParameter'" in caplog.text and "0x070B" in caplog.text and "0x0703" in caplog.text
    assert "Q" * 40 not in caplog.text  # a hostile name is cut in the log
    k.close()


def test_a_changed_configuration_wins(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    # written at run time: AxisVeloMax 300 (configured 1000 then), AxisAcc 2000 (configured 5000)
    save(tmp_path, RetainData("nc1", {1: AxisRetain("A1", params={"AxisVeloMax": (300.0, 1000.0),
                                                                  "AxisAcc": (2000.0, 5000.0)})}))
    # since then the configuration's AxisVeloMax became 800: the configuration wins; AxisAcc is unchanged
    with caplog.at_level(logging.INFO, "nc_server.server"):
        core, k = restart(tmp_path, persistent=(), AxisVeloMax=800.0)
    assert core.params[0].AxisVeloMax == 800.0 and core.params[0].AxisAcc == 2000.0
    assert "parameter AxisVeloMax: the configuration changed it from 1000.0 to 800.0 since 300.0 was written at " \
           "run time: the configuration's 800.0 wins" in caplog.text
    assert "parameter AxisAcc = 2000.0 (configured 5000.0)" in caplog.text
    # and the next write keeps only what still differs from the configuration
    assert k.data_of(k._snapshot(core)).axes[1].params == {"AxisAcc": (2000.0, 5000.0)}
    k.close()


def test_a_refused_file_is_set_aside_and_unreferences_persistent_axes(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    path = tmp_path / "nc1.retain"
    for n, raw in enumerate((b"garbage", encode_retain(RetainData("nc2", {1: AxisRetain("A1", 1.0, True, True, 0.0)})))):
        path.write_bytes(raw)
        caplog.clear()
        with caplog.at_level(logging.INFO, "nc_server.server"):
            core, k = restart(tmp_path, persistent=(1,), Homed=True)  # configured Homed: an absolute encoder?
        assert k.loaded is None and k.status == "refused"
        errors = [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR]
        assert len(errors) == 1 and "0x4002" in errors[0] and "starts with its configuration" in errors[0], caplog.text
        aside = tmp_path / ("nc1.retain.rejected" + ("" if n == 0 else ".1"))
        assert aside.read_bytes() == raw and not path.exists()
        assert core.nctoplc["ActPos"][0] == 0.0
        # TwinCAT 0x4002: the persistent axis is not referenced; the others keep their configured Homed
        assert core.axes.homed.tolist() == [False, True, True]
        assert "axis 1 'A1': 0x4002 NC retain data error: the retain file was not usable: Homed FALSE" in caplog.text
        k.close()
    assert (tmp_path / "nc1.retain.rejected").read_bytes() == b"garbage"  # never overwritten


def test_an_unreadable_file_is_set_aside(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                         caplog: pytest.LogCaptureFixture) -> None:
    # (the review's reproduction: the first write replaced an unreadable file)
    path = tmp_path / "nc1.retain"
    good = encode_retain(RetainData("nc1", {1: AxisRetain("A1", 130.0, True, True, 0.0, {"AxisVeloMax": (321.0, 1000.0)})}))
    write_atomic(path, good)

    def unreadable(*_a: Any) -> bytes:
        raise OSError(errno.EIO, "Input/output error")

    monkeypatch.setattr(R, "_read_file", unreadable)
    with caplog.at_level(logging.ERROR, "nc_server.server"):
        core, k = restart(tmp_path)
    monkeypatch.undo()
    assert k.status == "unreadable" and "cannot read it (Input/output error)" in caplog.text
    assert (tmp_path / "nc1.retain.rejected").read_bytes() == good  # what may still be rescued is kept
    k._write(k._snapshot(core))  # the first write makes a fresh file
    assert stored(tmp_path).axes[1] == AxisRetain("A1", 0.0, False, True, 0.0)
    k.close()

    # it cannot even be renamed: the NC writes nothing during this run
    path.unlink()
    write_atomic(path, good)
    monkeypatch.setattr(R, "_read_file", unreadable)

    def no_rename(_p: Path) -> Path:
        raise OSError(errno.EROFS, "Read-only file system")

    monkeypatch.setattr(R, "_set_aside", no_rename)
    caplog.clear()
    with caplog.at_level(logging.ERROR, "nc_server.server"):
        core, k = restart(tmp_path)
    monkeypatch.undo()
    assert k.writing_disabled and "does NOT write the retain file during this run" in caplog.text
    k._write(k._snapshot(core))
    k.stop(core)
    assert path.read_bytes() == good and k.writes == 0


def test_a_fifo_does_not_block_the_load(tmp_path: Path) -> None:
    os.mkfifo(tmp_path / "nc1.retain")  # (the configuration refuses one; here it appeared later)
    core, k = restart(tmp_path)
    assert k.status == "unreadable" and stat.S_ISFIFO(os.lstat(tmp_path / "nc1.retain.rejected").st_mode)
    k.close()


def test_missing_file_is_the_first_start(tmp_path: Path) -> None:
    core, k = restart(tmp_path, Homed=True)
    assert k.status == "missing" and k.loaded is None
    assert core.axes.homed.tolist() == [True, True, True]  # the configured Homed (no file yet)
    k.close()


def test_a_snapshot_taken_while_moving_is_restored_unreferenced(tmp_path: Path,
                                                                 caplog: pytest.LogCaptureFixture) -> None:
    # (the review's reproduction: after a SIGKILL mid-move the axis came back referenced, 100 u off)
    core = make_core()
    k = keeper(tmp_path, core)
    power(core, 0)
    core.step()
    ok(cmd(core, "SetReferenceFlag", 1, ReferenceFlag=True))
    ok(cmd(core, "MoveAbsolute", 1, Position=500.0, Velocity=1000.0))
    run_until(core, lambda: core.act_pos[0] > 100.0)
    assert core.moving[0]
    k._write(k._snapshot(core))  # the last snapshot before the SIGKILL
    snap_pos = float(core.act_pos[0])
    assert stored(tmp_path).axes[1].standstill is False and stored(tmp_path).axes[1].homed is True
    for _ in range(100):  # motion the file never sees
        core.step()
    k.close()
    with caplog.at_level(logging.WARNING, "nc_server.server"):
        core2, k2 = restart(tmp_path)
    assert core2.act_pos[0] == pytest.approx(snap_pos) and not core2.axes.homed[0]
    assert "axis 1 'A1': 0x4002 NC retain data error: its position" in caplog.text and "while it moved" in caplog.text
    k2.close()
    # taken at standstill: referenced
    run_until(core, lambda: not core.moving[0] and R.standing(core)[0])
    k3 = RetainKeeper(tmp_path / "nc1.retain", "nc1", core)
    k3.load()
    k3.applied = True  # (the running NC of above)
    k3._write(k3._snapshot(core))
    k3.close()
    core4, k4 = restart(tmp_path)
    assert core4.act_pos[0] == pytest.approx(500.0, abs=0.02) and core4.axes.homed[0]
    k4.close()


def test_out_of_range_positions_are_a_per_axis_matter(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    # (the review's reproduction: the NC reached 1.8e9 and wrote a file it then refused entirely)
    core = make_core(persistent=(1, 2))
    k = keeper(tmp_path, core)
    ok(cmd(core, "SetActualPosition", 1, Position=9e8))
    ok(cmd(core, "SetActualPositionOnTheFly", 1, ActualPosition=9e8, PreviousPosition=0.0))
    ok(cmd(core, "SetReferenceFlag", 1, ReferenceFlag=True))
    ok(cmd(core, "WriteParameter", 1, ParameterNumber=VELO_MAX, Value=111.0))
    ok(cmd(core, "SetActualPosition", 2, Position=42.0))
    ok(cmd(core, "SetReferenceFlag", 2, ReferenceFlag=True))
    ok(cmd(core, "WriteParameter", 3, ParameterNumber=VELO_MAX, Value=321.0))
    core.step()
    with caplog.at_level(logging.WARNING, "nc_server.server"):
        k._write(k._snapshot(core))
        ok(cmd(core, "WriteParameter", 3, ParameterNumber=VELO_MAX, Value=322.0))
        k._write(k._snapshot(core))
    assert k.writes == 2 and k.write_errors == 0
    assert caplog.text.count("position 1800000000.0 is outside") == 1  # logged once
    d = stored(tmp_path)  # the reader takes it
    assert d.axes[1] == AxisRetain("A1", params={"AxisVeloMax": (111.0, 1000.0)})
    assert d.axes[2].position == 42.0 and d.axes[3].params == {"AxisVeloMax": (322.0, 1000.0)}
    k.close()
    caplog.clear()
    with caplog.at_level(logging.WARNING, "nc_server.server"):
        core2, k2 = restart(tmp_path, persistent=(1, 2), Homed=True)
    assert core2.axes.homed.tolist() == [False, True, True]  # axis 1 unreferenced, axis 2 restored, 3 configured
    assert core2.act_pos[1] == pytest.approx(42.0) and core2.params[0].AxisVeloMax == 111.0
    assert core2.params[2].AxisVeloMax == 322.0
    assert "axis 1 'A1': 0x4002" in caplog.text and "holds no position" in caplog.text
    k2.close()
    # a file with such a value (another writer, an older NC): that axis alone
    for bad in (1e12, float("nan"), float("-inf")):
        raw = with_body(msgpack.packb({"nc": "nc1", "saved_ns": 1, "axes": {
            1: axis_doc(position=bad), 2: axis_doc(name="A2", position=7.0)}}))
        (tmp_path / "nc1.retain").write_bytes(raw)
        caplog.clear()
        with caplog.at_level(logging.WARNING, "nc_server.server"):
            core3, k3 = restart(tmp_path, persistent=(1, 2))
        assert k3.status == "loaded" and core3.axes.homed.tolist() == [False, True, False]
        assert core3.act_pos[0] == 0.0 and core3.act_pos[1] == pytest.approx(7.0)
        assert "is not a number within +/-1e+09: skipped: Homed FALSE" in caplog.text
        k3.close()


def test_the_homed_flag_is_skipped_when_the_position_step_fails(tmp_path: Path,
                                                               caplog: pytest.LogCaptureFixture) -> None:
    save(tmp_path, RetainData("nc1", {1: AxisRetain("A1", 50.0, True, True, 0.0)}))
    core = make_core(drive=SimDrive)
    k = RetainKeeper(tmp_path / "nc1.retain", "nc1", core)
    k.load()
    power(core, 0)
    core.step()
    ok(cmd(core, "MoveVelocity", 1, Velocity=10.0))  # the axis moves: SetActualPosition is refused
    core.step()
    with caplog.at_level(logging.WARNING, "nc_server.server"):
        k.apply(core)
    assert not core.axes.homed[0] and core.act_pos[0] < 1.0
    assert "SetActualPosition 50.0 refused: 0x4B01" in caplog.text and "Homed FALSE" in caplog.text
    k.close()


def test_an_axis_with_another_name_or_modulo_setting_is_skipped(tmp_path: Path,
                                                                caplog: pytest.LogCaptureFixture) -> None:
    save(tmp_path, RetainData("nc1", {
        1: AxisRetain("Spindle", 50.0, True, True, 0.0, {"AxisVeloMax": (300.0, 1000.0)}),  # axis 1 is A1 now
        2: AxisRetain("A2", 60.0, True, True, 360.0),  # a modulo axis then, linear now
        3: AxisRetain("A3", 70.0, True, True, 0.0, {"AxisAcc": (2000.0, 5000.0)}),
    }))
    with caplog.at_level(logging.WARNING, "nc_server.server"):
        core, k = restart(tmp_path, persistent=(1, 2, 3))
    assert core.axes.homed.tolist() == [False, False, True]
    assert core.act_pos.tolist()[:2] == [0.0, 0.0] and core.act_pos[2] == pytest.approx(70.0)
    assert core.params[0].AxisVeloMax == 1000.0 and core.params[2].AxisAcc == 2000.0
    assert "axis 1 'A1': the file's entry is of axis 'Spindle': skipped" in caplog.text
    assert "axis 2 'A2': 0x4002 NC retain data error: the modulo setting changed (file 360, now 0)" in caplog.text
    k.close()


def test_a_second_keeper_on_the_same_file_is_refused(tmp_path: Path) -> None:
    core = make_core()
    k1 = keeper(tmp_path, core)
    k2 = RetainKeeper(tmp_path / "nc1.retain", "nc1", core)
    with pytest.raises(RetainLockError) as ei:
        k2.load()
    assert "in use by another process" in str(ei.value) and f"pid {os.getpid()}" in str(ei.value)
    assert "nc1.retain.lock" in str(ei.value)
    k1.stop(core)  # releases the lock
    assert k2.load() is not None
    k2.close()


# ---- the retain thread ----------------------------------------------------------------------------
def step_and_tick(core: NcCore, k: RetainKeeper, n: int) -> None:
    for _ in range(n):
        core.step()
        k.tick(core)


def caught_up(k: RetainKeeper) -> bool:
    """The retain thread has handled the newest snapshot handed over."""
    return k.processed == k.handed


def test_the_thread_writes_changes_once_and_the_final_state(tmp_path: Path) -> None:
    core = make_core(persistent=(1,))
    k = keeper(tmp_path, core)
    k.start()
    try:
        k.tick(core)
        wait_until(lambda: caught_up(k) and stored(tmp_path).axes[1] == AxisRetain("A1", 0.0, False, True, 0.0), T)
        n, handed = k.writes, k.handed
        step_and_tick(core, k, 300)  # nothing changes: no more writes
        wait_until(lambda: caught_up(k), T, "the retain thread to handle the last snapshot")
        assert k.handed >= handed + 2 and k.writes == n
        power(core, 0)
        core.step()
        ok(cmd(core, "MoveAbsolute", 1, Position=20.0, Velocity=100.0))
        step_and_tick(core, k, 30)  # the axis started moving: a snapshot at once, written at once (standstill FALSE)
        wait_until(lambda: caught_up(k), T, "the retain thread to handle the last snapshot")
        d = stored(tmp_path).axes[1]
        assert d.standstill is False and 0.0 <= d.position < 20.0
        run_until(core, lambda: not core.moving[0], 10_000)
        step_and_tick(core, k, 50)  # the axis stands: written at once
        wait_until(lambda: caught_up(k) and stored(tmp_path).axes[1].standstill is True, T)
        assert stored(tmp_path).axes[1].position == pytest.approx(20.0, abs=0.02)
        n = k.writes
        step_and_tick(core, k, 300)
        wait_until(lambda: caught_up(k), T)
        assert k.writes == n
    finally:
        k.stop(core)
    final = stored(tmp_path)
    assert final.axes[1].position == pytest.approx(20.0, abs=0.02) and final.axes[1].standstill


def test_the_standstill_check_can_fail(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # (the review's point: the old assertion passed while every snapshot was written) a deliberately
    # broken data_of makes every snapshot differ; waiting on the processed counter sees the writes
    core = make_core()
    k = keeper(tmp_path, core)
    real = R.write_atomic

    def slow(p: Any, d: bytes) -> bool:
        time.sleep(0.05)
        return real(p, d)

    monkeypatch.setattr(R, "write_atomic", slow)
    monkeypatch.setattr(RetainKeeper, "data_of",
                        lambda self, s: RetainData("nc1", {1: AxisRetain("A1", float(s.seq), False, True, 0.0)}))
    k.start()
    try:
        k.tick(core)
        wait_until(lambda: caught_up(k) and k.writes == 1, T)
        step_and_tick(core, k, 300)
        wait_until(lambda: caught_up(k), T)
        assert k.writes > 1
    finally:
        k.stop()


def test_the_write_rate_while_moving(tmp_path: Path) -> None:
    core = make_core()
    k = keeper(tmp_path, core)
    now = [0.0]
    k._clock = lambda: now[0]
    power(core, 0)
    core.step()
    ok(cmd(core, "MoveVelocity", 1, Velocity=10.0))

    def snapshot_at(t: float) -> None:
        for _ in range(100):
            core.step()
        now[0] = t
        k._write(k._snapshot(core))

    for s in range(21):  # 2 s of snapshots, every 100 ms: while only positions change, one write per second
        snapshot_at(s / 10)
    assert k.writes == 3 and k.deferred == 18  # at 0.0 (standstill FALSE at once), 1.0, 2.0
    ok(cmd(core, "SetReferenceFlag", 1, ReferenceFlag=True))
    snapshot_at(2.05)  # a homed flag: at once
    ok(cmd(core, "WriteParameter", 1, ParameterNumber=VELO_MAX, Value=900.0))
    snapshot_at(2.1)  # a parameter: at once
    assert k.writes == 5 and stored(tmp_path).axes[1].params == {"AxisVeloMax": (900.0, 1000.0)}
    ok(cmd(core, "Stop", 1))
    run_until(core, lambda: bool(R.standing(core)[0]), 10_000)
    snapshot_at(2.2)  # standing: at once, then nothing while nothing changes
    snapshot_at(2.3)
    snapshot_at(5.0)
    assert k.writes == 6 and stored(tmp_path).axes[1].standstill is True
    ok(cmd(core, "SetActualPosition", 1, Position=3.0))
    snapshot_at(5.1)  # a standing axis's position: at once
    assert k.writes == 7 and stored(tmp_path).axes[1].position == 3.0
    k.close()


def test_tick_does_not_block_on_a_hung_disk(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    hang, entered = threading.Event(), threading.Event()

    def hung(_p: Any, _d: bytes) -> bool:
        entered.set()
        hang.wait(120)
        return True

    monkeypatch.setattr(R, "write_atomic", hung)
    core = make_core()
    k = keeper(tmp_path, core)
    k.start()
    try:
        k.tick(core)
        assert entered.wait(60)  # the retain thread hangs in its write
        handed = k.handed
        step_and_tick(core, k, 500)  # the cycle goes on: tick() returns
        assert k.handed >= handed + 4 and k.processed < k.handed and not hang.is_set()
    finally:
        hang.set()
        k.stop()


def test_a_kill_mid_move(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """The NC is killed while the axis moves (in-process: the retain thread and the core just stop, the
    kernel releases the lock): the next start has the last written position, unreferenced."""
    core = make_core()
    k = keeper(tmp_path, core)
    power(core, 0)
    core.step()
    ok(cmd(core, "SetReferenceFlag", 1, ReferenceFlag=True))
    ok(cmd(core, "MoveAbsolute", 1, Position=900.0, Velocity=100.0))
    k.start()
    try:
        step_and_tick(core, k, 200)
        wait_until(lambda: caught_up(k), T, "the retain thread to handle the last snapshot")
        d = stored(tmp_path).axes[1]
        assert d.homed and d.standstill is False
        step_and_tick(core, k, 50)  # the axis goes on after the write
        assert core.moving[0]
    finally:
        k._stop.set()  # SIGKILL: no final write
        k._wake.set()
        k.close()
    killed_at = stored(tmp_path).axes[1]
    assert killed_at.position < float(core.act_pos[0]) - 0.5
    with caplog.at_level(logging.WARNING, "nc_server.server"):
        core2, k2 = restart(tmp_path)
    assert core2.act_pos[0] == pytest.approx(killed_at.position) and not core2.axes.homed[0]
    assert "while it moved" in caplog.text
    k2.close()


def test_write_failures_are_reported_once(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    core = make_core()
    k = RetainKeeper(tmp_path / "gone" / "nc1.retain", "nc1", core)  # (the config refuses this; here: a lost disk)
    k.applied = True
    with caplog.at_level(logging.ERROR, "nc_server.server"):
        k._write(k._snapshot(core))
        k._write(k._snapshot(core))
    assert k.write_errors == 2 and caplog.text.count("cannot write") == 1


def test_the_server_applies_in_its_first_cycle_before_any_command(tmp_path: Path) -> None:
    from nc_server.server.app import NcServer
    conf = tmp_path / "nc.toml"
    conf.write_text(f'[nc]\nname = "nc1"\nrealtime = "off"\nretain_file = "{tmp_path / "nc1.retain"}"\n'
                    '[zenoh]\nlisten = ["tcp/127.0.0.1:9"]\n[[axis]]\nAxisId = 1\nName = "A1"\nAxisEnDataPersistence = true\n')
    cfg = load_config(conf)  # (zenoh is never opened here: server.cycle() is called directly)
    save(tmp_path, RetainData("nc1", {1: AxisRetain("A1", 130.0, True, True, 0.0)}))
    core = NcCore(list(cfg.axes), cfg.cycle_time, drive=EncoderAt5000([a.params for a in cfg.axes], cfg.cycle_time))
    server = NcServer(cfg, core)
    assert server.retain is not None
    try:
        server.load_retain()
        sentinel = object()  # a query that arrived before the first cycle
        server.transport.queries.append(sentinel)
        server.idle()  # between cycles: nothing before the file is applied
        assert list(server.transport.queries) == [sentinel]
        server.cycle(time.monotonic_ns())
        assert core.cycle == 1 and server.retain.applied
        assert core.act_pos[0] == pytest.approx(130.0) and core.axes.homed[0]
        assert list(server.transport.queries) == [sentinel] and server.frames.ring.seq == 0  # no command, no frame yet
        server.transport.queries.clear()
        frames = server.frames.reader()
        server.cycle(time.monotonic_ns())
        got = frames.read_newest()
        assert got is not None and core.nctoplc["ActPos"][0] == pytest.approx(130.0)
        assert decode_frame(got[1])[1]["ActPos"][0] == pytest.approx(130.0)  # the first frame shows the restored state
    finally:
        server.retain.stop()


# ---- configuration ----------------------------------------------------------------------------
def test_config_keys(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    assert load_config().retain_file is None
    cfg = load_config(retain_file=str(tmp_path / "a.retain"))
    assert cfg.retain_file == str(tmp_path / "a.retain")
    conf = tmp_path / "nc.toml"
    conf.write_text(f'[nc]\nretain_file = "{tmp_path / "b.retain"}"\n[[axis]]\nAxisId = 1\nAxisEnDataPersistence = true\n')
    cfg = load_config(conf)
    assert cfg.retain_file == str(tmp_path / "b.retain") and cfg.axes[0].params.AxisEnDataPersistence
    (tmp_path / "b.retain").write_bytes(b"")  # an existing regular file is fine
    assert load_config(conf).retain_file == str(tmp_path / "b.retain")
    os.mkfifo(tmp_path / "fifo")
    (tmp_path / "link").symlink_to(tmp_path / "b.retain")
    for bad, what in ((str(tmp_path / "nodir" / "x.retain"), "does not exist"), (str(tmp_path), "a directory"),
                      ("", "must be a file path"), (str(tmp_path / "fifo"), "a FIFO"),
                      (str(tmp_path / "link"), "a symlink")):
        with pytest.raises(ConfigError) as ei:
            load_config(retain_file=bad)
        assert ei.value.key == "nc.retain_file" and what in str(ei.value), ei.value
    conf.write_text('[nc]\nretain_file = 1\n[[axis]]\nAxisId = 1\n')
    with pytest.raises(ConfigError) as ei:
        load_config(conf)
    assert ei.value.key == "nc.retain_file"
    # a directory the NC may not write (root may write anywhere: access() is asked)
    real_access = os.access
    monkeypatch.setattr(os, "access", lambda p, m, **kw: False if Path(p) == tmp_path else real_access(p, m, **kw))
    with pytest.raises(ConfigError) as ei:
        load_config(retain_file=str(tmp_path / "c.retain"))
    assert "not writable" in str(ei.value)
    monkeypatch.undo()
    # a relative path is resolved against the working directory (also in a config file elsewhere)
    sub = tmp_path / "run"
    sub.mkdir()
    conf.write_text('[nc]\nretain_file = "data/nc1.retain"\n[[axis]]\nAxisId = 1\n')
    (sub / "data").mkdir()
    monkeypatch.chdir(sub)
    assert load_config(conf).retain_file == str(sub / "data" / "nc1.retain")
    assert load_config(retain_file="x.retain").retain_file == str(sub / "x.retain")
