"""The process data the NC maps on its CANopen CiA 402 drives, and the packing of PDO payloads.

One table per direction: PDO number -> the mapped objects ``(index, bits)`` in order, used by the master
(:mod:`.link`) to write the mapping over SDO and by the simulated slaves (:mod:`.slave`, which read their
mapping back from their own object dictionary, as a real drive does) to fill their TPDOs.

Decisions:

* RPDO1 (every cycle): controlword 0x6040, target position 0x607A, modes of operation 0x6060 (56 bits).
  RPDO2 (synchronous, sent only when its content changed: it is applied at every later SYNC until the next
  one): touch probe function 0x60B8, plus target velocity 0x60FF in CSV. In CSP no velocity feed forward is
  sent (it would cost one more frame per axis and cycle).
* TPDO1 (synchronous, every SYNC): statusword 0x6041, position actual 0x6064, error code 0x603F (64 bits);
  TPDO2 (every SYNC): velocity actual 0x606C, torque actual 0x6077, modes of operation display 0x6061;
  TPDO3 (synchronous acyclic, type 0: sent at a SYNC only when changed): touch probe status 0x60B9 and
  touch probe 1 position 0x60BA (the index pulse latch); TPDO4 (synchronous acyclic): touch probe 2 positive and
  negative edge positions 0x60BC / 0x60BD (MC_TouchProbe; 64 bits, the 4th and last TPDO of the CiA 301 default
  set; 0x60B9 in TPDO3 carries probe 2's status bits too). No SDO in the cycle: the probe's function bits travel in
  RPDO2 (0x60B8 holds both probes), its status and positions in the on-change TPDO3/TPDO4, which cost the bus
  nothing while nothing is latched. The age of a node's inputs is counted on TPDO1 and TPDO2.
* Bus load: per axis and cycle RPDO1 + TPDO1 + TPDO2 (3 frames of 7-8 bytes, about 125 bits each with
  stuffing) plus one SYNC for all: at 1 Mbit/s about 2 axes fit a 1 ms cycle, 8 axes need a 4 ms cycle
  (:func:`bus_load`). The virtual bus has no bitrate.

It may import: canopen (objectdictionary), nc_server.drives.cia402.
"""
from __future__ import annotations

import numpy as np

import struct
from typing import Sequence

from canopen import objectdictionary as od

from ..cia402 import objects as obj

#: (index, bits) of a mapped object
Entry = tuple[int, int]

RPDO1: tuple[Entry, ...] = ((obj.CONTROLWORD, 16), (obj.TARGET_POSITION, 32), (obj.MODES_OF_OPERATION, 8))
RPDO2_CSP: tuple[Entry, ...] = ((obj.TOUCH_PROBE_FUNCTION, 16),)
RPDO2_CSV: tuple[Entry, ...] = ((obj.TARGET_VELOCITY, 32), (obj.TOUCH_PROBE_FUNCTION, 16))
TPDO1: tuple[Entry, ...] = ((obj.STATUSWORD, 16), (obj.POSITION_ACTUAL, 32), (obj.ERROR_CODE, 16))
TPDO2: tuple[Entry, ...] = ((obj.VELOCITY_ACTUAL, 32), (obj.TORQUE_ACTUAL, 16),
                            (obj.MODES_OF_OPERATION_DISPLAY, 8))
TPDO3: tuple[Entry, ...] = ((obj.TOUCH_PROBE_STATUS, 16), (obj.TOUCH_PROBE_POS1_POS, 32))
TPDO4: tuple[Entry, ...] = ((obj.TOUCH_PROBE_POS2_POS, 32), (obj.TOUCH_PROBE_POS2_NEG, 32))

#: transmission types (0x1800 sub 2): 1 = synchronous, every SYNC; 0 = synchronous acyclic (on change)
SYNC_EVERY, SYNC_ACYCLIC = 1, 0
TPDO_TRANS = {1: SYNC_EVERY, 2: SYNC_EVERY, 3: SYNC_ACYCLIC, 4: SYNC_ACYCLIC}

INT32_MIN, INT32_MAX = -(1 << 31), (1 << 31) - 1
_SPAN = 1 << 32
#: |increments| beyond this are not taken from a float (int64 holds the rest of the arithmetic exactly)
_FLOAT_LIMIT = float(1 << 62)


def wrap32(x: np.ndarray) -> np.ndarray:
    """Increments (int64, or float: rounded) as the INT32 a position object (0x607A, 0x6064, 0x60BA-0x60BD) carries:
    modulo 2^32, so an endless axis wraps around instead of stopping at the range's end (as a drive's 32-bit
    position counter does; the other side unwraps with :func:`unwrap32`)."""
    if x.dtype.kind == "f":
        x = np.rint(np.clip(np.nan_to_num(x), -_FLOAT_LIMIT, _FLOAT_LIMIT)).astype(np.int64)
    return ((x.astype(np.int64) - INT32_MIN) % _SPAN) + INT32_MIN


def unwrap32(raw: np.ndarray, near: np.ndarray) -> np.ndarray:
    """The int64 increments nearest to ``near`` (int64) whose INT32 is ``raw``: continuous positions from a wrapping
    32-bit counter, as long as a value moves less than 2^31 increments between two readings."""
    near = near.astype(np.int64)
    return near + wrap32(raw.astype(np.int64) - wrap32(near))

_FMT = {od.BOOLEAN: "B", od.INTEGER8: "b", od.UNSIGNED8: "B", od.INTEGER16: "h", od.UNSIGNED16: "H",
        od.INTEGER32: "i", od.UNSIGNED32: "I", od.INTEGER64: "q", od.UNSIGNED64: "Q", od.REAL32: "f",
        od.REAL64: "d"}


def rpdo_layout(csv: bool) -> dict[int, tuple[Entry, ...]]:
    """The NC's RPDO mapping of one axis (CSV adds the target velocity)."""
    return {1: RPDO1, 2: RPDO2_CSV if csv else RPDO2_CSP}


TPDO_LAYOUT: dict[int, tuple[Entry, ...]] = {1: TPDO1, 2: TPDO2, 3: TPDO3, 4: TPDO4}


def struct_for(types: Sequence[int | None]) -> struct.Struct:
    """The little-endian struct packing objects of these CANopen data types in a row (byte aligned).

    Raises:
        ValueError: a data type a PDO of the NC cannot carry.
    """
    fmt = "<"
    for t in types:
        if t not in _FMT:
            raise ValueError(f"data type {t!r} cannot be mapped by the NC")
        fmt += _FMT[t]
    return struct.Struct(fmt)


def frame_bits(dlc: int) -> int:
    """Bits on the wire of a standard (11 bit id) CAN data frame with ``dlc`` bytes, worst-case bit stuffing
    included (47 frame bits + data, one stuff bit per 4 bits of the stuffed 34 + 8 dlc)."""
    return 47 + 8 * dlc + (34 + 8 * dlc - 1) // 4


def bus_load(n_axes: int, cycle_time: float, bitrate: int, csv: bool = False) -> float:
    """The fraction of the bus the cyclic process data of ``n_axes`` take (1.0: full; >1: does not fit).

    Counts SYNC (0 bytes), per axis RPDO1, TPDO1, TPDO2 every cycle; the on-change PDOs (RPDO2, TPDO3)
    are left out."""
    per_axis = sum(frame_bits(sum(b for _, b in m) // 8) for m in (RPDO1, TPDO1, TPDO2))
    return (frame_bits(0) + n_axes * per_axis) / (bitrate * cycle_time)
