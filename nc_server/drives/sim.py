"""Simulated drives: a first-order position lag, stepped with the NC's fixed cycle time.

The lag makes PosDiff realistic (about velocity x SimTimeConstant at constant
velocity). Because the simulation advances by exactly one cycle_time per NC cycle
(never by wall-clock time), a stalled process cannot produce a following error.
A disabled drive holds its position (think: brake).

Touch probe input 1 (MC_TouchProbe) is simulated in one of two ways per axis: a sensor pattern of
the drive position (SimProbePeriod > 0: TRUE while ((position - SimProbeOffset) mod SimProbePeriod)
< SimProbeWidth, e.g. marks on a conveyor), or, on axes without a pattern, levels commanded with
:meth:`SimDrive.set_probe_signal` at a given instant of the next cycle. Within a cycle the drive is
taken as moving linearly from the previous to the new actual position, so the latch reports the
exact pattern edge (or the interpolated position at a commanded instant), as a hardware latch would.

Stepper axes (``SimStepper``, for MC_PowerStepper): the motor sits on a simulated KL2531/KL2541 terminal
(:mod:`.stepper`, shared with ``cia402-sim``) whose status byte and word the drive reports
(:meth:`SimDrive.terminal_status`, NCJOBS DriveStatus); it can be made to stall on demand
(:meth:`SimDrive.set_stall`, NC command SimStall: the motor stands, the set-point runs away) and given terminal
errors (:meth:`SimDrive.set_terminal_error`).

Encoder (:mod:`.encoder`): the position the drive reports goes through the encoder chain of
AxisEncoderScalingFactor, AxisEncoderOffset, AxisEncoderDirectionInverse and AxisEncoderEncoderMask; changing
one moves the reported position, not the motor. Mechanics (:mod:`.mechanics`): the torque fields of NCTOPLC.
The sensor pattern and the sync pulses are positions as the encoder reports them (the drive position).

Injectable drive states (for tests and simulations; no wire command sets them yet): :meth:`SimDrive.set_io_invalid`
(the drive's I/O data invalid: the NC reads the last valid values, the motor gets no new set-points and holds),
:meth:`SimDrive.set_device_error` (a drive hardware error: not ready, no torque, the motor holds).
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from ..core.params import AxisParams
from .base import DriveABC
from .encoder import EncoderChain, pulse_passed
from .mechanics import Mechanics
from .npcount import count_nonzero
from .probe_pattern import check_probe_signal, first_pattern_edge, pattern_level, signal_edges
from .stepper import StepperTerminals


class SimDrive(DriveABC):
    simulated = True

    def __init__(self, params: Sequence[AxisParams], cycle_time: float) -> None:
        super().__init__(params, cycle_time)
        n = len(params)
        self._alpha = np.ones(n)
        self._pulse_spacing = np.ones(n)
        self._pulse_offset = np.zeros(n)
        self._probe_period = np.zeros(n)
        self._probe_offset = np.zeros(n)
        self._probe_width = np.zeros(n)
        self._probe_rows = np.zeros(0, dtype=np.intp)  # the axes with a sensor pattern
        self._probe_level = np.zeros(n, dtype=bool)  # the commanded input of the axes without one
        #: set_probe_signal events for the next step: axis -> [(offset [s], level)]
        self._probe_pending: dict[int, list[tuple[float, bool]]] = {}
        #: the commanded edges of the cycle just stepped: axis -> [(fraction, new level)], in time order
        self._probe_edges: dict[int, list[tuple[float, bool]]] = {}
        self.terminals = StepperTerminals(n)  # the SimStepper axes' terminals
        self.encoder = EncoderChain(n)
        self.mechanics = Mechanics(n, cycle_time)
        for i, p in enumerate(params):
            self.configure(i, p)

    def configure(self, index: int, params: AxisParams) -> None:
        self.mechanics.configure(index, params)
        pos = float(self.act_pos[index])
        new = self.encoder.configure(index, params, pos)
        if new != pos:  # the same increments read through another chain: the position jumps, the motor stands
            self.act_pos = self.act_pos.copy()  # (the NC may hold this array: it compares before and after)
            self.act_pos[index] = new
        t = params.SimTimeConstant
        self._alpha[index] = 1.0 if t <= 0 else 1.0 - math.exp(-self.cycle_time / t)
        self._pulse_spacing[index] = getattr(params, "SimSyncPulseSpacing", 1.0)
        self._pulse_offset[index] = getattr(params, "SimSyncPulseOffset", 0.0)
        period = float(getattr(params, "SimProbePeriod", 0.0))
        self._probe_period[index] = period
        self._probe_offset[index] = getattr(params, "SimProbeOffset", 0.0)
        self._probe_width[index] = getattr(params, "SimProbeWidth", 0.0)
        if period > 0:  # the pattern decides the level from now on: commanded signals are dropped
            self._probe_level[index] = False
            self._probe_pending.pop(index, None)
            self._probe_edges.pop(index, None)
        self._probe_rows = np.flatnonzero(self._probe_period > 0)
        self.terminals.configure(index, params)

    def latch_sync_pulse(self, rows: np.ndarray, prev_pos: np.ndarray) -> np.ndarray:
        """Sync pulses at SimSyncPulseOffset + k * SimSyncPulseSpacing: the latch reports the exact
        pulse position (the interpolated crossing within the cycle, not the cycle's position)."""
        rows = np.asarray(rows, dtype=np.intp)
        return pulse_passed(np.asarray(prev_pos, dtype=float), self.act_pos[rows], self._pulse_spacing[rows],
                            self._pulse_offset[rows])

    def step(self, enabled: np.ndarray, set_pos: np.ndarray, set_velo: np.ndarray, set_acc: np.ndarray) -> None:
        dt = self.cycle_time
        delivering = enabled
        if self.faulty:  # a drive not ready or without valid I/O data holds (no set-point reaches it)
            delivering = enabled & self.ready & self.io_valid
        act = self.act_pos
        # act + (alpha * delivering) * (set_pos - act) (disabled: hold) in one new array: the same operations (+ and *
        # commute bit for bit); every axis delivering: alpha * 1.0 is alpha
        new_pos = np.subtract(set_pos, act, dtype=float)
        new_pos *= self._alpha if count_nonzero(delivering) == len(act) else self._alpha * delivering
        new_pos += act
        if self.terminals.any:
            t = self.terminals
            t.update(enabled, set_velo)  # (at rest the motor latches in again)
            if t.stalled.any():
                new_pos = np.where(t.stalled, self.act_pos, new_pos)  # a stalled motor stands
        new_velo = np.subtract(new_pos, act)
        new_velo /= dt
        new_acc = np.subtract(new_velo, self.act_velo)
        new_acc /= dt
        if self.faulty:  # invalid I/O data: the NC reads the last valid values
            stale = ~self.io_valid
            new_velo[stale] = self.act_velo[stale]
            new_acc[stale] = self.act_acc[stale]
        self.act_acc = new_acc
        self.act_velo = new_velo
        self.act_pos = new_pos
        self.mechanics.step(delivering, set_velo, set_acc, new_velo, new_acc)
        if self._probe_pending or self._probe_edges:  # no work at all without commanded probe signals
            self._probe_edges = self._apply_probe_signals()

    # -- torque, encoder, injectable drive states ------------------------------------------------------------

    def set_torque_offset(self, values: np.ndarray) -> None:
        """PLCTONC.ExtTorque [%]: non-finite values keep the last value, |value| clipped to 1000 %
        (:meth:`.mechanics.Mechanics.set_offset`)."""
        self.mechanics.set_offset(np.asarray(values, dtype=float))

    def torque_fields(self) -> np.ndarray | None:
        """The mechanics' torque fields (:class:`.mechanics.Mechanics`); None while it rests (all 0 shown)."""
        return None if self.mechanics.resting else self.mechanics.fields

    def encoder_count(self, index: int) -> float:
        """The hardware counter of axis ``index``'s encoder: increments & mask [inc] (not rounded)."""
        return self.encoder.hardware_count(index, float(self.act_pos[index]))

    def set_io_invalid(self, index: int, invalid: bool) -> None:
        """Axis ``index``'s I/O data become invalid (``invalid`` False: valid again) from the next step: the
        reported values stay the last valid ones and the motor holds (no set-point reaches it)."""
        self._check_index(index)
        self.io_valid[index] = not invalid
        self._faults_changed()

    def set_device_error(self, index: int, error: bool) -> None:
        """Axis ``index``'s drive hardware reports an error (``error`` False: it is gone): the drive is not
        ready, delivers no torque and holds."""
        self._check_index(index)
        self.device_error[index] = bool(error)
        self.ready[index] = not error
        self._faults_changed()

    def _faults_changed(self) -> None:
        self.faulty = bool(np.count_nonzero(~self.io_valid) or np.count_nonzero(self.device_error))

    def _check_index(self, index: int) -> None:
        if not 0 <= int(index) < len(self.act_pos):
            raise IndexError(f"no axis index {index}")

    # -- stepper terminal ----------------------------------------------------------------------------------

    def terminal_status(self) -> np.ndarray | None:
        """NCJOBS DriveStatus of every axis (:mod:`.stepper`); None without SimStepper axes."""
        return self.terminals.status if self.terminals.any else None

    def set_stall(self, index: int, stall: bool) -> None:
        """Stall the stepper of axis ``index`` now (:meth:`.stepper.StepperTerminals.set_stall`)."""
        self.terminals.set_stall(index, stall)

    def set_terminal_error(self, index: int, status_word: int) -> None:
        """The error bits of axis ``index``'s terminal status word (:meth:`.stepper.StepperTerminals.set_terminal_error`)."""
        self.terminals.set_terminal_error(index, status_word)

    # -- touch probe ---------------------------------------------------------------------------------------

    def probe_input(self) -> np.ndarray:
        """Input 1 per axis: the sensor pattern at the actual position, else the commanded level."""
        level = self._probe_level.copy()
        r = self._probe_rows
        if len(r):
            level[r] = pattern_level(self.act_pos[r], self._probe_period[r], self._probe_offset[r],
                                     self._probe_width[r])
        return level

    def set_probe_signal(self, index: int, level: bool, offset: float) -> None:
        """Command input 1 of an axis without a sensor pattern (SimProbePeriod == 0).

        Several calls before one step make several events in that cycle; a second call for the same
        offset replaces the first. The commanded level persists until changed.

        Raises:
            IndexError: no axis ``index``.
            NotImplementedError: the axis has a sensor pattern (SimProbePeriod > 0), which alone
                decides its input (the NC answers 0x4251).
            ValueError: offset outside 0 <= offset < cycle_time [s].
        """
        index = int(index)
        if not 0 <= index < len(self.act_pos):
            raise IndexError(f"no axis index {index}")
        offset = check_probe_signal(index, float(self._probe_period[index]), offset, self.cycle_time)
        events = self._probe_pending.setdefault(index, [])
        events[:] = [e for e in events if e[0] != offset]
        events.append((offset, bool(level)))

    def latch_probe(self, rows: np.ndarray, falling: np.ndarray,
                    prev_pos: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The first edge of the requested kind in the cycle just stepped: a pattern edge at its exact
        position, a commanded one at prev_pos + fraction * (act_pos - prev_pos)."""
        rows = np.asarray(rows, dtype=np.intp)
        falling = np.asarray(falling, dtype=bool)
        a = np.asarray(prev_pos, dtype=float)
        b = self.act_pos[rows]
        m = len(rows)
        found, pos, frac = np.zeros(m, dtype=bool), np.full(m, np.nan), np.full(m, np.nan)
        # the sensor pattern has edges only for 0 < width < period, and only while the axis moves
        period, width = self._probe_period[rows], self._probe_width[rows]
        k = np.flatnonzero((width > 0) & (width < period) & (a != b))
        if len(k):
            x = self._first_pattern_edge(rows[k], falling[k], a[k], b[k])
            hit = ~np.isnan(x)
            k, x = k[hit], x[hit]
            found[k], pos[k] = True, x
            frac[k] = np.clip((x - a[k]) / (b[k] - a[k]), 0.0, 1.0)
        if self._probe_edges:  # commanded signals (axes without a pattern, so no overlap with the above)
            for j, i in enumerate(rows.tolist()):
                for f, level in self._probe_edges.get(i, ()):
                    if level != falling[j]:  # rising: to True; falling: to False
                        found[j], frac[j], pos[j] = True, f, a[j] + f * (b[j] - a[j])
                        break
        return found, pos, frac

    def _first_pattern_edge(self, rows: np.ndarray, falling: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """The first pattern edge of the requested kind passed moving from a to b (a != b) [u], NaN if none
        (:func:`.probe_pattern.first_pattern_edge`)."""
        return first_pattern_edge(falling, a, b, self._probe_period[rows], self._probe_offset[rows],
                                  self._probe_width[rows])

    def _apply_probe_signals(self) -> dict[int, list[tuple[float, bool]]]:
        """Turn the pending set_probe_signal events into this cycle's edges; update the commanded levels."""
        edges = signal_edges(self._probe_pending, self._probe_level, self.cycle_time)
        self._probe_pending = {}
        return edges
