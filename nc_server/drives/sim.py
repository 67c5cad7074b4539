"""Simulated drives: a first-order position lag, stepped with the NC's fixed cycle time.

The lag makes PosDiff realistic (about velocity x SimTimeConstant at constant
velocity). Because the simulation advances by exactly one cycle_time per NC cycle
(never by wall-clock time), a stalled process cannot produce a following error.
A disabled drive holds its position (think: brake).
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from ..core.params import AxisParams
from .base import DriveABC


class SimDrive(DriveABC):
    simulated = True

    def __init__(self, params: Sequence[AxisParams], cycle_time: float) -> None:
        super().__init__(params, cycle_time)
        self._alpha = np.ones(len(params))
        self._pulse_spacing = np.ones(len(params))
        self._pulse_offset = np.zeros(len(params))
        for i, p in enumerate(params):
            self.configure(i, p)

    def configure(self, index: int, params: AxisParams) -> None:
        t = params.SimTimeConstant
        self._alpha[index] = 1.0 if t <= 0 else 1.0 - math.exp(-self.cycle_time / t)
        self._pulse_spacing[index] = getattr(params, "SimSyncPulseSpacing", 1.0)
        self._pulse_offset[index] = getattr(params, "SimSyncPulseOffset", 0.0)

    def latch_sync_pulse(self, rows: np.ndarray, prev_pos: np.ndarray) -> np.ndarray:
        """Sync pulses at SimSyncPulseOffset + k * SimSyncPulseSpacing: the latch reports the exact
        pulse position (the interpolated crossing within the cycle, not the cycle's position)."""
        sp, off = self._pulse_spacing[rows], self._pulse_offset[rows]
        a, b = (prev_pos - off) / sp, (self.act_pos[rows] - off) / sp
        up = b > a
        k = np.where(up, np.floor(b), np.ceil(b))  # the last pulse index reached in the direction of travel
        crossed = np.where(up, k > np.floor(a) + 0 * a, k < np.ceil(a)) & (a != b)
        crossed &= np.where(up, k > a, k < a)
        return np.where(crossed, off + k * sp, np.nan)

    def step(self, enabled: np.ndarray, set_pos: np.ndarray, set_velo: np.ndarray, set_acc: np.ndarray) -> None:
        dt = self.cycle_time
        new_pos = self.act_pos + (self._alpha * enabled) * (set_pos - self.act_pos)  # disabled: hold
        new_velo = (new_pos - self.act_pos) / dt
        self.act_acc = (new_velo - self.act_velo) / dt
        self.act_velo = new_velo
        self.act_pos = new_pos
