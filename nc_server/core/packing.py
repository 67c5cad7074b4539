"""Packing the NC's state into its output records: the NCJOBS_AXIS_REF job records (on events, one
packed write per part) and the NCTOPLC_AXIS_REF fields the cycle writes (every cycle, a few vector
copies into views of the record array).

It owns the record layouts' packed forms (checked against ``nc_schema``'s dtypes at import) and
nothing else: what goes in comes from the caller.

It may import: nc_schema, numpy, .jobs.base (ENDED_KEPT, types), .npcount.
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from nc_schema import NCJOBS_DTYPE, NCTOPLC_DTYPE
from nc_schema.layout import flat_struct

from .jobs.base import ENDED_KEPT
from .npcount import count_nonzero

if TYPE_CHECKING:
    from .jobs.base import JobQueue
    from .stages import CouplingStage, ExternalStage, ProbeStage, SuperpositionStage

#: the queue part of an NCJOBS_AXIS_REF record: AxisId, ActiveCmdNo, ActiveState, BufferedCmdNo, BufferedMode,
#: NewestCmdNo, Flags, then ENDED_KEPT x (CmdNo, CmdState, ErrorId)
NCJOBS_QUEUE = flat_struct(NCJOBS_DTYPE, stop="MasterId")
#: its slots part: MasterId, SyncFlags, GearRatio, SuperCmdNo, SuperState, SuperErrorId, SuperDistance,
#: SuperVelocityDiff, SuperLength, ProbeCmdNo, ProbeState, ProbeCounter, RecordedPosition, RecordedTimeNs,
#: ProbeErrorId, DriveStatus
NCJOBS_SLOTS = flat_struct(NCJOBS_DTYPE, start="MasterId", stop="PhaseError")
#: the phase part (coupling across NCs): PhaseError, PhaseErrorMax, PhaseBound, MasterAgeUs, written as columns
#: every cycle by the coupling stage while such a slave runs
NCJOBS_PHASE = flat_struct(NCJOBS_DTYPE, start="PhaseError")
NCJOBS_SIZE = NCJOBS_DTYPE.itemsize
assert NCJOBS_DTYPE["Ended"].shape == (ENDED_KEPT,)
assert NCJOBS_QUEUE.size + NCJOBS_SLOTS.size + NCJOBS_PHASE.size == NCJOBS_SIZE and NCJOBS_DTYPE.names == (
    "AxisId", "ActiveCmdNo", "ActiveState", "BufferedCmdNo", "BufferedMode", "NewestCmdNo", "Flags", "Ended",
    "MasterId", "SyncFlags", "GearRatio", "SuperCmdNo", "SuperState", "SuperErrorId", "SuperDistance",
    "SuperVelocityDiff", "SuperLength", "ProbeCmdNo", "ProbeState", "ProbeCounter", "RecordedPosition",
    "RecordedTimeNs", "ProbeErrorId", "DriveStatus", "PhaseError", "PhaseErrorMax", "PhaseBound", "MasterAgeUs", "_reserved3")
SYNC_EXT_ENABLED, SYNC_EXT_FOLLOWING, SYNC_DYN, SYNC_SYNCHRON, SYNC_REMOTE = 1, 2, 4, 8, 16
_NO_ENDED = [0, 0, 0] * ENDED_KEPT


class JobRecords:
    """The NCJOBS_AXIS_REF records of one NC (``ncjobs``), written as packed bytes (field by field
    through np.void cost ~6 us a record)."""

    def __init__(self, ncjobs: np.ndarray, axis_ids: Any) -> None:
        self.ncjobs = ncjobs
        self._bytes = ncjobs.view(np.uint8).data  # (= memoryview(...), which numpy types as a buffer on 3.12+ only)
        self._ids = [int(x) for x in axis_ids]
        self.drive_status = ncjobs["DriveStatus"]  # (a view: a simulated stepper terminal's status)
        #: counts the writes into ``ncjobs`` (every writer bumps it: the frame ring copies the records into a
        #: slot only when they changed since that slot's last frame)
        self.version = 0

    def pack_queue(self, i: int, q: JobQueue, cmd_no: int, cmd_state: int, amended: bool) -> None:
        """Row ``i``'s queue part: the shown job (``cmd_no``, ``cmd_state``), the waiting one, the ended ones."""
        w = q.waiting
        ended = [x for e in q.ended for x in (e.cmd_no, e.state, e.error_id)]
        ended += _NO_ENDED[len(ended):]
        o = i * NCJOBS_SIZE
        self.version += 1
        self._bytes[o:o + NCJOBS_QUEUE.size] = NCJOBS_QUEUE.pack(
            self._ids[i], cmd_no, cmd_state, w.cmd_no if w is not None else 0,
            w.buffer_mode if w is not None else 0, q.newest, 1 if amended else 0, *ended)

    def pack_slots(self, i: int, c: CouplingStage, sp: SuperpositionStage, pr: ProbeStage, ex: ExternalStage) -> None:
        """Row ``i``'s coupling, superposition, touch probe and drive status part."""
        m = int(c.master[i])
        k = int(c.remote[i])
        slave = m >= 0 or k >= 0
        master_id = self._ids[m] if m >= 0 else c.remote_master_id(k) if k >= 0 else 0
        flags = ((SYNC_EXT_ENABLED if ex.on[i] else 0) | (SYNC_EXT_FOLLOWING if ex.following[i] else 0)
                 | (SYNC_DYN if c.dyn[i] else 0) | (SYNC_SYNCHRON if slave and c.state[i] == 13 else 0)
                 | (SYNC_REMOTE if k >= 0 else 0))
        o = i * NCJOBS_SIZE + NCJOBS_QUEUE.size
        self.version += 1
        self._bytes[o:o + NCJOBS_SLOTS.size] = NCJOBS_SLOTS.pack(
            master_id, flags, float(c.ratio[i]) if slave else 0.0,
            int(sp.cmd_no[i]), int(sp.state[i]), int(sp.error[i]), *(float(x) for x in sp.actual[:, i]),
            int(pr.cmd_no[i]), int(pr.state[i]), int(pr.counter[i]), float(pr.recorded[i]), int(pr.recorded_ns[i]), int(pr.error[i]),
            int(self.drive_status[i]))


