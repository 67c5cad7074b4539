"""The simulated stepper terminal (KL2531/KL2541, MC_PowerStepper): one model for ``SimDrive`` and ``cia402-sim``.

A ``SimStepper`` axis's motor sits on a simulated terminal whose status byte and word the drive reports
(NCJOBS DriveStatus: bits 0-7 the status byte, 8-23 the status word, 31 set where there is one). It can be made
to stall on demand (NC command SimStall): a stalled motor loses its field synchronism, so its actual position
stays where it is (the set-point runs away: a growing following error) and the status byte shows LoadAngle 7,
until the stall is lifted or the set velocity is 0 (at rest the motor latches in again and the position
controller brings it to the set position). Terminal errors (status word bits, SimTerminalError) set the status
byte's Error bit; Ready is the controller enable without an error, Idle a set velocity 0.

It may import: numpy, nc_server.core.params.
"""
from __future__ import annotations

import numpy as np

from ..core.params import AxisParams

EPS_V = 1e-9  # [u/s]: a set velocity at most this is "at rest"
# the simulated terminal's status byte (schema/params.json stepper_terminal)
_SB_READY, _SB_IDLE, _SB_ERROR = np.uint32(1), np.uint32(1 << 4), np.uint32(1 << 6)
_LOAD_ANGLE_MAX = np.uint32(7)
_PRESENT = np.uint32(1 << 31)


class StepperTerminals:
    """The terminals of ``n`` axes (columns; only ``SimStepper`` axes have one).

    Attributes:
        stepper: per axis, SimStepper.
        stalled: per axis, the motor is stalled (stands whatever the set-point).
        any: some axis is a SimStepper (a plain bool: the cycle checks it every step).
        status: the DriveStatus of the last :meth:`update`.
    """

    def __init__(self, n: int) -> None:
        self.stepper = np.zeros(n, dtype=bool)
        self.stalled = np.zeros(n, dtype=bool)
        self.status_word = np.zeros(n, dtype=np.uint32)  # the terminal's error bits (status word)
        self.status = np.zeros(n, dtype=np.uint32)
        self.any = False

    def configure(self, index: int, params: AxisParams) -> None:
        self.stepper[index] = bool(getattr(params, "SimStepper", False))
        if not self.stepper[index]:
            self.stalled[index] = False
            self.status_word[index] = 0
            self.status[index] = 0
        self.any = bool(self.stepper.any())

    def update(self, enabled: np.ndarray, set_velo: np.ndarray) -> None:
        """One cycle's set velocity: at rest a stalled motor latches in again; the status of this cycle."""
        self.stalled &= np.abs(set_velo) > EPS_V
        err = self.status_word != 0
        sb = ((np.asarray(enabled, dtype=bool) & ~err).astype(np.uint32) * _SB_READY
              | self.stalled.astype(np.uint32) * (_LOAD_ANGLE_MAX << 1)
              | (np.abs(set_velo) <= EPS_V).astype(np.uint32) * _SB_IDLE
              | err.astype(np.uint32) * _SB_ERROR)
        self.status = np.where(self.stepper, sb | (self.status_word << 8) | _PRESENT, 0).astype(np.uint32)

    def set_stall(self, index: int, stall: bool) -> None:
        """Stall the stepper of axis ``index`` now (``stall`` False: it follows again at once).

        Raises:
            IndexError: no axis ``index``.
            NotImplementedError: the axis is not a SimStepper (the NC answers 0x4251).
        """
        self.check(index)
        self.stalled[index] = bool(stall)

    def set_terminal_error(self, index: int, status_word: int) -> None:
        """The error bits of axis ``index``'s terminal status word (0 clears them).

        Raises:
            IndexError, NotImplementedError: as :meth:`set_stall`; ValueError: outside 0..65535.
        """
        self.check(index)
        if not 0 <= int(status_word) <= 0xFFFF:
            raise ValueError(f"status word must be in 0..65535, got {status_word}")
        self.status_word[index] = int(status_word)

    def check(self, index: int) -> None:
        if not 0 <= int(index) < len(self.stepper):
            raise IndexError(f"no axis index {index}")
        if not self.stepper[index]:
            raise NotImplementedError(f"axis index {index} is not a simulated stepper (SimStepper = false)")
