"""The drive's I/O and device state as the NC shows it (vectorized, after the drive step).

StateDWord bits (twincat-nc-reference.md 1.1):

* IoDataInvalid (bit 30): the drive's I/O data are invalid (``DriveABC.io_valid`` False; on EtherCAT a bad
  WcState). The NC reads the last valid values meanwhile.
* ErrorPropagationDelayed (bit 6, "a preliminary error warning"): invalid I/O data for 1..3 cycles in a row;
  in the 4th the axis error 0x4655 (NC_DRIVE_IO_DATA_INVALID, "invalid IO data for more than n continuous NC
  cycles") replaces it.
* DriveDeviceError (bit 28): the drive hardware reports an error (``DriveABC.device_error``: a CiA 402 drive in
  Fault / Fault reaction active, or one that left Operation enabled while the NC wanted it enabled); an enabled
  axis gets the axis error 0x4650 (NC_DRIVE_NOT_READY) at once; the drive is not ready, so a start is refused with
  0x4225 (checks.check_startable) and ControlLoopClosed/Operational are off.
* Lost communication (``DriveABC.comm_error``: heartbeat, node guarding, a remote drive's liveliness): the axis
  error 0x4651 (NC_DRIVE_CYCLIC_COMM_ERROR, TwinCAT's "cyclic communication error"), enabled or not, before a
  device error of the same axis (the drive's state is unknown while it does not answer).

Decisions (Beckhoff leaves n open): n = 3 cycles (:data:`DELAY_CYCLES`); the I/O and communication errors are
raised on a disabled axis too (the encoder's data are invalid whatever the controller does); after MC_Reset either error comes back
in the next cycle while its condition lasts (the error describes the drive, not an event). The monitor costs
one flag check per cycle while no drive is faulty and none was in the last cycle.

It may import: numpy, nc_schema.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from nc_schema import ErrorCodes, StateDWord

#: cycles of invalid I/O data shown as ErrorPropagationDelayed before the axis error 0x4655
DELAY_CYCLES = 3
_IO_INVALID = np.uint32(int(StateDWord.IoDataInvalid))
_DELAYED = np.uint32(int(StateDWord.ErrorPropagationDelayed))
_DEVICE = np.uint32(int(StateDWord.DriveDeviceError))


class DriveMonitor:
    """The drive state bits of every axis and the errors they raise.

    Attributes:
        invalid_cycles: cycles in a row with invalid I/O data, per axis.
        dw: the StateDWord bits of the last run (IoDataInvalid, ErrorPropagationDelayed, DriveDeviceError).
        active: some bit is set (the NC ORs ``dw`` into StateDWord only then).
    """

    def __init__(self, n: int) -> None:
        self.invalid_cycles = np.zeros(n, dtype=np.int64)
        self.dw = np.zeros(n, dtype=np.uint32)
        self.active = False

    def run(self, drive: Any, enabled: np.ndarray, error: np.ndarray) -> list[tuple[int, int]]:
        """Update the bits from ``drive`` (a DriveABC); return the new axis errors (row, code).

        Args:
            enabled: the controller enable per axis; error: the axes' error codes (0: none).
        """
        if not drive.faulty:
            if self.active:  # the last fault has gone: the bits and the count go back to 0
                self.active = False
                self.dw[:] = 0
                self.invalid_cycles[:] = 0
            return []
        bad = ~drive.io_valid
        device = drive.device_error
        self.invalid_cycles += 1
        self.invalid_cycles *= bad
        over = self.invalid_cycles > DELAY_CYCLES
        dw = bad * _IO_INVALID
        dw |= (bad & ~over) * _DELAYED
        dw |= device * _DEVICE
        self.dw = dw
        self.active = True
        free = (error == 0) & ~over
        faults = [(int(i), int(ErrorCodes.NC_DRIVE_IO_DATA_INVALID)) for i in np.flatnonzero(over & (error == 0))]
        comm = drive.comm_error
        if comm.any():
            faults += [(int(i), int(ErrorCodes.NC_DRIVE_CYCLIC_COMM_ERROR)) for i in np.flatnonzero(comm & free)]
            free &= ~comm
        faults += [(int(i), int(ErrorCodes.NC_DRIVE_NOT_READY)) for i in np.flatnonzero(device & enabled & free)]
        return faults
