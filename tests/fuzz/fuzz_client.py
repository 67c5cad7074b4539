"""Fuzz target: the PLC client's decoding of what an NC sends (status frames, command replies).

A ``PlcRuntime`` (the real one: ``_take_frames``, ``ZenohPort``'s reply callback, the task, the
function blocks) runs a program of function blocks on axes 1 and 2 of nc1 (and a block on an axis
the NC does not have); its zenoh objects are replaced by fakes fed from the input, on virtual time.
One input is up to 40 PLC cycles; in each:

* the status frame: none (stale data), the NC's records with some fields changed (a table value,
  a bit toggled, or raw; the cycle counter going on, jumping or going back; with or without job
  records), or raw bytes;
* the NC's liveliness token: unchanged, deleted or (re)appearing;
* every pending command query: no answer yet, a reply map whose fields are right, plausible or
  hostile (wrong types, huge numbers, NaN, missing fields), raw bytes, an error reply, or the end of
  the query without any reply;
* which block inputs (Enable, Execute, ...) are set.

A finding is an exception out of ``PlcRuntime.step()`` (the program's blocks are ours: nothing an NC
sends may crash them), an exception logged meanwhile, or a hang (``-timeout``).

Run: ``python -m tests.fuzz.fuzz_client [libFuzzer args] [CORPUS_DIR | CRASH_FILE ...]``.
"""
from __future__ import annotations

import collections
import math
from typing import Any

import numpy as np

from tests.fuzz._runner import Reader, Writer, instrument, main

with instrument():
    import msgpack
    import zenoh

    from nc_schema import NCJOBS_DTYPE, NCTOPLC_DTYPE, CmdState, encode_frame
    from plc_client import (
        MC_Halt, MC_Home, MC_Jog, MC_MoveAbsolute, MC_MoveSuperImposed, MC_MoveVelocity, MC_Power,
        MC_ReadActualPosition, MC_ReadAxisError, MC_ReadStatus, MC_Reset, MC_SetActualPosition, MC_SetOverride,
        MC_Stop, AXIS_REF, MC_AbortTrigger, MC_ExtSetPointGenEnable, MC_GearIn, MC_GearOut, MC_InputRef, MC_NewPos,
        MC_TouchProbe,
    )
    from plc_client.runtime import PlcRuntime
    from tests.fuzz._nc import LOG, FuzzNc

MAX_CYCLES = 40
CYCLE = 0.01
# the NC's records as a real NC shows two powered axes at standstill
_NC = FuzzNc(CYCLE, held=[1, 2])
NCTOPLC0 = _NC.core.nctoplc[:2].copy()
NCJOBS0 = _NC.core.ncjobs[:2].copy()
del _NC
NC_FIELDS = [n for n in NCTOPLC_DTYPE.names if not n.startswith("_")]
JOB_FIELDS = [n for n in NCJOBS_DTYPE.names if not n.startswith("_") and NCJOBS_DTYPE.fields[n][0].kind != "V"]
INTS = (0, 1, 2, 3, 4, 5, 6, 7, 8, 0xFF, 0xFFFF, 0x4B0F, 0x4000, 0x8F01, 0x723, 2**31 - 1, 2**31, 2**32 - 1, -1,
        *(int(v) for v in CmdState))
FLOATS = (0.0, 1.0, -1.0, 100.0, 1e300, -1e300, 5e-324, math.nan, math.inf, -math.inf, -0.0)
#: reply field values: plausible and hostile
VALUES = (0, 1, -1, 7, 2**16, 2**32 - 1, 2**63 - 1, -(2**63), 2**64 - 1, 0.5, math.nan, math.inf, -math.inf, True,
          False, None, "", "x", "0", b"\x00", [], {}, [1, 2], {"error": 0}, 1e300)
REPLY_FIELDS = ("id", "cmd", "error", "text", "cycle", "CmdNo", "Value")
VALUE_KEYS = ("ActualDistance", "ActualVelocityDiff", "ActualLength", "x")


# ---- fakes for the zenoh objects of one NC link --------------------------------------------------
class _Payload:
    def __init__(self, data: bytes) -> None:
        self.data = data

    def to_bytes(self) -> bytes:
        return self.data

    def __len__(self) -> int:
        return len(self.data)


