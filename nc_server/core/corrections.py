"""The chain between the NC's set-point and the drive, and back to the actual position: actual position
correction, backlash compensation and dead time, vectorized over the axes. While none of them is on
for any axis the cycle pays one flag check (``Corrections.active``).

Actual position correction (AxisEnActPosCorrection 1046, AxisActPosCorrectionFilterTime 1047). Infosys,
TF50x0 NC PTP "Other Settings" (https://infosys.beckhoff.com/content/1033/tf50x0_tc3_nc_ptp/3439915403.html):
"If Position Correction is enabled, [PlcToNc.PositionCorrection] adds an additional offset", filtered by
a P-T1 filter of the "Filter Time Position Correction (P-T1)"; MC_PositionCorrectionLimiter "adds the
correction value to the actual value of the axis"
(https://infosys.beckhoff.com/content/1033/tcplclib_tc2_mc2/2220092043.html). So here:
ActPos = drive position + the filtered correction, NCTOPLC.ActPosWithoutPosCorrection = ActPos without
it; the position controller closes its loop on the corrected ActPos, so the drive moves by minus the
correction (the simulated drive is the machine's uncorrected side). Decisions (the manual is silent): a
non-finite PositionCorrection is ignored (the last finite value stays the filter's input); filter time
0 = unfiltered; the filter starts from 0 when the correction is switched on, and the correction leaves
at once when it is switched off; the software limits are checked against the corrected ActPos (the page:
"this correction does not affect the software end positions": the limits themselves do not move).

Backlash compensation (AxisEnBacklashCompensation 1035, AxisBacklash 1036; TwinCAT keeps it "only for
compatibility", MC_BacklashCompensation builds on the position correction instead:
https://infosys.beckhoff.com/content/1033/tcplclib_tc2_mc2/9760638347.html). Decisions: positive is the
reference direction (at start and whenever the compensation is switched on: no correction); while the
last non-zero set velocity was negative the full AxisBacklash is added on the negative side, i.e. the
drive is commanded AxisBacklash further negative and ActPos is the drive position plus AxisBacklash
(the load's side of the play); the change comes as a step in the cycle the set velocity reverses (the
drive's own dynamics smooth it); ActPosWithoutPosCorrection includes it (it is not the PLC's position
correction).

Dead time (AxisDelayTimeVeloPosition 1032, "dead time compensation delay", TwinCAT error 0x430C):
the velocity is output at once, the position set value the controller compares with the actual
position is the set position of AxisDelayTimeVeloPosition ago (whole NC cycles, rounded; at most
0.1 s): the simulated drive follows that delayed set position and PosDiff (and the lag monitoring)
compare it with ActPos, so a drive's dead time does not show as a following error. Infosys on dead
time compensation: https://infosys.beckhoff.com/content/1033/tf50x0_tc3_nc_ptp/10650596235.html.
The history restarts (every entry := the set position) where the position moves without motion: the
controller's activation, a parameter written while disabled (the encoder parameters), and it is
shifted with MC_SetActualPosition(OnTheFly) (:meth:`Corrections.shift`), so a stale history is never
replayed. Changing the dead time (at standstill only) restarts the history too.

How: the correction value (position correction + backlash) is carried in ``axes.offset`` (NC position -
drive position, which MC_SetActualPosition already uses): each cycle its change is added there, so
every conversion between the NC's and the drive's frame (the drive step, touch probe and homing
latches) includes it without knowing about it.

It may import: numpy, nc_schema, .axes, .params.
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, Sequence

import numpy as np

from .axes import AxisTable
from .params import AxisParams

if TYPE_CHECKING:
    from .nc import NcCore

#: The longest dead time (AxisDelayTimeVeloPosition's table maximum) [s].
MAX_DEAD_TIME = 0.1
_EPS_V = 1e-9


class Corrections:
    """Position correction, backlash compensation and dead time of all axes (module docstring).

    Args:
        axes: the core's axis table (set positions, velocities, ``offset``).
        params: the axes' parameters, in row order.
        cycle_time: the NC cycle time [s].

    Attributes:
        active: any axis has one of them on, or a correction still to take off (the cycle's flag).
        pc: the filtered position correction of each axis [u] (0 where off).
        value: what ``axes.offset`` holds of the corrections (position correction + backlash) [u].
        delay: the dead time of each axis [cycles].
    """

    def __init__(self, axes: AxisTable, params: Sequence[AxisParams], cycle_time: float) -> None:
        n = axes.n
        self.axes = axes
        self.cycle_time = float(cycle_time)
        #: longest dead time in cycles (0.1 s rounded down: the table's maximum is never exceeded)
        self.max_delay = int(math.floor(MAX_DEAD_TIME / self.cycle_time + 1e-9))
        self.pc_on = np.zeros(n, dtype=bool)
        self.pc_alpha = np.ones(n)
        self.pc_in = np.zeros(n)      # PLCTONC.PositionCorrection (the last finite value)
        self.pc = np.zeros(n)
        self.bl_on = np.zeros(n, dtype=bool)
        self.bl_size = np.zeros(n)
        self.bl_neg = np.zeros(n, dtype=bool)  # the last set velocity was negative
        self.value = np.zeros(n)
        self.delay = np.zeros(n, dtype=np.intp)
        self._hist: np.ndarray | None = None  # (max_delay + 2, n) ring of set positions (the delayed one and the one before)
        self._head = 0
        self._cols = np.arange(n)
        self.any_pc = self.any_bl = self.any_dt = False
        self.active = False
        for i, p in enumerate(params):
            self.configure(i, p)

    def configure(self, i: int, p: AxisParams) -> None:
        """Take axis row ``i``'s parameters (at start and after a WriteParameter)."""
        was_pc, was_bl = bool(self.pc_on[i]), bool(self.bl_on[i])
        self.pc_on[i] = p.AxisEnActPosCorrection
        t = p.AxisActPosCorrectionFilterTime
        self.pc_alpha[i] = 1.0 if t <= 0 else 1.0 - math.exp(-self.cycle_time / t)
        if not self.pc_on[i] or not was_pc:
            self.pc[i] = 0.0  # (off: taken off at the next step; on: the filter starts from 0)
        self.bl_on[i] = p.AxisEnBacklashCompensation
        self.bl_size[i] = p.AxisBacklash
        if not self.bl_on[i] or not was_bl:
            self.bl_neg[i] = False  # positive: the reference direction
        d = min(int(round(p.AxisDelayTimeVeloPosition / self.cycle_time)), self.max_delay)
        if d != self.delay[i]:
            self.delay[i] = d
            self.any_dt = bool(np.count_nonzero(self.delay))
            if self.any_dt and self._hist is None:
                self._hist = np.repeat(self.axes.set_pos[None, :], self.max_delay + 2, axis=0)
            self.restart_history(i)
        self.any_pc = bool(np.count_nonzero(self.pc_on))
        self.any_bl = bool(np.count_nonzero(self.bl_on))
        self.active = self.any_pc or self.any_bl or self.any_dt or bool(np.count_nonzero(self.value))

    def take_input(self, correction: np.ndarray) -> None:
        """PLCTONC.PositionCorrection of every axis (on a PLCTONC change); non-finite values are ignored."""
        ok = np.isfinite(correction)
        self.pc_in[ok] = correction[ok]

    def restart_history(self, i: int, jump: float = 0.0) -> None:
        """Axis row ``i``'s position moved without motion: its dead-time history restarts at its set
        position (the delayed set position is the set position; nothing old is replayed). ``jump`` (by
        how much it moved, unused) makes it fit a position-jump hook's ``(row, jump)`` signature."""
        if self._hist is not None:
            self._hist[:, i] = self.axes.set_pos[i]

    def shift(self, i: int, diff: float) -> None:
        """The NC positions of row ``i`` moved by ``diff`` (MC_SetActualPosition(OnTheFly), homing): the
        history moves with them, so a running motion goes on unchanged."""
        if self._hist is not None:
            self._hist[:, i] += diff

    def step(self, core: NcCore) -> np.ndarray:
        """This cycle's corrections, before the drive step: the change of the correction value goes
        into ``axes.offset`` (and ``core.prev_act_pos``, the previous position in the NC frame the
        latches compare with); returns the set position the controller uses (the delayed one)."""
        a = self.axes
        ref: np.ndarray = a.set_pos
        v: np.ndarray = a.set_velo
        if self.any_dt:
            h = self._hist
            assert h is not None  # (allocated when the first dead time was configured)
            self._head = head = (self._head + 1) % h.shape[0]
            h[head] = a.set_pos
            ref = h[(head - self.delay) % h.shape[0], self._cols]
            if self.any_bl:  # (the backlash reverses with the set-point the drive follows: the delayed one)
                v = np.where(self.delay > 0,
                             (ref - h[(head - self.delay - 1) % h.shape[0], self._cols]) / self.cycle_time, v)
        new = np.zeros(a.n)
        if self.any_pc:
            pc = self.pc
            pc += self.pc_alpha * (self.pc_in - pc)
            pc *= self.pc_on
            new += pc
        if self.any_bl:
            neg = self.bl_neg
            neg |= v < -_EPS_V
            neg &= (v <= _EPS_V) & self.bl_on
            new += neg * self.bl_size
        delta = new - self.value
        if np.count_nonzero(delta):
            a.offset += delta
            core.prev_act_pos = core.prev_act_pos + delta
            self.value = new
            if not (self.any_pc or self.any_bl or self.any_dt) and not np.count_nonzero(new):
                self.active = False  # (the last correction is off)
        return ref