def _short_mantissas(period: np.ndarray) -> bool:
    """Every period is positive, finite and has at most 22 significant bits (e.g. 360: a product with an integer of
    magnitude below 2 ** 30 is exact)."""
    if not (np.all(period > 0) and np.all(np.isfinite(period))):
        return False
    for b in period.tolist():
        m = int(math.ldexp(math.frexp(b)[0], 53))  # the 53-bit significand as an integer
        if (m // (m & -m)).bit_length() > 22:  # (its odd part)
            return False
    return True


class _Modulo:
    """``np.divmod(x, period)`` of the actual and the set positions (rows 0 and 1 of one (2, n) block: one pass of
    vector operations for both) into the records' turns (int32) and modulo positions, the same bytes, mostly
    without the division: from each position's turns ``q`` of the last cycle, ``r = x - q * period``; where
    ``0 <= r < period``, ``q`` is floor(x / period) (``q * period`` is exact: short mantissas, ``|q| < 2 ** 30``;
    ``x - q * period`` is then the correctly rounded remainder, which is what divmod's fmod-and-adjust gives: fmod
    is exact, and its adjustment ``fmod + period`` rounds the same real number) and ``(q, r)`` is divmod's result
    (``r + 0.0``: its zero is +0). The other entries (a turn passed, the first cycle, NaN, -0.0) take
    ``np.divmod``. Periods that are not short (or not positive and finite) take ``np.divmod`` for all axes. The
    turns change only where ``np.divmod`` ran: a cycle without such an entry leaves the turns fields as the last
    call wrote them.

    Per cycle (no turn passed) this is six calls: ``q * period`` is kept (``base``, made again where ``np.divmod``
    ran), and ``0 <= r < period`` is one unsigned comparison of the bit patterns (for a positive finite period: a
    sign bit set (-0.0, negative, -NaN) or a NaN compares above it; the -0.0 that ``r >= 0`` let through goes to
    ``np.divmod``, whose result is the same). No remainder shown is then -0.0 (those of ``np.divmod`` never are
    for a positive period: its zero is +0), so ``r`` is copied as it is (``r + 0.0`` gives the same bytes)."""

    def __init__(self, n: int) -> None:
        self.q = np.full((2, n), np.nan)  # the turns of the last cycle as floats (NaN: unknown or too large)
        self._base = np.full((2, n), np.nan)  # q * period (NaN where q is)
        self._x = np.empty((2, n))
        self._turns = np.empty((2, n))
        self._r = np.empty((2, n))
        self._r01 = (self._r[0], self._r[1])
        self._r_bits = self._r.view(np.uint64)
        self._ok = np.empty((2, n), dtype=bool)
        self._key = b""
        self._short = False
        self._period2 = np.ones((2, n))  # the periods of the key, twice
        self._period_bits = self._period2.view(np.uint64)
        self._turns_shown = False  # the turns fields hold ``q`` (written by the last call, from this ``q``)

    def __call__(self, act: np.ndarray, set_pos: np.ndarray, period: np.ndarray, act_turns: np.ndarray,
                 act_mod: np.ndarray, set_turns: np.ndarray, set_mod: np.ndarray) -> None:
        key = period.tobytes()
        if key != self._key:
            self._key, self._short = key, _short_mantissas(period)
            self.q[...] = np.nan
            self._base[...] = np.nan
            self._period2 = np.stack((period, period))  # (same shape as q: no broadcasting per cycle)
            self._period_bits = self._period2.view(np.uint64)
        if not self._short:
            np.divmod(act, period, out=(act_turns, act_mod), casting="unsafe")
            np.divmod(set_pos, period, out=(set_turns, set_mod), casting="unsafe")
            self._turns_shown = False
            return
        q, r, ok, x, base = self.q, self._r, self._ok, self._x, self._base
        r0, r1 = self._r01
        np.subtract(act, base[0], out=r0)  # (x - q * period, row by row: no stacked copy of the positions)
        np.subtract(set_pos, base[1], out=r1)
        np.less(self._r_bits, self._period_bits, out=ok)  # 0 <= r < period, -0.0 excluded
        if count_nonzero(ok) < ok.size:
            x[0] = act
            x[1] = set_pos
            bad = (~ok).nonzero()
            qd, rd = np.divmod(x[bad], period[bad[1]])
            src = self._turns
            src[...] = q
            src[bad] = qd
            q[bad] = np.where(np.abs(qd) < 2.0 ** 30, qd, np.nan)
            np.multiply(q, self._period2, out=base)
            r[bad] = rd
            self._turns_shown = False  # (written below; shown as ``q`` where |turns| < 2 ** 30 only)
        elif not self._turns_shown:
            src = q
            self._turns_shown = True
        else:
            src = None  # (no turn passed: the turns fields stay)
        act_mod[...] = r0  # (= r + 0.0: no r is -0.0, see the class docstring)
        set_mod[...] = r1
        if src is not None:
            np.copyto(act_turns, src[0], casting="unsafe")
            np.copyto(set_turns, src[1], casting="unsafe")


class NctoplcPacker:
    """The NCTOPLC_AXIS_REF fields the cycle writes, as views of ``nctoplc`` (a field lookup per
    write costs more than the copy)."""

    def __init__(self, nctoplc: np.ndarray) -> None:
        n = len(nctoplc)
        self.nctoplc = nctoplc
        assert NCTOPLC_DTYPE.names is not None and NCTOPLC_DTYPE.fields is not None  # (a structured dtype)
        self.out = {name: nctoplc[name] for name in NCTOPLC_DTYPE.names}
        # (one 1-D copy per field: a transposed copy into several adjacent fields costs more than the copies apart)
        self._sp_out = (self.out["SetPos"], self.out["SetVelo"], self.out["SetAcc"], self.out["SetJerk"])
        self._torque_out = tuple(self.out[k] for k in ("SetTorque", "ActTorque", "ActTorqueDerivative",
                                                       "SetTorqueDerivative", "AbsPhasingPos", "TorqueOffset"))
        self._torque_src: np.ndarray | None = None  # the drive's torque fields (6, n) whose rows are in _torque_rows
        self._torque_rows: tuple[np.ndarray, ...] = ()
        self._torque_out12 = self._torque_out[1:3]  # (ActTorque, ActTorqueDerivative)
        self._torque_ver: int | None = None  # the Mechanics.set_version of the rows copied last (None: unknown)
        self._mod = _Modulo(n)
        self._axis_state_key = b""  # (AxisState changes on events only: written when its bytes changed)
        self._sdw3_src: np.ndarray | None = None  # (the drive's probe input array written last)
        # StateDWord from its inputs, SetVelo/SetAcc/SetJerk from theirs (the same while the axes move steadily):
        # written when an input changed (the event words: other arrays after every derive; the rest: their bytes)
        self._sd_words: tuple[np.ndarray | None, np.ndarray | None] = (None, None)
        self._sd_key: tuple[bytes, ...] = ()
        self._dyn_key = b""

    def fill(self, core: Any, event_dw: np.ndarray, loop_dw: np.ndarray) -> None:
        """This cycle's values from the axis table, the drive and the set-point words of ``core``
        (``event_dw``, ``loop_dw``: NcCore's words of its last derive, new arrays on every derive)."""
        a, d, o = core.axes, core.drive, self.out
        act = core.act_pos
        sd_key = (core.sp_dw.tobytes(), a.enabled.tobytes(), d.ready.tobytes(), d.following.tobytes(),
                  b"" if a.mon_clear else a.mon_dw.tobytes())
        words = self._sd_words
        if sd_key != self._sd_key or event_dw is not words[0] or loop_dw is not words[1]:
            sd = event_dw | core.sp_dw
            if not a.mon_clear:  # (all 0 otherwise)
                sd |= a.mon_dw
            sd |= (a.enabled & d.ready & d.following) * loop_dw  # (MC_Power.Status: the drive follows)
            o["StateDWord"][...] = sd
            self._sd_key, self._sd_words = sd_key, (event_dw, loop_dw)
        key = core.axis_state.tobytes()
        if key != self._axis_state_key:
            o["AxisState"][...] = core.axis_state
            self._axis_state_key = key
        o["ActPos"][...] = act
        o["ActVelo"][...] = d.act_velo
        torque = d.torque_fields()
        if torque is not None:  # (None: all 0 and shown so already)
            m = getattr(d, "mechanics", None)  # (a drive's Mechanics counts its writes of rows 0, 3, 4, 5)
            ver = m.set_version if m is not None and m.fields is torque else None
            if torque is not self._torque_src or ver is None or ver != self._torque_ver:
                if torque is not self._torque_src:
                    self._torque_src, self._torque_rows = torque, tuple(torque)
                for dst, src in zip(self._torque_out, self._torque_rows):
                    dst[...] = src
                self._torque_ver = ver
            else:  # (rows 0, 3, 4, 5 as copied last: unchanged since)
                o1, o2 = self._torque_out12
                rows = self._torque_rows
                o1[...] = rows[1]
                o2[...] = rows[2]
        o["ActAcc"][...] = d.act_acc
        np.subtract(core.pos_ref, act, out=o["PosDiff"])  # (with a dead time: the delayed set position)
        sp_pos, sp_velo, sp_acc, sp_jerk = self._sp_out
        sp_pos[...] = a.set_pos
        key = a.S[1:].tobytes()  # (SetVelo, SetAcc, SetJerk)
        if key != self._dyn_key:
            sp_velo[...] = a.set_velo
            sp_acc[...] = a.set_acc
            sp_jerk[...] = a.set_jerk
            self._dyn_key = key
        if count_nonzero(a.continuous):
            np.copyto(a.target_pos, a.set_pos, where=a.continuous)  # endless motion: the target moves with the axis
            o["TargetPos"][...] = a.target_pos
        self._mod(act, a.set_pos, a.modulo_factor, o["ModuloActTurns"], o["ModuloActPos"], o["ModuloSetTurns"],
                  o["ModuloSetPos"])  # divmod: // and %
        corr = core.corrections  # (ActPos less the filtered PLCTONC.PositionCorrection)
        o["ActPosWithoutPosCorrection"][...] = act - corr.pc if corr.any_pc else act
        pi = d.probe_input()
        if pi is not self._sdw3_src:  # (a drive that found its input unchanged hands out the same array)
            o["StateDWord3"][...] = pi  # bit 0: TouchProbe1InputState
            self._sdw3_src = pi
        o["DcTimeStamp"].fill(core.nc_time_ns & 0xFFFFFFFF)  # (a scalar: fill costs less than a broadcast)