class _Sample:
    def __init__(self, data: bytes = b"", kind: Any = None) -> None:
        self.payload = _Payload(data)
        self.kind = kind


class _Channel:
    """RingChannel/FifoChannel stand-in: ``try_recv`` pops what the input put there."""

    def __init__(self) -> None:
        self.items: collections.deque[_Sample] = collections.deque()

    def try_recv(self) -> _Sample | None:
        return self.items.popleft() if self.items else None

    def undeclare(self) -> None:
        pass


class _Ok:
    def __init__(self, data: bytes) -> None:
        self.payload = _Payload(data)


class _Reply:
    def __init__(self, ok: _Ok | None) -> None:
        self.ok = ok


class _ReplyChannel:
    """The FifoChannel of one command query: replies the input put there, then "empty and closed"."""

    def __init__(self) -> None:
        self.replies: collections.deque[_Reply] = collections.deque()
        self.closed = False

    def try_recv(self) -> _Reply | None:
        if self.replies:
            return self.replies.popleft()
        if self.closed:
            raise RuntimeError("channel is empty and closed")
        return None


class _Session:
    """Records each ``get`` (a command query) with its reply channel; the input answers them."""

    def __init__(self) -> None:
        self.queries: list[tuple[str, bytes, _ReplyChannel]] = []

    def get(self, key: str, handler: Any, payload: bytes = b"", **kw: Any) -> _ReplyChannel:
        rx = _ReplyChannel()
        self.queries.append((key, payload, rx))
        return rx

    def close(self) -> None:
        pass


class _Pub:
    def __init__(self) -> None:
        self.last = b""

    def put(self, data: bytes) -> None:
        self.last = data

    def undeclare(self) -> None:
        pass


class FuzzRuntime(PlcRuntime):
    """The runtime on virtual time (one PLC cycle = ``cycle_time``)."""

    def clock(self) -> float:
        return self.cycle * self.cycle_time


# ---- the program -----------------------------------------------------------------------------------
class Program:
    """Function blocks on X (axis 1), Y (axis 2, geared to X) and an axis nc1 does not have."""

    def __init__(self) -> None:
        self.X, self.Y, self.Z = AXIS_REF(nc="nc1", axis_id=1), AXIS_REF(nc="nc1", axis_id=2), AXIS_REF(nc="nc1", axis_id=9)
        self.ref = MC_InputRef()
        self.b = dict(
            power=MC_Power(), powery=MC_Power(), mabs=MC_MoveAbsolute(), mvel=MC_MoveVelocity(), halt=MC_Halt(),
            stop=MC_Stop(), reset=MC_Reset(), home=MC_Home(), gear=MC_GearIn(), gearout=MC_GearOut(),
            sup=MC_MoveSuperImposed(), probe=MC_TouchProbe(), abort=MC_AbortTrigger(), status=MC_ReadStatus(),
            err=MC_ReadAxisError(), pos=MC_ReadActualPosition(), ext=MC_ExtSetPointGenEnable(),
            setpos=MC_SetActualPosition(), jog=MC_Jog(), newpos=MC_NewPos(), ovr=MC_SetOverride(), z=MC_MoveAbsolute(),
        )
        self.bits = 0

    def cycle(self, plc: Any) -> None:
        b, X, Y, on = self.b, self.X, self.Y, self.bit
        b["power"](Axis=X, Enable=on(0), Enable_Positive=on(1), Enable_Negative=True, Override=100.0)
        b["powery"](Axis=Y, Enable=on(0), Enable_Positive=True, Enable_Negative=True)
        b["mabs"](Axis=X, Execute=on(2), Position=100.0, Velocity=50.0)
        b["mvel"](Axis=X, Execute=on(3), Velocity=20.0)
        b["halt"](Axis=X, Execute=on(4))
        b["stop"](Axis=X, Execute=on(5))
        b["reset"](Axis=X, Execute=on(6))
        b["home"](Axis=X, Execute=on(7), bCalibrationCam=on(8))
        b["gear"](Master=X, Slave=Y, Execute=on(9), RatioNumerator=1, RatioDenominator=2)
        b["gearout"](Slave=Y, Execute=on(10))
        b["sup"](Axis=X, Execute=on(11), Distance=5.0, VelocityDiff=10.0, Acceleration=100.0, Deceleration=100.0)
        b["probe"](Axis=X, TriggerInput=self.ref, Execute=on(12))
        b["abort"](Axis=X, TriggerInput=self.ref, Execute=on(13))
        b["status"](Axis=X, Enable=on(14))
        b["err"](Axis=X, Enable=on(14))
        b["pos"](Axis=Y, Enable=on(14))
        b["ext"](Axis=Y, Execute=on(15))
        b["setpos"](Axis=Y, Execute=on(16), Position=1.0)
        b["jog"](Axis=Y, JogForward=on(17), JogBackwards=on(18))
        b["newpos"](Axis=X, Execute=on(19), NewPos=10.0)
        b["ovr"](Axis=Y, Execute=on(20), Override=50.0)
        b["z"](Axis=self.Z, Execute=on(21), Position=1.0, Velocity=1.0)

    def bit(self, k: int) -> bool:
        return bool(self.bits >> k & 1)


