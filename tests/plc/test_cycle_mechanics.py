"""The cheap per-cycle mechanics of the PLC task (issue 19) give what the plain ways gave: the preallocated
PLC frame is encode_plc_records' bytes, the blocks' NCJOBS values are the numpy record's, a snapshot is
the frame of its cycle whatever the NC does to its arrays afterwards, a frame taken as bytes gives what
decode_frame's arrays give, and the blocks' one-update input and output paths fall back to setattr where a
class has a property of that name."""
from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
import pytest

from nc_schema import NCJOBS_DTYPE, NCTOPLC_DTYPE, decode_frame, encode_frame, encode_plc_records
from plc_client import AXIS_REF, MC_Power, MC_ReadStatus, PlcTask
from plc_client.fb.base import ExecuteBlock, FunctionBlock
from plc_client.plcframe import PlcFrameBuffer
from plc_client.port import CommandPort
from plc_client.records import NO_JOBS, NcJobsValues
from znc_testing.plc_rig import Rig, ScriptNc


def _random_plctonc(axes: list[AXIS_REF], rng: np.random.Generator) -> None:
    for ax in axes:
        ax._plctonc_buf[:] = rng.integers(0, 256, len(ax._plctonc_buf), dtype=np.uint8).tobytes()


def test_plc_frame_buffer_is_encode_plc_records_every_cycle() -> None:
    axes = [AXIS_REF("nc1", a) for a in (7, 1, 65535)]
    rng = np.random.default_rng(3)
    buf = PlcFrameBuffer(axes)
    for cycle in (0, 1, 2, 2**40 + 3, 2**64 - 1):
        _random_plctonc(axes, rng)  # the records change between cycles: each frame has the new ones
        ref = encode_plc_records(cycle, [(ax.axis_id, ax._plctonc) for ax in axes])
        assert buf.frame(cycle) == ref
    assert PlcFrameBuffer([]).frame(5) == encode_plc_records(5, [])
    assert buf.frame(9) is buf.buf  # the same buffer, rewritten


def test_the_task_frame_follows_the_controlled_axes() -> None:
    """PlcTask.plc_frame: the frame of the axes _publish is given, rebuilt when they change (a hand-over,
    another axis controlled), equal to encode_plc_records of the same axes and cycle."""
    nc = ScriptNc(n_axes=3)
    sent: list[tuple[bytes, bytes]] = []

    def publish(name: str, axes: list[AXIS_REF]) -> None:
        sent.append((bytes(nc.plc_frame(name, axes)),
                     encode_plc_records(nc.cycle, [(a.axis_id, a._plctonc) for a in axes])))

    nc._publish = publish  # type: ignore[method-assign]
    x, y = nc.ax, nc.axis("nc1", 2)
    px, py = MC_Power(), MC_Power()
    nc.calls.append(lambda: px(Axis=x, Enable=True, Enable_Positive=True, Override=50.0))
    for _ in range(3):
        nc.cycle_once()
    nc.calls.append(lambda: py(Axis=y, Enable=nc.cycle % 2 == 0))  # its ControlDWord changes every cycle
    for _ in range(4):
        nc.cycle_once()
    assert len(sent) == 7
    for got, ref in sent:
        assert got == ref
    assert len(sent[2][0]) < len(sent[3][0])  # the second axis joined the frame


def test_nc_jobs_values_are_the_numpy_record() -> None:
    rng = np.random.default_rng(5)
    a = np.frombuffer(rng.integers(0, 256, NCJOBS_DTYPE.itemsize, dtype=np.uint8).tobytes(), dtype=NCJOBS_DTYPE)
    a = a.copy()
    a["GearRatio"] = 1.25  # (random bytes could make NaNs: == would fail)
    for f in ("SuperDistance", "SuperVelocityDiff", "SuperLength", "RecordedPosition"):
        a[f] = rng.normal()
    j = NcJobsValues(a.tobytes())
    rec = a[0]
    assert NcJobsValues.dtype.names is not None
    for name in NcJobsValues.dtype.names:
        if name == "Ended":
            want = tuple((int(e["CmdNo"]), int(e["CmdState"]), int(e["ErrorId"])) for e in rec["Ended"])
            assert j.Ended == j["Ended"] == want
        else:
            assert getattr(j, name) == j[name] == rec[name].item(), name
            assert type(j[name]) in (int, float)
    assert j.record.tobytes() == a.tobytes() and not j.record.flags.writeable
    with pytest.raises(KeyError):
        j["Nope"]
    assert NO_JOBS.AxisId == 0 and NO_JOBS.Ended == ((0, 0, 0),) * 4


