"""Struct-of-arrays state of all axes of one NC.

Every per-cycle quantity is a numpy column indexed like ``NcCore.axis_ids``, so a
cycle is a fixed number of vector operations regardless of the axis count. Axis
parameters live in :class:`AxisParams` objects (the source of truth) and are
mirrored into columns by :meth:`AxisTable.load_params`.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from nc_schema import OpModeDWord, StateDWord

from .params import AxisParams
from .profile import N_SEGMENTS

#: packs 8 bool bytes (viewed as one little-endian uint64) into one byte: byte b (0/1) lands on bit
#: 56 + b of the product, no two partial products overlap or carry; then shift right by PACK_SHIFT
PACK_BYTES = np.uint64(0x0102040810204080)
PACK_SHIFT = np.uint64(56)
#: the event-driven StateDWord flags: the columns of ``AxisTable.events``, in this order
EVENT_FLAGS = (("homed", StateDWord.Homed), ("stopped", StateDWord.HasBeenStopped), ("has_job", StateDWord.HasJob),
               ("homing", StateDWord.HomingBusy), ("amended", StateDWord.NewTargetPos),
               ("continuous", StateDWord.ContinuousMotion), ("buffered", StateDWord.CmdBuffered),
               ("locked", StateDWord.MotionCommandsLocked))
#: StateDWord of a packed events byte (PTPmode always: every axis is a PTP axis)
_EVENT_LUT = np.array([int(StateDWord.PTPmode) | sum(int(f) for b, (_, f) in enumerate(EVENT_FLAGS) if k >> b & 1)
                       for k in range(256)], dtype=np.uint32)
_ERROR = np.uint32(int(StateDWord.Error))
assert [name for name, _ in EVENT_FLAGS] == ["homed", "stopped", "has_job", "homing", "amended", "continuous",
                                             "buffered", "locked"]  # AxisTable.__init__ unpacks them so


class AxisTable:
    """All per-axis state, column-wise."""

    # the columns __init__ unpacks from a matrix (rows of ``S``, columns of ``events``): declared, as
    # iterating an array is untyped
    set_pos: np.ndarray
    set_velo: np.ndarray
    set_acc: np.ndarray
    set_jerk: np.ndarray
    homed: np.ndarray
    stopped: np.ndarray
    has_job: np.ndarray
    homing: np.ndarray
    amended: np.ndarray
    continuous: np.ndarray
    buffered: np.ndarray
    locked: np.ndarray

    def __init__(self, axis_ids: Sequence[int], params: Sequence[AxisParams]) -> None:
        n = len(axis_ids)
        self.n = n
        self.ids = np.asarray(axis_ids, dtype=np.uint32)

        def f() -> np.ndarray:
            return np.zeros(n)

        def b() -> np.ndarray:
            return np.zeros(n, dtype=bool)

        # parameter columns
        self.vmax, self.acc, self.dec, self.jerk = f(), f(), f(), f()
        self.en_min, self.en_max, self.min_lim, self.max_lim = b(), b(), f(), f()
        self.lag_en, self.lag_max, self.lag_filter = b(), f(), f()
        self.range_en, self.range_win = b(), f()
        self.target_en, self.target_win, self.target_time = b(), f(), f()
        self.peh_en, self.peh_time = b(), f()
        self.mm_en, self.mm_win, self.mm_time = b(), f(), f()  # motion monitoring (0x435D)
        self.mm_rows = np.zeros(0, dtype=np.intp)  # the axes with motion monitoring on
        self.modulo_factor = f()
        self.opmode = np.zeros(n, dtype=np.uint32)
        # set-point generator (the profile stage): set-points as rows of one matrix, so a cycle can
        # copy all four in one operation
        self.S = np.zeros((4, n))
        self.set_pos, self.set_velo, self.set_acc, self.set_jerk = self.S
        self.seg = np.zeros((5, n, N_SEGMENTS))
        self.seg[0] = np.inf
        self.traj_t, self.traj_dur = f(), f()
        self.traj_on = b()           # the generator follows a plan
        self.origin = f()            # shift of the running plan since it was planned (SetActualPositionOnTheFly)
        self.offset = f()            # NC position - drive position (MC_SetActualPosition)
        # event-driven StateDWord flags: the columns of one (n, 8) bool matrix (packed in one
        # operation, AxisTable.event_dwords), in the order of EVENT_FLAGS. has_job (a numbered job
        # runs), homing, amended, continuous and buffered are mirrored from the job queues on events
        # (NcCore._sync); locked: MC_Stop active
        self.events = np.zeros((n, 8), dtype=bool)
        (self.homed, self.stopped, self.has_job, self.homing, self.amended, self.continuous, self.buffered,
         self.locked) = self.events.T
        # mirrored from the job queues on events (NcCore._sync)
        self.hold_enable = b()       # the running job keeps the drive enabled (fault ramp)
        self.driving = b()           # the running job is checked against the feed enables
        self.held = b()              # the running job waits at override 0
        self.sp_row = np.zeros(n, dtype=np.intp)  # set-point flag bits of the row: 1 held, 2 a job runs, not held
        self.watch_kind = np.full(n, -1, dtype=np.int16)  # job kind whose watch() sees this row, -1: none
        self.homing_state = np.zeros(n, dtype=np.uint32)
        self.cmd_no = np.zeros(n, dtype=np.uint16)
        self.cmd_state = np.zeros(n, dtype=np.uint16)
        self.target_pos = f()
        # axis state
        self.error = np.zeros(n, dtype=np.uint32)
        self.enabled = b()           # controller enable in effect last cycle
        self.override = np.ones(n)   # applied override 0..1
        # monitoring
        self.lag_timer = f()
        self.window_timer = f()
        self.since_end = np.full(n, -1.0)  # s since the logical end of a position job; -1: not watching
        self.changed: list[int] = []  # rows whose plan changed since the profile stage last looked
        self.in_target, self.in_area = b(), b()
        self.mm_anchor, self.mm_timer = f(), f()  # motion monitoring: where the current window began, since when
        self.mon_dw = np.zeros(n, dtype=np.uint32)  # StateDWord bits from monitoring (windows, soft limits)
        # what monitoring knows without looking (each array is written elsewhere only to its resting value,
        # so a cycle need not look again until monitoring itself changes it): no lag timer runs, no window
        # flag is set, no row watches a job's end (engine: since_end >= 0 sets end_watch)
        self.lag_clear = self.windows_clear = True
        self.mon_clear = True  # mon_dw is all 0 (False where monitoring or the drive monitor may have set bits)
        self.end_watch = False
        for i, p in enumerate(params):
            self.load_params(i, p)
            self.homed[i] = p.Homed

    def event_dwords(self, err: np.ndarray) -> np.ndarray:
        """The event-driven StateDWord bits of every axis (``err``: its error != 0)."""
        code = self.events.view(np.uint64)[:, 0] * PACK_BYTES
        code >>= PACK_SHIFT
        dw: np.ndarray = _EVENT_LUT[code]
        dw |= err * _ERROR
        return dw

    def load_params(self, i: int, p: AxisParams) -> None:
        """Mirror one axis's parameters into the columns."""
        self.vmax[i], self.acc[i], self.dec[i], self.jerk[i] = p.AxisVeloMax, p.AxisAcc, p.AxisDec, p.AxisJerk
        self.en_min[i], self.min_lim[i] = p.AxisEnMinSoftPosLimit, p.AxisMinSoftPosLimit
        self.en_max[i], self.max_lim[i] = p.AxisEnMaxSoftPosLimit, p.AxisMaxSoftPosLimit
        self.lag_en[i], self.lag_max[i], self.lag_filter[i] = (
            p.AxisEnPositionLagMonitoring, p.AxisMaxPosLagValue, p.AxisMaxPosLagFilterTime)
        self.range_en[i], self.range_win[i] = p.AxisEnPositionRangeMonitoring, p.AxisPositionRangeWindow
        self.target_en[i], self.target_win[i], self.target_time[i] = (
            p.AxisEnTargetPositionMonitoring, p.AxisTargetPositionWindow, p.AxisTargetPositionMonitoringTime)
        self.peh_en[i], self.peh_time[i] = p.AxisEnInTargetTimeout, p.AxisInTargetTimeout
        if p.AxisEnMotionMonitoring and not self.mm_en[i]:
            self.mm_anchor[i] = np.nan  # (switched on: its first window starts where the axis is then)
        self.mm_en[i], self.mm_win[i], self.mm_time[i] = (
            p.AxisEnMotionMonitoring, p.AxisMotionMonitoringWindow, p.AxisMotionMonitoringTime)
        self.mm_rows = np.flatnonzero(self.mm_en)
        self.modulo_factor[i] = p.AxisEncoderModuloValue
        m = OpModeDWord(0)
        flags = [
            (p.AxisEnPositionRangeMonitoring, OpModeDWord.OpModePosAreaMonitoring),
            (p.AxisEnTargetPositionMonitoring, OpModeDWord.OpModeTargetPosMonitoring),
            (p.AxisEnMotionMonitoring, OpModeDWord.OpModeMotionMonitoring),
            (p.AxisEnInTargetTimeout, OpModeDWord.OpModePEHTimeMonitoring),
            (p.AxisEnBacklashCompensation, OpModeDWord.OpModeBacklashCompensation),
            (p.AxisEnActPosCorrection, OpModeDWord.OpModePosCorrection),
            (p.Modulo, OpModeDWord.OpModeModulo),
            (p.AxisEnPositionLagMonitoring, OpModeDWord.OpModePosLagMonitoring),
            (p.AxisEnMinSoftPosLimit, OpModeDWord.OpModeSoftLimitMinMonitoring),
            (p.AxisEnMaxSoftPosLimit, OpModeDWord.OpModeSoftLimitMaxMonitoring),
            (p.AxisAllowMotionCmdToSlave, OpModeDWord.OpModeAllowSlaveCommands),
            (p.AxisAllowMotionCmdToExtSetAxis, OpModeDWord.OpModeAllowExtSetAxisCommands),
        ]
        for on, bit in flags:
            if on:
                m |= bit
        self.opmode[i] = int(m)
