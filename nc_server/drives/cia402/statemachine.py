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


def decode(statusword: np.ndarray) -> np.ndarray:
    """The power state per axis (int8 :class:`State` values) of statuswords (0x6041)."""
    return _DECODE[np.asarray(statusword, dtype=np.uint16) & 0x7F]


def statusword(states: np.ndarray, target_reached: np.ndarray | bool = False,
               follows: np.ndarray | bool = False, remote: bool = True) -> np.ndarray:
    """The device's statusword (uint16) per axis.

    Args:
        states: :class:`State` values.
        target_reached: bit 10 per axis (CSP/CSV: the drive stands at its target / velocity reached).
        follows: bit 12 per axis (CSP/CSV: the drive follows the command value; only in Operation enabled).
        remote: bit 9 (the drive is controlled over the fieldbus).
    """
    s = np.asarray(states, dtype=np.intp)
    w = _ENCODE[s]
    if remote:
        w = w | _REMOTE
    if np.any(target_reached):
        w = w | (np.asarray(target_reached, dtype=bool) * _TARGET_REACHED).astype(np.uint16)
    if np.any(follows):
        w = w | ((np.asarray(follows, dtype=bool) & (s == _OE)) * _FOLLOWS).astype(np.uint16)
    return w.astype(np.uint16)


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
        the new states (int8).
    """
    s = np.asarray(states, dtype=np.int8)
    cw = np.asarray(controlword, dtype=np.uint16)
    fault = np.asarray(fault, dtype=bool)
    low3 = cw & 0x7
    low4 = cw & 0xF
    disable_voltage = (cw & 0x2) == 0
    quick_stop = (cw & 0x6) == 0x2
    shutdown = low3 == 0x6
    switch_on = low3 == 0x7
    enable_op = low4 == 0xF
    disable_op = low4 == 0x7
    reset_edge = ((cw & _FAULT_RESET) != 0) & ((np.asarray(prev_controlword, dtype=np.uint16) & _FAULT_RESET) == 0)

    n = s.copy()
    n[s == _NR] = _SOD                                                                  # 0 + 1 (self test done)
    n = np.where((s == _SOD) & shutdown, _RTSO, n)                                      # 2
    rtso = s == _RTSO
    n = np.where(rtso & switch_on, np.where(enable_op, _OE, _SO), n)                    # 3 (+ 4)
    n = np.where(rtso & (disable_voltage | quick_stop), _SOD, n)                        # 7
    so = s == _SO
    n = np.where(so & enable_op, _OE, n)                                                # 4
    n = np.where(so & shutdown, _RTSO, n)                                               # 6
    n = np.where(so & (disable_voltage | quick_stop), _SOD, n)                          # 10
    oe = s == _OE
    n = np.where(oe & disable_op, _SO, n)                                               # 5
    n = np.where(oe & shutdown, _RTSO, n)                                               # 8
    n = np.where(oe & disable_voltage, _SOD, n)                                         # 9
    n = np.where(oe & quick_stop, _QSA, n)                                              # 11
    qsa = s == _QSA
    n = np.where(qsa & disable_voltage, _SOD, n)                                        # 12
    n = np.where(qsa & enable_op, _OE, n)                                               # 16
    n = np.where((s == _FRA) & np.asarray(stopped, dtype=bool), _FLT, n)                # 14
    n = np.where((s == _FLT) & reset_edge & ~fault, _SOD, n)                            # 15
    n = np.where(fault & (s != _FRA) & (s != _FLT), _FRA, n)                            # 13
    return n.astype(np.int8)


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
    want = np.asarray(want_enabled, dtype=bool)
    up = _UP[s]
    down = _DOWN[s]
    cw = np.where(want, up, down)
    fault = s == _FLT
    if np.any(reset_request):
        reset = fault & np.asarray(reset_request, dtype=bool)
        if prev_controlword is not None:
            had = (np.asarray(prev_controlword, dtype=np.uint16) & _FAULT_RESET) != 0
            cw = np.where(reset & ~had, _FAULT_RESET, cw)
        else:
            cw = np.where(reset, _FAULT_RESET, cw)
    return cw.astype(np.uint16)


# state -> controlword toward Operation enabled / toward Ready to switch on
_UP = np.array([0x0006, 0x0006, 0x000F, 0x000F, 0x000F, 0x000F, 0x0000, 0x0000], dtype=np.uint16)
_DOWN = np.array([0x0006, 0x0006, 0x0006, 0x0006, 0x0006, 0x0000, 0x0000, 0x0000], dtype=np.uint16)
