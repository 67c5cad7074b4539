"""The claim/supply machine of a door: the axes it holds and the PLCTONC it supplies for each.

A door (nc-ads; the OPC UA and web doors) that lets its users write PLCTONC claims the axis for its client
id and then *supplies* that PLCTONC: one PLC frame with every supplied axis per supply period, so the NC's
watchdog sees a live holder. Each supply belongs to one of the door's connections (``owner``). A supply ends:

* released by the door: :meth:`Supplies.disable` (enables off for a few periods, then :meth:`due` names the
  axis to release), :meth:`Supplies.disable_all` (shutdown), :meth:`Supplies.take` (its connection closed);
* by the NC's rules: a new NC instance (:meth:`Supplies.end_all`: the new NC knows no claim of the old one),
  or the NC's claims map no longer naming this client as the holder (:meth:`Supplies.end_lost`).

The commands (Claim, Release, SetExternalError) are the door's to send (``NcLink.request``): this module
keeps the state only. Thread-safe with the lock passed in (the door's, so its image and supplies change
together); none of its methods blocks. The PLC runtime's claims follow MC_Power instead
(``plc_client.task.ClaimState``).

May import: ``nc_schema``.
"""
from __future__ import annotations

import struct
import threading
from dataclasses import dataclass
from typing import Callable

from nc_schema import PLCTONC_DTYPE

#: ControlDWord bits the door clears to disable: Enable | FeedEnablePlus | FeedEnableMinus.
CONTROL_ENABLE_ALL = 0x7
CONTROL_ENABLE = 0x1
_CW = struct.Struct("<I")
assert PLCTONC_DTYPE.fields is not None  # (a structured dtype)
_CW_OFF = int(PLCTONC_DTYPE.fields["ControlDWord"][1])
_OVERRIDE_OFF = int(PLCTONC_DTYPE.fields["Override"][1])


@dataclass
class Supply:
    """An axis the door holds: the PLCTONC it publishes, the connection that wrote it, the NC cycle of the
    Claim's reply (a claims map of an earlier cycle cannot tell it is lost)."""

    record: bytearray
    conn_id: int
    claim_cycle: int
    release_after: int = -1  # >= 0: publish this many more times, then release (disable)


def _enables_off(rec: bytearray) -> None:
    _CW.pack_into(rec, _CW_OFF, _CW.unpack_from(rec, _CW_OFF)[0] & ~CONTROL_ENABLE_ALL)


class Supplies:
    """The supplied axes (``axes``: AxisId -> :class:`Supply`) under ``lock``; see the module docstring."""

    def __init__(self, lock: threading.Lock | None = None) -> None:
        self.lock = lock or threading.Lock()
        self.axes: dict[int, Supply] = {}

    def __contains__(self, axis: int) -> bool:
        return axis in self.axes

    def __bool__(self) -> bool:
        return bool(self.axes)

    def get(self, axis: int) -> Supply | None:
        with self.lock:
            return self.axes.get(axis)

    def record(self, axis: int) -> bytes | None:
        """A copy of the PLCTONC supplied for ``axis``, None if the door does not hold it."""
        with self.lock:
            sup = self.axes.get(axis)
            return None if sup is None else bytes(sup.record)

    def override(self, axis: int) -> int | None:
        """The supplied Override of ``axis`` [1/1000000], None if the door does not hold it."""
        with self.lock:
            sup = self.axes.get(axis)
            return None if sup is None else _CW.unpack_from(sup.record, _OVERRIDE_OFF)[0]

    def start(self, axis: int, record: bytearray, owner: int, claim_cycle: int) -> Supply:
        """The Claim of ``axis`` was accepted (its reply's cycle ``claim_cycle``): supply ``record`` for ``owner``."""
        sup = Supply(record, owner, claim_cycle)
        with self.lock:
            self.axes[axis] = sup
        return sup

    def change(self, axis: int, change: Callable[[bytearray], None], owner: int) -> int | None:
        """Apply ``change`` to the supplied record of ``axis``; ``owner`` supplies it from now on (a pending
        release is cancelled). Returns the previous owner, None if ``axis`` is not supplied."""
        with self.lock:
            sup = self.axes.get(axis)
            if sup is None:
                return None
            rec = bytearray(sup.record)
            change(rec)
            prev = sup.conn_id
            sup.record, sup.conn_id, sup.release_after = rec, owner, -1
            return prev

    def disable(self, axis: int, owner: int, periods: int = 3) -> bool:
        """Enables off for ``periods`` more supply periods, then release (:meth:`due`). False: not supplied."""
        with self.lock:
            sup = self.axes.get(axis)
            if sup is None:
                return False
            _enables_off(sup.record)
            sup.conn_id, sup.release_after = owner, periods
            return True

    def disable_all(self) -> list[int]:
        """Enables off on every supply, no release pending (the door's shutdown releases them). The axes."""
        with self.lock:
            for sup in self.axes.values():
                _enables_off(sup.record)
                sup.release_after = -1
            return sorted(self.axes)

    def due(self) -> tuple[list[tuple[int, bytes]], list[int]]:
        """One supply period: (AxisId, PLCTONC) of every supply in AxisId order, to publish now as one PLC
        frame, and the axes whose enables-off periods ended with it (the door releases them)."""
        release: list[int] = []
        with self.lock:
            items = sorted(self.axes.items())
            for a, sup in items:
                if sup.release_after >= 0:
                    if sup.release_after == 0:
                        release.append(a)
                    sup.release_after -= 1
            return [(a, bytes(sup.record)) for a, sup in items], release

    def take(self, axis: int, owner: int | None = None) -> Supply | None:
        """End the supply of ``axis`` (if ``owner`` supplies it; None: any) to release it; the supply or None."""
        with self.lock:
            sup = self.axes.get(axis)
            if sup is None or (owner is not None and sup.conn_id != owner):
                return None
            del self.axes[axis]
            return sup

    def owned_by(self, owner: int) -> list[tuple[int, bool]]:
        """(AxisId, Enable supplied) of every supply of ``owner``."""
        with self.lock:
            return [(a, bool(_CW.unpack_from(s.record, _CW_OFF)[0] & CONTROL_ENABLE))
                    for a, s in self.axes.items() if s.conn_id == owner]

    def end_all(self) -> list[int]:
        """A new NC instance: every supply ends (nothing is re-enabled by itself). The axes dropped."""
        with self.lock:
            dropped = sorted(self.axes)
            self.axes.clear()
            return dropped

    def end_lost(self, cycle: int, claims: dict[int, str], client_id: str) -> list[int]:
        """The NC's claims map of NC cycle ``cycle``: a supply whose Claim came before it and that it does not
        name ``client_id`` the holder of was lost by the NC's rules; those end. The axes dropped."""
        lost = []
        with self.lock:
            for a, sup in list(self.axes.items()):
                if cycle > sup.claim_cycle and claims.get(a) != client_id:
                    del self.axes[a]
                    lost.append(a)
        return lost