# ---- the NC's side, from the input -----------------------------------------------------------------
def int_value(r: Reader, dt: np.dtype, old: int) -> int:
    m = r.u8() % 3
    if m == 0:
        v = r.pick(INTS)
    elif m == 1:
        v = old ^ (1 << (r.u8() % (8 * dt.itemsize)))
    else:
        v = int.from_bytes(r.take(dt.itemsize).ljust(dt.itemsize, b"\0"), "little")
    bits = 8 * dt.itemsize
    v &= (1 << bits) - 1
    if dt.kind == "i" and v >= 1 << (bits - 1):
        v -= 1 << bits
    return v


def mutate(r: Reader, recs: np.ndarray, names: list[str]) -> None:
    rec = recs[r.u8() % len(recs)]
    name = r.pick(names)
    dt = recs.dtype.fields[name][0]
    if dt.kind == "f":
        rec[name] = r.pick(FLOATS) if r.u8() & 1 else r.f64()
    elif dt.kind in "ui":
        rec[name] = int_value(r, dt, int(rec[name]))


def hostile(r: Reader) -> Any:
    m = r.u8() % 4
    if m == 0:
        return r.pick(VALUES)
    if m == 1:
        return r.f64()
    if m == 2:
        return r.take(r.u8() % 16).decode("utf-8", "replace")
    return {r.pick(VALUE_KEYS): r.pick(VALUES) for _ in range(r.u8() % 3)}


def reply_for(r: Reader, flags: int, payload: bytes, nc_cycle: int, cmdno: int) -> bytes:
    """A reply to ``payload``: the right fields; ``flags`` (2 bits per field) leaves some out or makes
    them hostile."""
    try:
        req = msgpack.unpackb(payload, raw=False)
    except Exception:
        req = {}
    right = {"id": req.get("id"), "cmd": req.get("cmd"), "error": 0, "text": "", "cycle": nc_cycle + 1,
             "CmdNo": cmdno}
    if req.get("cmd") == "MoveSuperImposed":
        right["Value"] = {"ActualDistance": 5.0, "ActualVelocityDiff": 10.0, "ActualLength": 50.0}
    out: dict[Any, Any] = {}
    for k, name in enumerate(REPLY_FIELDS):
        f = flags >> (2 * k) & 3
        if f == 0 or f == 1:
            if name in right:
                out[name] = right[name]
        elif f == 2:
            out[name] = hostile(r)
        elif name == "error":
            out[name] = r.pick(INTS)
        # f == 3 for the other fields: left out
    try:
        return msgpack.packb(out, use_bin_type=True)
    except (OverflowError, TypeError, ValueError):
        return b"\x80"


class NcModel:
    """What the input makes the NC send: frames from its records, replies to the queries."""

    def __init__(self) -> None:
        self.cycle = 1000
        self.recs = NCTOPLC0.copy()
        self.jobs = NCJOBS0.copy()
        self.cmdno = 1

    def frame(self, r: Reader) -> bytes | None:
        m = r.u8()
        kind = m % 4
        if kind == 0:
            return None  # no new frame this PLC cycle
        if kind == 3:
            return r.blob()
        step = m >> 2
        self.cycle = (self.cycle + (1 if step < 48 else (step - 60) * 1000)) % 2**64  # mostly +1, some jumps
        for _ in range(r.u8() % 4):
            mutate(r, self.recs, NC_FIELDS)
        if kind == 2:
            for _ in range(r.u8() % 3):
                mutate(r, self.jobs, JOB_FIELDS)
            return encode_frame(self.cycle, self.cycle * 10**6 % 2**64, self.recs, 0, self.jobs)
        return encode_frame(self.cycle, self.cycle * 10**6 % 2**64, self.recs)


