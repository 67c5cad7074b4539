"""The CiA 402 power state machine, pure and vectorized over axes.

Arrays of :class:`.objects.State` values (any integer dtype) and uint16 controlwords / statuswords, one entry
per axis; every function is a few table look-ups and ``np.where`` (no per-axis Python loops).

* :func:`decode`: statusword -> state (the CiA 402 statusword masks);
* :func:`statusword`: state -> statusword (the device side);
* :func:`device_next`: the device's transitions 0..16 for a controlword;
* :func:`nc_controlword`: the NC's next controlword walking toward Operation enabled or toward disabled.

Decisions (CiA 402 leaves them to the device / the master):

* The device does transition 3 + 4 in one step when the controlword in Ready to switch on is "switch on +
  enable operation" (0x000F; CiA 402-2 allows it), so an NC enable reaches Operation enabled in one cycle
  from Ready to switch on.
* Quick stop option code 6 (0x605A): the drive stops on its quick-stop ramp and stays in Quick stop active;
  transition 16 (enable operation, quick stop bit 1) takes it back to Operation enabled, disable voltage
  (transition 12) to Switch on disabled.
* Fault reaction active -> Fault (transition 14) when the device says its reaction is done (``stopped``).
* A fault reset (transition 15) needs the rising edge of bit 7 *and* no fault condition left (``fault``
  False); a fault condition present in any other state starts the fault reaction (transition 13).
* The NC's "disabled" is Ready to switch on (power stage ready, no torque; a brake holds): from there one
  controlword 0x000F enables. The NC sends Shutdown (0x0006) to disable, Disable voltage (0x0000) from Quick
  stop active and during Fault / Fault reaction active.

It may import: numpy.
"""
from __future__ import annotations

import numpy as np

from .objects import CW, SW, State

_NR, _SOD, _RTSO, _SO, _OE, _QSA, _FRA, _FLT = (int(s) for s in State)

# statusword & 0x7F -> state (masks of CiA 402-2 table "State coding")
_DECODE = np.zeros(128, dtype=np.int8)
for _w in range(128):
    if _w & 0x4F == 0x00:
        _DECODE[_w] = _NR
    elif _w & 0x4F == 0x40:
        _DECODE[_w] = _SOD
    elif _w & 0x6F == 0x21:
        _DECODE[_w] = _RTSO
    elif _w & 0x6F == 0x23:
        _DECODE[_w] = _SO
    elif _w & 0x6F == 0x27:
        _DECODE[_w] = _OE
    elif _w & 0x6F == 0x07:
        _DECODE[_w] = _QSA
    elif _w & 0x4F == 0x0F:
        _DECODE[_w] = _FRA
    elif _w & 0x4F == 0x08:
        _DECODE[_w] = _FLT
    else:  # no valid coding (e.g. 0x01): taken as Not ready to switch on
        _DECODE[_w] = _NR

# state -> statusword bits 0..6 (bit 4 voltage enabled added where the power stage has voltage)
_V = int(SW.VOLTAGE_ENABLED)
_ENCODE = np.array([0x0000, 0x0040, 0x0021 | _V, 0x0023 | _V, 0x0027 | _V, 0x0007 | _V, 0x000F | _V, 0x0008],
                   dtype=np.uint16)
_REMOTE = np.uint16(int(SW.REMOTE))
_TARGET_REACHED = np.uint16(int(SW.TARGET_REACHED))
_FOLLOWS = np.uint16(int(SW.DRIVE_FOLLOWS))
_FAULT_RESET = np.uint16(int(CW.FAULT_RESET))
_ENCODE_FOLLOWS = (_ENCODE | _REMOTE | np.where(np.arange(8) == _OE, _FOLLOWS, 0)).astype(np.uint16)


def decode(statusword: np.ndarray) -> np.ndarray:
    """The power state per axis (int8 :class:`State` values) of statuswords (0x6041)."""
    return _DECODE[np.asarray(statusword, dtype=np.uint16) & 0x7F]


def statusword(states: np.ndarray, target_reached: np.ndarray | bool = False,
               follows: np.ndarray | bool = False, remote: bool = True) -> np.ndarray:
    """The device's statusword (uint16) per axis.

    Args:
        states: :class:`State` values.
        target_reached: bit 10 per axis (CSP/CSV: the drive stands at its target / velocity reached).
        follows: bit 12 per axis (CSP/CSV: the drive follows the command value; set only in Operation enabled):
            True: wherever the drive is in Operation enabled.
        remote: bit 9 (the drive is controlled over the fieldbus).
    """
    s = np.asarray(states, dtype=np.intp)
    if follows is True and remote:  # the simulated device's cycle: one look-up
        return _ENCODE_FOLLOWS[s]
    w = _ENCODE[s]
    if remote:
        w = w | _REMOTE
    if np.any(target_reached):
        w = w | (np.asarray(target_reached, dtype=bool) * _TARGET_REACHED).astype(np.uint16)
    if np.any(follows):
        w = w | ((np.asarray(follows, dtype=bool) & (s == _OE)) * _FOLLOWS).astype(np.uint16)
    return w.astype(np.uint16, copy=False)


