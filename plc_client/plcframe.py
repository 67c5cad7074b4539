"""The PLC frame of one NC, packed into a buffer kept from cycle to cycle (issue 19: one PLCTONC frame per
cycle, no per-cycle allocation that can be avoided).

:class:`PlcFrameBuffer` holds the frame of a fixed list of axes: PLC_FRAME_HEADER and each axis's
PLC_AXIS_RECORD head (AxisId) are written once, when the list is set; a cycle writes the PlcCycle (one
``pack_into``) and copies each axis's 128 PLCTONC bytes into its slot (one slice assignment each). The bytes
are those of :func:`nc_schema.encode_plc_records` for the same cycle and axes (tests/plc/test_plcframe.py).
The task rebuilds it only when the axes it controls change (:meth:`plc_client.task.PlcTask.plc_frame`).
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Sequence

from nc_schema.frames import PLC_AXIS_HEAD_STRUCT, PLC_FRAME_HEADER_STRUCT, PLC_FRAME_MAGIC, WIRE_VERSION
from nc_schema.layout import (PLC_AXIS_RECORD_SIZE, PLC_FRAME_HEADER_DTYPE, PLC_FRAME_HEADER_SIZE, PLCTONC_SIZE,
                              member_struct)

if TYPE_CHECKING:  # pragma: no cover
    from .axis_ref import AXIS_REF

#: where PLC_FRAME_HEADER keeps the PLC cycle, and its struct
_CYCLE_OFFSET, _CYCLE_STRUCT = member_struct(PLC_FRAME_HEADER_DTYPE, "PlcCycle")
_HEAD_SIZE = PLC_AXIS_HEAD_STRUCT.size


class PlcFrameBuffer:
    """The PLC frame of ``axes`` (their AxisIds and PlcToNc records, in this order), kept in one bytearray.

    Attributes:
        axes: the axes, as given (the task compares it by identity to know whether to rebuild).
        buf: the frame; :meth:`frame` rewrites it and returns it (valid until the next call).
    """

    __slots__ = ("axes", "buf", "_slots")

    def __init__(self, axes: Sequence[AXIS_REF]) -> None:
        self.axes = axes
        n = len(axes)
        self.buf = bytearray(PLC_FRAME_HEADER_SIZE + n * PLC_AXIS_RECORD_SIZE)
        PLC_FRAME_HEADER_STRUCT.pack_into(self.buf, 0, PLC_FRAME_MAGIC, WIRE_VERSION, PLC_FRAME_HEADER_SIZE, 0, n,
                                          PLC_AXIS_RECORD_SIZE, 0)
        #: (slice of the PLCTONC record in ``buf``, the axis's PLCTONC bytes) per axis
        self._slots: list[tuple[slice, bytearray]] = []
        o = PLC_FRAME_HEADER_SIZE
        for ax in axes:
            PLC_AXIS_HEAD_STRUCT.pack_into(self.buf, o, ax.axis_id, 0)
            self._slots.append((slice(o + _HEAD_SIZE, o + _HEAD_SIZE + PLCTONC_SIZE), ax._plctonc_buf))
            o += PLC_AXIS_RECORD_SIZE

    def frame(self, plc_cycle: int) -> bytearray:
        """This cycle's frame: ``plc_cycle`` and the axes' PLCTONC records as they are now."""
        buf = self.buf
        _CYCLE_STRUCT.pack_into(buf, _CYCLE_OFFSET, plc_cycle)
        for where, rec in self._slots:
            buf[where] = rec
        return buf
