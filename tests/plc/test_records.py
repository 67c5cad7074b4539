"""AXIS_REF.NcToPlc / PlcToNc with TwinCAT member names: plain Python values, generated from
schema/structs.json, the item form kept, checked writes, lazy unpacking."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from nc_schema import NCTOPLC_DTYPE, PLCTONC_DTYPE, ErrorCodes, StateDWord, member_struct, to_dict
from nc_schema.codec import load_json
from nc_server.core import NcCore
from nc_server.core.params import AxisConfig
from nc_sim import InProcessPlc, run_cycles
from plc_client import AXIS_REF, NCTOPLC_AXIS_REF, PLCTONC_AXIS_REF, MC_MoveVelocity, MC_Power


def _record(**values: object) -> np.void:
    a = np.zeros(1, dtype=NCTOPLC_DTYPE)
    for k, v in values.items():
        a[k] = v
    return a[0]


def test_every_schema_member_is_an_attribute() -> None:
    schema = load_json("structs.json")["structs"]
    for struct_name, cls in (("NCTOPLC_AXIS_REF", NCTOPLC_AXIS_REF), ("PLCTONC_AXIS_REF", PLCTONC_AXIS_REF)):
        names = [f["name"] for f in schema[struct_name]["fields"] if not f["name"].startswith("_")]
        assert list(cls().keys()) == names
        for n in names:
            assert isinstance(getattr(cls, n), property), n
            assert getattr(cls, n).__doc__.startswith(next(f["type"] for f in schema[struct_name]["fields"]
                                                           if f["name"] == n))


def test_nctoplc_values_are_plain_and_match_numpy() -> None:
    rec = _record(SetPos=12.5, ActPos=-3.25, StateDWord=0x80000001, CmdNo=65535, ModuloActTurns=-7,
                  CamCouplingState=[1, 2, 3, 4, 5, 6, 7, 255], CamCouplingTableID=[9] * 8, AxisId=3)
    r = NCTOPLC_AXIS_REF(rec.tobytes())
    assert r.SetPos == 12.5 and type(r.SetPos) is float
    assert r.ActPos == -3.25 and r.StateDWord == 0x80000001 and type(r.StateDWord) is int
    assert r.CmdNo == 65535 and r.ModuloActTurns == -7 and r.AxisId == 3
    assert r.CamCouplingState == (1, 2, 3, 4, 5, 6, 7, 255) and r.CamCouplingTableID == (9,) * 8
    assert r["SetPos"] == r.SetPos and r["CamCouplingState"] == r.CamCouplingState
    # every member equals what numpy reads from the same bytes
    for name, want in to_dict(rec).items():
        got = r[name]
        assert (list(got) if isinstance(got, tuple) else got) == want, name
    d = r.as_dict()
    assert d == to_dict(rec)
    json.dumps(d)  # JSON-ready without float()
    assert r.tobytes() == rec.tobytes() and r.record.dtype == NCTOPLC_DTYPE and r.dtype == NCTOPLC_DTYPE
    assert float(r.record["SetPos"]) == 12.5
    with pytest.raises(ValueError):
        r.record["SetPos"] = 1.0  # the numpy form is read-only too


def test_nctoplc_is_read_only_and_names_are_checked() -> None:
    r = NCTOPLC_AXIS_REF(_record(SetPos=1.0).tobytes())
    with pytest.raises(ValueError):
        r["SetPos"] = 2.0
    with pytest.raises(AttributeError):
        r.SetPos = 2.0  # type: ignore[misc]
    with pytest.raises(AttributeError):
        r.Foo = 1  # type: ignore[attr-defined]
    with pytest.raises(KeyError):
        r["Foo"]
    with pytest.raises(AttributeError):
        r.SetPosition  # type: ignore[attr-defined]
    assert r.SetPos == 1.0
    with pytest.raises(ValueError):
        NCTOPLC_AXIS_REF(b"\0" * 10)


def test_plctonc_attributes_write_the_published_bytes() -> None:
    ax = AXIS_REF(nc="nc1", axis_id=1)
    assert ax.PlcToNc.Override == 1_000_000 and ax.PlcToNc["Override"] == 1_000_000
    ax.PlcToNc.Override = 500_000
    ax.PlcToNc.GearRatio1 = 1.5
    ax.PlcToNc["ExtSetDirection"] = -1
    ax.PlcToNc.MapState = True
    raw = np.frombuffer(ax.PlcToNc.tobytes(), dtype=PLCTONC_DTYPE)[0]
    assert int(raw["Override"]) == 500_000 and float(raw["GearRatio1"]) == 1.5
    assert int(raw["ExtSetDirection"]) == -1 and int(raw["MapState"]) == 1
    # the numpy view the frame encoders take is the same memory
    assert int(ax._plctonc["Override"][0]) == 500_000 and ax._plctonc.tobytes() == ax.PlcToNc.tobytes()
    ax.PlcToNc.record["Override"] = 7
    assert ax.PlcToNc.Override == 7
    assert type(ax.PlcToNc.GearRatio1) is float and ax.PlcToNc.as_dict()["GearRatio1"] == 1.5


@pytest.mark.parametrize("name,value,exc", [
    ("Override", 5.5, TypeError), ("Override", -1, ValueError), ("Override", 2 ** 32, ValueError),
    ("Override", "100", TypeError), ("GearRatio1", "1.0", TypeError), ("GearRatio1", None, TypeError),
    ("ExtSetDirection", 2 ** 31, ValueError), ("PlcCycleCount", 256, ValueError), ("Nonsense", 1, KeyError),
    # a bool only for BOOL/BYTE members: Override = True would be 1 (0.0001 %) silently
    ("Override", True, TypeError), ("ControlDWord", np.bool_(True), TypeError), ("ExtSetDirection", False, TypeError),
    ("Override", np.float64(500000.0), TypeError),
])
def test_plctonc_bad_writes_change_nothing(name: str, value: object, exc: type[Exception]) -> None:
    ax = AXIS_REF(nc="nc1", axis_id=1)
    before = ax.PlcToNc.tobytes()
    with pytest.raises(exc):
        ax.PlcToNc[name] = value
    if name != "Nonsense":
        with pytest.raises(exc):
            setattr(ax.PlcToNc, name, value)
    assert ax.PlcToNc.tobytes() == before


def test_snapshot_of_each_cycle_keeps_its_values() -> None:
    core = NcCore([AxisConfig(AxisId=1)], cycle_time=0.001)
    X = AXIS_REF(nc="nc1", axis_id=1)
    power, jog = MC_Power(), MC_MoveVelocity()

    def cycle(plc: InProcessPlc) -> None:
        power(Axis=X, Enable=True, Enable_Positive=True, Enable_Negative=True)
        jog(Axis=X, Execute=bool(power.Status), Velocity=100.0)

    plc = InProcessPlc(core, cycle)
    run_cycles(core, plc, 200, nc_steps=10, until=lambda: jog.InVelocity)
    assert jog.InVelocity
    old = X.NcToPlc
    pos = old.SetPos
    run_cycles(core, plc, 5, nc_steps=10)
    assert X.NcToPlc.SetPos > pos and old.SetPos == pos  # an older snapshot is not changed under you
    assert math.isclose(X.NcToPlc.SetVelo, 100.0) and X.NcToPlc.SetVelo == float(core.nctoplc[0]["SetVelo"])
    assert X.NcToPlc.AxisId == 1 and X.NcToPlc.CmdNo == int(core.nctoplc[0]["CmdNo"])
    json.dumps({"SetPos": X.NcToPlc.SetPos, "CmdNo": X.NcToPlc.CmdNo, "State": X.NcToPlc.StateDWord})


def test_nctoplc_unpacks_lazily_once_per_cycle() -> None:
    r = NCTOPLC_AXIS_REF._of(_record(SetPos=4.0).tobytes())
    assert r._v is None  # nothing unpacked until read
    assert r.SetPos == 4.0
    v = r._v
    assert v is not None and r.ActPos == 0.0 and r._v is v  # one unpack serves every member


def test_plctonc_bool_members_take_bools_and_a_real_gets_a_hint() -> None:
    ax = AXIS_REF(nc="nc1", axis_id=1)
    ax.PlcToNc.MapState = True
    ax.PlcToNc.PlcCycleControl = np.bool_(True)  # BYTE: a bool is 1
    assert ax.PlcToNc.MapState == 1 and ax.PlcToNc.PlcCycleControl == 1
    with pytest.raises(TypeError, match=r"round\(\)"):
        ax.PlcToNc.Override = 0.5 * 1e6
    assert ax.PlcToNc.Override == 1_000_000


def test_pick_struct_reads_the_members_the_full_unpack_reads() -> None:
    from nc_schema import NCJOBS_DTYPE
    from nc_schema.layout import pick_struct
    from plc_client.records import NcJobsValues
    rng = np.random.default_rng(7)
    names = ("StateDWord", "ErrorCode", "CoupleState", "SetVelo", "SetAcc")
    pick = pick_struct(NCTOPLC_DTYPE, *names)
    jnames = ("AxisId", "ActiveCmdNo", "ActiveState", "BufferedCmdNo", "NewestCmdNo")
    jpick = pick_struct(NCJOBS_DTYPE, *jnames)
    for _ in range(50):
        raw = _record(StateDWord=int(rng.integers(0, 2**32)), ErrorCode=int(rng.integers(0, 2**32)),
                      CoupleState=int(rng.integers(0, 2**16)), SetVelo=float(rng.normal()),
                      SetAcc=float(rng.normal()), SetPos=float(rng.normal())).tobytes()
        full = NCTOPLC_AXIS_REF(raw)
        assert pick.unpack(raw) == tuple(getattr(full, n) for n in names)
        jraw = rng.integers(0, 256, NCJOBS_DTYPE.itemsize, dtype=np.uint8).tobytes()
        jobs = NcJobsValues(jraw)
        assert jpick.unpack(jraw) == tuple(getattr(jobs, n) for n in jnames)
    with pytest.raises(ValueError):
        pick_struct(NCTOPLC_DTYPE, "ErrorCode", "StateDWord")  # not in the record's order
    with pytest.raises(ValueError):
        pick_struct(NCTOPLC_DTYPE, "CamCouplingState")  # an array
    with pytest.raises(KeyError):
        pick_struct(NCTOPLC_DTYPE, "NoSuchMember")


def test_snapshot_keeps_statedword_and_unpacks_nctoplc_only_when_read() -> None:
    core = NcCore([AxisConfig(AxisId=1)], cycle_time=0.001)
    X = AXIS_REF(nc="nc1", axis_id=1)
    power = MC_Power()
    seen: list[tuple[bool, bool]] = []  # per cycle after MC_Power: (NcToPlc not unpacked yet, _sdw = its StateDWord)

    def cycle(plc: InProcessPlc) -> None:
        power(Axis=X, Enable=True, Enable_Positive=True, Enable_Negative=True)
        rec = X.NcToPlc
        lazy = rec._v is None
        seen.append((lazy, rec._sdw == rec.StateDWord))  # (the read unpacks it, after the laziness was noted)

    plc = InProcessPlc(core, cycle)
    run_cycles(core, plc, 200, nc_steps=10, until=lambda: power.Status)
    assert power.Status and X.Status.ControlLoopClosed
    assert len(seen) > 1 and all(lazy for lazy, _ in seen[1:])  # MC_Power and the task read it without unpacking
    assert all(same for _, same in seen)
    assert X.NcToPlc._sdw & int(StateDWord.ControlLoopClosed) and X.Status.ErrorId == X.NcToPlc.ErrorCode


def test_a_record_assigned_by_hand_is_what_the_blocks_see() -> None:
    """A program (or a test) that puts its own NcToPlc in place: MC_Power judges that record's StateDWord and
    ErrorCode (Error/ErrorID, Enable TRUE and FALSE), not those of the cycle's snapshot it replaced (nor
    Status.ErrorId, refreshed from that snapshot)."""
    core = NcCore([AxisConfig(AxisId=1)], cycle_time=0.001)
    X = AXIS_REF(nc="nc1", axis_id=1)
    power = MC_Power()
    inject = [False]
    enable = [True]
    sdw_off, sdw_struct = member_struct(NCTOPLC_DTYPE, "StateDWord")
    ec_off, ec_struct = member_struct(NCTOPLC_DTYPE, "ErrorCode")

    def cycle(plc: InProcessPlc) -> None:
        if inject[0]:
            raw = bytearray(X.NcToPlc.tobytes())
            sdw_struct.pack_into(raw, sdw_off, X.NcToPlc.StateDWord | int(StateDWord.Error))
            ec_struct.pack_into(raw, ec_off, ErrorCodes.NC_POSITION_LAG)
            X.NcToPlc = NCTOPLC_AXIS_REF(bytes(raw))
        power(Axis=X, Enable=enable[0], Enable_Positive=True, Enable_Negative=True)

    plc = InProcessPlc(core, cycle)
    run_cycles(core, plc, 200, nc_steps=10, until=lambda: power.Status)
    assert power.Status
    inject[0] = True
    run_cycles(core, plc, 1, nc_steps=10)
    assert X.NcToPlc.StateDWord & int(StateDWord.Error) and X.NcToPlc._sdw == X.NcToPlc.StateDWord
    assert X.Status.ErrorId == 0, "the snapshot's (the NC has no error): the record's code is only in its bytes"
    assert not power.Status
    assert power.Error and power.ErrorID == ErrorCodes.NC_POSITION_LAG == 0x4550
    enable[0] = False
    run_cycles(core, plc, 1, nc_steps=10)
    assert power.Error and power.ErrorID == 0x4550, "Enable FALSE: the record's code too"
    inject[0] = False
    run_cycles(core, plc, 1, nc_steps=10)
    assert not power.Error and power.ErrorID == 0


def test_a_record_assigned_by_hand_stays_until_the_next_frame() -> None:
    """The snapshot is renewed when a frame arrived (AXIS_REF docstring): while none did, a record the program
    assigned to NcToPlc stays in the cycles after (and MC_Power judges it); the next frame replaces it."""
    from znc_testing.plc_rig import ScriptNc

    nc = ScriptNc()
    X = nc.ax
    power = MC_Power()
    nc.calls.append(lambda: power(Axis=X, Enable=True))
    nc.cycle_once(2)
    assert nc.stale_cycles >= 4
    take = nc._take_frames
    nc._take_frames = lambda: None  # type: ignore[method-assign]  # no frame arrives
    raw = bytearray(X.NcToPlc.tobytes())
    sdw_off, sdw_struct = member_struct(NCTOPLC_DTYPE, "StateDWord")
    ec_off, ec_struct = member_struct(NCTOPLC_DTYPE, "ErrorCode")
    sdw_struct.pack_into(raw, sdw_off, X.NcToPlc.StateDWord | int(StateDWord.Error))
    ec_struct.pack_into(raw, ec_off, 0x4550)
    mine = X.NcToPlc = NCTOPLC_AXIS_REF(bytes(raw))
    nc.cycle_once(2)
    assert X.NcToPlc is mine and X.Status.Valid
    assert power.Error and power.ErrorID == 0x4550
    nc._take_frames = take  # type: ignore[method-assign]
    nc.cycle_once()
    assert X.NcToPlc is not mine and not X.NcToPlc.StateDWord & int(StateDWord.Error)
    assert not power.Error and power.ErrorID == 0