def _command_next(state: int, cw: int) -> int:
    """The device's transition for the command in controlword bits 0..3 (transitions 0..12 and 16; the fault
    transitions 13..15 depend on more than the controlword and are applied by :func:`device_next`)."""
    disable_voltage = cw & 0x2 == 0
    quick_stop = cw & 0x6 == 0x2
    shutdown = cw & 0x7 == 0x6
    switch_on = cw & 0x7 == 0x7
    enable_op = cw & 0xF == 0xF
    disable_op = cw & 0xF == 0x7
    if state == _NR:
        return _SOD                                       # 0 + 1 (the self test is done)
    if state == _SOD:
        return _RTSO if shutdown else _SOD                # 2
    if state == _RTSO:
        if switch_on:
            return _OE if enable_op else _SO              # 3 (+ 4)
        return _SOD if disable_voltage or quick_stop else _RTSO  # 7
    if state == _SO:
        if enable_op:
            return _OE                                    # 4
        if shutdown:
            return _RTSO                                  # 6
        return _SOD if disable_voltage or quick_stop else _SO  # 10
    if state == _OE:
        if disable_op:
            return _SO                                    # 5
        if shutdown:
            return _RTSO                                  # 8
        if disable_voltage:
            return _SOD                                   # 9
        return _QSA if quick_stop else _OE                # 11
    if state == _QSA:
        if disable_voltage:
            return _SOD                                   # 12
        return _OE if enable_op else _QSA                 # 16
    return state                                          # Fault reaction active, Fault: see device_next


#: (state * 16 + controlword & 0xF) -> next state by the command alone
_NEXT = np.array([_command_next(st, cw) for st in range(8) for cw in range(16)], dtype=np.int8)


def device_next(states: np.ndarray, controlword: np.ndarray, prev_controlword: np.ndarray,
                fault: np.ndarray | bool = False, stopped: np.ndarray | bool = True) -> np.ndarray:
    """The device's next state per axis (transitions 0..16 of CiA 402-2).

    Args:
        states: current :class:`State` values.
        controlword: the controlword (0x6040) received this cycle.
        prev_controlword: the one before (for the rising edge of the fault reset bit 7).
        fault: per axis, a fault condition is present (starts the fault reaction, blocks the fault reset).
        stopped: per axis, the fault reaction is done (Fault reaction active -> Fault).

    Returns:
        the new states (int8; a new array).
    """
    s = np.asarray(states, dtype=np.int8)
    cw = np.asarray(controlword, dtype=np.uint16)
    n = _NEXT[(s.astype(np.intp) << 4) | (cw & 0xF)]
    if np.count_nonzero(s >= _FRA):  # (only then: the common cycle is one table look-up)
        n = np.where((s == _FRA) & np.asarray(stopped, dtype=bool), np.int8(_FLT), n)                # 14
        reset_edge = ((cw & _FAULT_RESET) != 0) & ((np.asarray(prev_controlword, dtype=np.uint16) & _FAULT_RESET) == 0)
        n = np.where((s == _FLT) & reset_edge & ~np.asarray(fault, dtype=bool), np.int8(_SOD), n)  # 15
    if fault is not False and np.count_nonzero(fault):
        n = np.where(np.asarray(fault, dtype=bool) & (s < _FRA), np.int8(_FRA), n)                  # 13
    return n.astype(np.int8, copy=False)


def nc_controlword(states: np.ndarray, want_enabled: np.ndarray, reset_request: np.ndarray | bool = False,
                   prev_controlword: np.ndarray | None = None) -> np.ndarray:
    """The NC's next controlword per axis.

    Walks toward Operation enabled where ``want_enabled`` (Switch on disabled -> Shutdown 0x0006, Ready to switch
    on / Switched on / Operation enabled / Quick stop active -> 0x000F), toward Ready to switch on elsewhere
    (Shutdown 0x0006; from Quick stop active Disable voltage 0x0000). In Fault a ``reset_request`` sends the fault
    reset 0x0080 as an edge: where ``prev_controlword`` had bit 7 set already, this cycle sends 0x0000 (the next
    one 0x0080). Without a reset request Fault and Fault reaction active get 0x0000.

    Args:
        states: the drive's current :class:`State` values (decoded from its statusword).
        want_enabled: bool per axis: the NC's controller enable.
        reset_request: bool per axis: a fault reset is pending (MC_Reset).
        prev_controlword: the controlwords sent last cycle (None: taken as without bit 7).

    Returns:
        uint16 controlwords.
    """
    s = np.asarray(states, dtype=np.intp)
    cw = _WALK[(np.asarray(want_enabled, dtype=np.intp) << 3) | s]
    if reset_request is not False and np.count_nonzero(reset_request):
        reset = (s == _FLT) & np.asarray(reset_request, dtype=bool)
        if prev_controlword is not None:
            had = (np.asarray(prev_controlword, dtype=np.uint16) & _FAULT_RESET) != 0
            cw = np.where(reset & ~had, _FAULT_RESET, cw)
        else:
            cw = np.where(reset, _FAULT_RESET, cw)
    return cw.astype(np.uint16, copy=False)


# (want << 3 | state) -> controlword: toward Ready to switch on (want 0), toward Operation enabled (want 1)
_WALK = np.array([0x0006, 0x0006, 0x0006, 0x0006, 0x0006, 0x0000, 0x0000, 0x0000,
                  0x0006, 0x0006, 0x000F, 0x000F, 0x000F, 0x000F, 0x0000, 0x0000], dtype=np.uint16)