def test_snapshots_are_the_frame_of_their_cycle() -> None:
    """NcToPlc/NcJobs are sliced from one copy of the frame's records: the NC rewriting its arrays
    afterwards (the in-process core does, every step) changes none of them; NcJobs is still a read-only
    numpy record."""
    rig = Rig(n_axes=2)
    plc = rig.plc(program=lambda p: None)
    ax = plc.axis("nc1", 2)
    rig.run(2)
    plc.step()  # (no NC step after it: the core's arrays are this snapshot's frame)
    rec, jobs = ax.NcToPlc, ax.NcJobs
    before = (rec.tobytes(), jobs.tobytes())
    assert rec.tobytes() == rig.core.nctoplc[1].tobytes() and jobs.tobytes() == rig.core.ncjobs[1].tobytes()
    rig.core.nctoplc[1]["SetPos"] = 123.0
    rig.core.ncjobs[1]["NewestCmdNo"] = 77
    assert (rec.tobytes(), jobs.tobytes()) == before
    assert isinstance(jobs, np.void) and jobs.dtype == NCJOBS_DTYPE
    with pytest.raises(ValueError):
        jobs["NewestCmdNo"] = 1
    plc.step()  # the next snapshot has the NC's data of then
    assert ax.NcToPlc.SetPos == 123.0 and int(ax.NcJobs["NewestCmdNo"]) == 77 == ax._jobs.NewestCmdNo


def test_a_frame_entry_replaced_by_hand_is_snapshotted() -> None:
    """_frames entries put there other than by _set_frame (tests do) are what the axes get."""
    nc = ScriptNc()
    nc.cycle_once()
    cyc, recs, index, jobs = nc._frames["nc1"]
    recs = recs.copy()
    recs[0]["SetPos"] = 4.5
    nc._frames["nc1"] = (cyc, recs, index, jobs)
    nc._take_frames = lambda: None  # type: ignore[method-assign]
    nc.step()
    assert nc.ax.NcToPlc.SetPos == 4.5


class _PropertyOutput(ExecuteBlock):
    """A block with a property among its declared names: the one-update paths must not bypass it."""

    _INPUTS: ClassVar[dict[str, Any]] = {"Execute": False, "Level": 0}
    Level: int
    seen: list[Any]

    @property
    def Done(self) -> bool:  # type: ignore[override]
        return bool(self.__dict__.get("_done", False))

    @Done.setter
    def Done(self, v: bool) -> None:
        self.__dict__["_done"] = v
        self.__dict__.setdefault("_writes", []).append(v)

    def _start(self) -> None:
        self._finish("Done")

    def _progress(self) -> None:
        pass


def test_blocks_with_properties_keep_setattr() -> None:
    assert MC_Power._PLAIN_IO and MC_ReadStatus._PLAIN_IO
    assert not _PropertyOutput._PLAIN_IO
    fb = _PropertyOutput()
    fb(Execute=True, Level=3)
    assert fb.Done and fb.Level == 3 and "Done" not in fb.__dict__
    fb(Execute=False)
    assert not fb.Done and fb.__dict__["_writes"][-1] is False


def test_inputs_in_another_case_and_unknown_inputs_still_work() -> None:
    rs = MC_ReadStatus()
    rs(enable=True)
    assert rs.Enable is True
    with pytest.raises(TypeError):
        rs(Enable=True, Nope=1)
    assert isinstance(FunctionBlock._is_real(1.0), bool)
    assert FunctionBlock._is_real(1) and FunctionBlock._is_real(np.float32(2.0))
    assert not FunctionBlock._is_real(float("nan")) and not FunctionBlock._is_real(True)
    assert not FunctionBlock._is_real("1") and not FunctionBlock._is_real(float("inf"))


def _task_with(ids: tuple[int, ...]) -> tuple[PlcTask, dict[int, AXIS_REF]]:
    class _Port(CommandPort):
        def _transmit(self, pending: Any, payload: bytes) -> None:
            pass

    t = PlcTask(None, client_id="t")
    t.port = _Port("t")
    t._take_frames = lambda: None  # type: ignore[method-assign]
    return t, {a: t.axis("nc1", a) for a in ids}


def _frame(cycle: int, ids: list[int], rng: np.random.Generator, jobs: bool = True) -> tuple[bytes, np.ndarray,
                                                                                           np.ndarray | None]:
    recs = np.zeros(len(ids), dtype=NCTOPLC_DTYPE)
    recs["AxisId"] = ids
    recs["StateDWord"] = rng.integers(0, 2**32, len(ids))
    recs["SetPos"], recs["SetVelo"], recs["SetAcc"] = rng.normal(size=(3, len(ids)))
    recs["CmdNo"] = rng.integers(0, 2**16, len(ids))
    jr = None
    if jobs:
        jr = np.zeros(len(ids), dtype=NCJOBS_DTYPE)
        jr["AxisId"] = ids
        jr["ActiveCmdNo"] = rng.integers(0, 2**16, len(ids))
        jr["Ended"]["ErrorId"] = rng.integers(0, 2**32, (len(ids), 4))
    return encode_frame(cycle, 7, recs, jobs=jr), recs, jr


