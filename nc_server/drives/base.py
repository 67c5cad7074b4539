"""The drive (hardware) interface of the NC: what a real drive must implement.

A drive serves all axes of one NC at once, column-wise (numpy arrays indexed like
``NcCore.axis_ids``), so a cycle costs a few vector operations however many axes
there are. Positions in axis units, velocities in units/s, accelerations in units/s^2.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Sequence

import numpy as np

from ..core.params import AxisParams


class DriveABC(ABC):
    """A set of drives, one per axis.

    Attributes:
        act_pos: actual positions [u], updated by :meth:`step`.
        act_velo: actual velocities [u/s].
        act_acc: actual accelerations [u/s^2].
        ready: drive ready to be enabled (False: the NC refuses starts with 0x4225).
        simulated: True for simulated drives (OpModeDWord.OpModeSimulationAxis).
    """

    simulated: bool = False

    def __init__(self, params: Sequence[AxisParams], cycle_time: float) -> None:
        n = len(params)
        self.cycle_time = float(cycle_time)
        self.act_pos = np.zeros(n)
        self.act_velo = np.zeros(n)
        self.act_acc = np.zeros(n)
        self.ready = np.ones(n, dtype=bool)

    @abstractmethod
    def configure(self, index: int, params: AxisParams) -> None:
        """Apply (changed) parameters of one axis."""

    @abstractmethod
    def step(self, enabled: np.ndarray, set_pos: np.ndarray, set_velo: np.ndarray, set_acc: np.ndarray) -> None:
        """Advance one NC cycle: command the set-points, read back the actual values.

        Args:
            enabled: controller enable per axis (False: drive disabled, holds).
            set_pos, set_velo, set_acc: set-points of this cycle.
        """

    def latch_sync_pulse(self, rows: np.ndarray, prev_pos: np.ndarray) -> np.ndarray:
        """The encoder's sync (zero) pulse latch, for homing.

        Args:
            rows: axes whose latch is armed.
            prev_pos: their actual positions of the previous cycle [u].

        Returns:
            per row the exact position [u] of a sync pulse passed between ``prev_pos`` and the
            current actual position, NaN where none was passed (default: no latch, all NaN).
        """
        return np.full(len(rows), np.nan)

    def close(self) -> None:
        """Release the hardware (no-op for simulations)."""
