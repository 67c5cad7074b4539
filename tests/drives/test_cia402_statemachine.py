"""The CiA 402 power state machine (nc_server.drives.cia402.statemachine): decoding, encoding, every device
transition, the fault reset edge, quick stop, and the NC's controlword walk."""
from __future__ import annotations

import numpy as np

import nc_server.core  # noqa: F401  (first: nc_server.drives imports the core, which imports drives.base)
import pytest

from nc_server.drives.cia402 import statemachine as sm
from nc_server.drives.cia402.objects import State

S = State
NR, SOD, RTSO, SO, OE, QSA, FRA, FLT = (int(s) for s in State)


def _next(state: int, cw: int, prev: int = 0, fault: bool = False, stopped: bool = True) -> int:
    return int(sm.device_next(np.array([state]), np.array([cw], dtype=np.uint16),
                              np.array([prev], dtype=np.uint16), np.array([fault]), np.array([stopped]))[0])


@pytest.mark.parametrize("word, state", [
    (0x0000, NR), (0x0010, NR), (0x0040, SOD), (0x0250, SOD), (0x0021, RTSO), (0x0231, RTSO),
    (0x0023, SO), (0x0033, SO), (0x0027, OE), (0x1237, OE), (0x0007, QSA), (0x0017, QSA),
    (0x000F, FRA), (0x002F, FRA), (0x0008, FLT), (0x0218, FLT), (0x0028, FLT)])
def test_decode_masks(word: int, state: int) -> None:
    assert int(sm.decode(np.array([word], dtype=np.uint16))[0]) == state


def test_statusword_round_trip_and_bits() -> None:
    states = np.arange(8)
    w = sm.statusword(states, follows=np.ones(8, dtype=bool))
    assert list(sm.decode(w)) == list(states)
    assert all(x & 0x200 for x in w)  # remote
    assert [bool(x & 0x10) for x in w] == [False, False, True, True, True, True, True, False]  # voltage enabled
    assert [bool(x & 0x1000) for x in w] == [s == OE for s in states]  # drive follows only in OE


@pytest.mark.parametrize("name, state, cw, new", [
    ("0+1 self test", NR, 0x0000, SOD),
    ("2 shutdown", SOD, 0x0006, RTSO),
    ("SOD stays on switch on", SOD, 0x0007, SOD),
    ("3 switch on", RTSO, 0x0007, SO),
    ("3+4 switch on + enable", RTSO, 0x000F, OE),
    ("4 enable operation", SO, 0x000F, OE),
    ("5 disable operation", OE, 0x0007, SO),
    ("6 shutdown", SO, 0x0006, RTSO),
    ("7 disable voltage", RTSO, 0x0000, SOD),
    ("7 quick stop", RTSO, 0x0002, SOD),
    ("8 shutdown", OE, 0x0006, RTSO),
    ("9 disable voltage", OE, 0x0000, SOD),
    ("10 disable voltage", SO, 0x0000, SOD),
    ("10 quick stop", SO, 0x0002, SOD),
    ("11 quick stop", OE, 0x000B, QSA),
    ("QSA stays", QSA, 0x000B, QSA),
    ("12 disable voltage", QSA, 0x0000, SOD),
    ("16 enable operation", QSA, 0x000F, OE),
    ("OE stays", OE, 0x000F, OE),
    ("fault stays without reset", FLT, 0x000F, FLT),
])
def test_device_transitions(name: str, state: int, cw: int, new: int) -> None:
    assert _next(state, cw) == new, name


@pytest.mark.parametrize("state", [NR, SOD, RTSO, SO, OE, QSA])
def test_13_fault_starts_the_reaction(state: int) -> None:
    assert _next(state, 0x000F, fault=True) == FRA


def test_14_reaction_done_and_15_fault_reset_edge() -> None:
    assert _next(FRA, 0x0000, fault=False, stopped=False) == FRA
    assert _next(FRA, 0x0000, fault=False, stopped=True) == FLT
    assert _next(FLT, 0x0080, prev=0x0000) == SOD            # rising edge
    assert _next(FLT, 0x0080, prev=0x0080) == FLT            # level, no edge
    assert _next(FLT, 0x0080, prev=0x0000, fault=True) == FLT  # the cause is still there


def test_vectorized_mixed_states() -> None:
    states = np.array([SOD, RTSO, OE, FLT])
    cw = np.array([0x06, 0x0F, 0x0B, 0x80], dtype=np.uint16)
    assert list(sm.device_next(states, cw, np.zeros(4, dtype=np.uint16))) == [RTSO, OE, QSA, SOD]


def test_nc_controlword_walks_up_from_every_state() -> None:
    for start in (NR, SOD, RTSO, SO, OE, QSA):
        s = np.array([start])
        prev = np.zeros(1, dtype=np.uint16)
        for _ in range(4):
            cw = sm.nc_controlword(s, np.array([True]), False, prev)
            s, prev = sm.device_next(s, cw, prev), cw
        assert int(s[0]) == OE, start


def test_nc_controlword_walks_down_to_ready_to_switch_on() -> None:
    for start in (NR, SOD, RTSO, SO, OE, QSA):
        s = np.array([start])
        prev = np.zeros(1, dtype=np.uint16)
        for _ in range(4):
            cw = sm.nc_controlword(s, np.array([False]), False, prev)
            s, prev = sm.device_next(s, cw, prev), cw
        assert int(s[0]) == RTSO, start


def test_enable_from_ready_takes_one_cycle() -> None:
    cw = sm.nc_controlword(np.array([RTSO]), np.array([True]))
    assert int(cw[0]) == 0x000F
    assert int(sm.device_next(np.array([RTSO]), cw, np.zeros(1, dtype=np.uint16))[0]) == OE


def test_fault_reset_is_an_edge() -> None:
    want = np.array([True])
    # no request: 0
    assert int(sm.nc_controlword(np.array([FLT]), want, False, np.array([0], dtype=np.uint16))[0]) == 0
    # request after a 0: 0x80 at once
    assert int(sm.nc_controlword(np.array([FLT]), want, np.array([True]), np.array([0], dtype=np.uint16))[0]) == 0x80
    # request while bit 7 is still set from the last cycle: first 0, then 0x80
    prev = np.array([0x80], dtype=np.uint16)
    cw1 = sm.nc_controlword(np.array([FLT]), want, np.array([True]), prev)
    cw2 = sm.nc_controlword(np.array([FLT]), want, np.array([True]), cw1)
    assert (int(cw1[0]), int(cw2[0])) == (0x00, 0x80)
    # the reset reaches Switch on disabled, then the walk goes on
    s = sm.device_next(np.array([FLT]), cw2, cw1)
    assert int(s[0]) == SOD
    # reaction active: no reset yet
    assert int(sm.nc_controlword(np.array([FRA]), want, np.array([True]), np.zeros(1, dtype=np.uint16))[0]) == 0