def test_a_frame_taken_as_bytes_gives_what_decode_frame_gives() -> None:
    """_set_frame_bytes (the frame's bytes, no numpy) and _set_frame(decode_frame(...)) give every axis the
    same NcToPlc, NcJobs and Status: with and without job records, an axis the frame lacks (missing), the
    axis set changing, and the NC restarting (its cycle going back)."""
    rng = np.random.default_rng(11)
    ids = (2, 9, 7)
    a, axes_a = _task_with(ids)
    b, axes_b = _task_with(ids)
    frames = [(10, [5, 2, 9], True), (20, [5, 2, 9], True), (30, [5, 2, 9], False), (40, [9, 2], True),
              (50, [9, 2], True), (5, [2, 9, 7], True), (15, [2, 9, 7], True)]
    for cycle, in_frame, with_jobs in frames:
        data, _, _ = _frame(cycle, in_frame, rng, with_jobs)
        h, recs, jobs = decode_frame(data)
        a._set_frame("nc1", int(h["Cycle"]), recs, jobs)
        b._set_frame_bytes("nc1", data)
        a.step()
        b.step()
        for k in ids:
            xa, xb = axes_a[k], axes_b[k]
            assert xa.NcToPlc == xb.NcToPlc and xa.NcJobs.tobytes() == xb.NcJobs.tobytes(), (cycle, k)
            assert xa.Status.as_dict() == xb.Status.as_dict() and xa.missing == xb.missing, (cycle, k)
            assert xa.nc_epoch == xb.nc_epoch
    assert axes_b[7].Status.Valid and axes_b[7].nc_epoch == 1  # (the restart at cycle 5)
    with pytest.raises(ValueError):
        b._set_frame_bytes("nc1", b"\0" * 40)


def _snap_state(ax: AXIS_REF) -> tuple[Any, ...]:
    return (dict(ax.Status.__dict__), ax.NcToPlc.tobytes(), ax._jobs.tobytes(), ax.missing, ax.pending,
            ax._unchanged)


def test_cycles_without_a_new_frame_give_what_decoding_the_same_frame_again_gives() -> None:
    """A cycle that finds no newer frame skips the decoding (PlcTask._snapshot_all, AXIS_REF._src): every axis
    then has what it had when the frame was taken again as new bytes each cycle (the decoding path), its
    Status, NcToPlc, NcJobs and counters, through the frames stopping (stale after stale_cycles: 0x4B0F),
    an NC reported down, a changed StateDWord and an axis the next frame lacks."""
    rng = np.random.default_rng(5)
    ids = (3, 1, 4)
    skip, axes_s = _task_with(ids)  # takes a frame only when a new one comes (the runtime's way)
    dec, axes_d = _task_with(ids)  # takes the frame held again every cycle (a new entry: decoded again)
    blocks = {t: {a: (MC_ReadStatus(), MC_Power()) for a in ids} for t in (skip, dec)}
    assert skip.stale_cycles == dec.stale_cycles
    stale = skip.stale_cycles
    # per cycle: a new frame (its ids) or None (no newer frame); "down"/"up": the NC's liveliness
    plan: list[Any] = [list(ids)] + [None] * 3 + [list(ids)] + [None] * (stale + 3) + [list(ids), None, "down", None,
                                                                                       "up", list(ids), None,
                                                                                       [3, 4], None, None]
    held: bytes | None = None
    for k, what in enumerate(plan):
        if what == "down":
            skip.nc_down("nc1"), dec.nc_down("nc1")
        elif what == "up":
            skip.nc_up("nc1"), dec.nc_up("nc1")
        elif what is not None:
            held = _frame(100 + k, what, rng)[0]
            skip._set_frame_bytes("nc1", held)
        assert held is not None
        dec._set_frame_bytes("nc1", bytes(held))  # (the same cycle again: taken, a new frame entry)
        for t, axes in ((skip, axes_s), (dec, axes_d)):
            t.step()
            for a, ax in axes.items():
                rs, pw = blocks[t][a]
                rs(Axis=ax, Enable=True)
        for a in ids:
            assert _snap_state(axes_s[a]) == _snap_state(axes_d[a]), (k, a)
            rs_s, rs_d = blocks[skip][a][0], blocks[dec][a][0]
            assert (rs_s.Valid, rs_s.Error, rs_s.ErrorID) == (rs_d.Valid, rs_d.Error, rs_d.ErrorID), (k, a)
    # the path was taken (the frames held for some cycles), and the data went stale on it as on the other
    assert any(ax._src is not None for ax in axes_s.values())


def test_a_programs_write_into_status_lasts_until_the_next_new_frame() -> None:
    """AXIS_REF.Status is derived from the NC's record at every snapshot of a new frame (TwinCAT's ReadStatus
    rewrites it each call): a member the program wrote is set again from StateDWord even when StateDWord did not
    change."""
    nc = ScriptNc()
    nc.cycle_once(2)
    homed, error = nc.ax.Status.Homed, nc.ax.Status.Error
    nc.ax.Status.Homed = not homed
    nc.ax.Status.Error = not error
    nc.cycle_once(2)  # new frames, the same StateDWord
    assert nc.ax.Status.Homed == homed and nc.ax.Status.Error == error
