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
        for i, p in enumerate(params):
            self.configure(i, p)

    def configure(self, index: int, params: AxisParams) -> None:
        t = params.SimTimeConstant
        self._alpha[index] = 1.0 if t <= 0 else 1.0 - math.exp(-self.cycle_time / t)

    def step(self, enabled: np.ndarray, set_pos: np.ndarray, set_velo: np.ndarray, set_acc: np.ndarray) -> None:
        dt = self.cycle_time
        new_pos = self.act_pos + (self._alpha * enabled) * (set_pos - self.act_pos)  # disabled: hold
        new_velo = (new_pos - self.act_pos) / dt
        self.act_acc = (new_velo - self.act_velo) / dt
        self.act_velo = new_velo
        self.act_pos = new_pos