def answer(r: Reader, nc: NcModel, session: _Session) -> None:
    """This cycle's answer to every pending query (one mode and one set of reply flags per cycle)."""
    m, flags = r.u8() % 8, r.u16()
    if m == 0:
        return  # no answer yet
    queries, session.queries = session.queries, []
    for key, payload, rx in queries:
        if m <= 3:
            nc.cmdno = (nc.cmdno + 1) % 65536
            rx.replies.append(_Reply(_Ok(reply_for(r, flags, payload, nc.cycle, nc.cmdno))))
        elif m == 4:
            rx.replies.append(_Reply(_Ok(r.blob())))
        elif m == 5:
            rx.replies.append(_Reply(None))  # an error reply (e.g. the query timed out in zenoh)
        if m == 7:  # answered right, the query stays open: a second reply comes with the next answer
            rx.replies.append(_Reply(_Ok(reply_for(r, 0, payload, nc.cycle, nc.cmdno))))
            session.queries.append((key, payload, rx))
        else:
            rx.closed = True  # the query ends (m == 6: without any reply)


def make_runtime() -> tuple[FuzzRuntime, Program, _Session, _Channel, _Channel]:
    prog = Program()
    rt = FuzzRuntime(prog.cycle, {"nc1": "tcp/127.0.0.1:9"}, cycle_time=CYCLE, client_id="plc1", command_timeout=0.1,
                     claim_retry=0.2)
    link = rt.links["nc1"]
    session, frames, alive = _Session(), _Channel(), _Channel()
    link.session, link.frames, link.alive_sub, link.pub = session, frames, alive, _Pub()
    link.ready = True
    rt._opened = True
    alive.items.append(_Sample(kind=zenoh.SampleKind.PUT))
    return rt, prog, session, frames, alive


def test_one(data: bytes) -> None:
    r = Reader(data)
    rt, prog, session, frames, alive = make_runtime()
    nc = NcModel()
    for _ in range(MAX_CYCLES):
        if r.left() <= 0:
            break
        f = nc.frame(r)
        if f is not None:
            frames.items.clear()  # RingChannel(1): only the newest
            frames.items.append(_Sample(f))
        ev = r.u8() % 16
        if ev == 1:
            alive.items.append(_Sample(kind=zenoh.SampleKind.DELETE))
        elif ev == 2:
            alive.items.append(_Sample(kind=zenoh.SampleKind.PUT))
        prog.bits = r.u32() | r.u8() << 32
        rt.step()
        LOG.check(f"in PLC cycle {rt.cycle}")
        answer(r, nc, session)
    rt.step()
    LOG.check("in the last PLC cycle")


def seeds() -> list[bytes]:
    out = []
    # enable, then each block alone, every query answered right (flags 0), frames going on
    for bit in range(2, 22):
        w = Writer()
        for c in range(12):
            w.u8(1).u8(0)  # a frame: cycle + 1, no field changed
            w.u8(0)  # liveliness unchanged
            w.u32(1 | 2 | ((1 << bit) if c >= 3 else 0)).u8(0)
            w.u8(1).u16(0)  # every query answered right
        out.append(w.bytes())
    w = Writer()  # stale frames, the NC restarting (liveliness, then its cycle counter going back)
    for c in range(40):
        if 10 <= c < 35:
            w.u8(0)  # no frame
        elif c == 36:
            w.u8(1 | 62 << 2).u8(0)  # cycle - 2000
        else:
            w.u8(1).u8(0)
        w.u8(1 if c == 20 else 2 if c == 36 else 0).u32(3 | 4 | 1 << 14).u8(0).u8(1).u16(0)
    out.append(w.bytes())
    w = Writer()  # job records, and a frame of raw bytes
    for c in range(8):
        w.u8(2).u8(0).u8(0) if c != 4 else w.u8(3).blob(encode_frame(5, 0, NCTOPLC0))
        w.u8(0).u32(3 | 1 << 9).u8(0).u8(1).u16(0)
    out.append(w.bytes())
    return out


if __name__ == "__main__":
    main("client", test_one, seeds)
