"""Fuzz target: PLCTONC frames through the server's decode path and ``CycleInputs.apply``.

One input is a scenario on a fresh NC (:mod:`tests.fuzz._nc`; plc1 holds and powers axes 1-4): a
setup byte (cycle time, an optional command that makes the NC read more of PLCTONC: a move, the
external set-point generator, MC_GearInDyn's ratio, homing on the cam input, a touch probe), then up
to 24 operations:

* a raw frame (bytes) or a structured one (PLC_FRAME_HEADER with each field right or fuzzed, records
  with AxisIds from a table or fuzzed, fuzzed PLCTONC bytes) from plc1, or from plc2 (no claim);
* a field of plc1's PLCTONC record of one axis set to a plausible, boundary or raw value (every
  later cycle's frame carries it, as a PLC writing ``PlcToNc`` would);
* NC cycles with plc1's frame, cycles without (the watchdog), a command.

Every frame goes through ``transport.decode_plctonc`` (only ValueError may come out) and then, as
nc-server's cycle does, ``CycleInputs.apply`` and ``core.step()`` (no exception, no exception logged,
finite outputs: see ``_nc``).

Run: ``python -m tests.fuzz.fuzz_plctonc [libFuzzer args] [CORPUS_DIR | CRASH_FILE ...]``.
"""
from __future__ import annotations

import numpy as np

from tests.fuzz._runner import Reader, Writer, instrument, main

with instrument():
    from nc_schema import (
        PLC_AXIS_RECORD_DTYPE, PLC_FRAME_HEADER_DTYPE, PLCTONC_DTYPE, ControlDWord, encode_plc_frame, make_request,
    )
    from nc_schema.codec import PLC_FRAME_MAGIC, WIRE_VERSION
    from nc_server.server.transport import decode_plctonc
    from tests.fuzz._nc import AXES, HOLDER, OTHER, FuzzNc

MAX_OPS = 24
MAX_STEPS = 1000
MAX_BYTES = PLC_FRAME_HEADER_DTYPE.itemsize + len(AXES) * PLC_AXIS_RECORD_DTYPE.itemsize
AXIS_IDS = (*AXES, 0, 5, 255, 2**31, 2**32 - 1)
FIELDS = [n for n in PLCTONC_DTYPE.names if not n.startswith("_")]
LREALS = (0.0, 1.0, -1.0, 0.5, 2.0, 10.0, -10.0, 100.0, 500.0, 501.0, 1e6, 1e6 + 1, -1e6, 1e-9, 1e300, -1e300,
          1.7976931348623157e308, 5e-324, -0.0, float("nan"), float("inf"), float("-inf"))
ENABLES = int(ControlDWord.Enable | ControlDWord.FeedEnablePlus | ControlDWord.FeedEnableMinus)
INTS = (0, 1, 2, 3, 5, 7, 8, 9, 15, 0xFF, 0x100, 1_000_000, 1_000_001, 999_999, 500_000, 2**31 - 1, 2**31,
        2**32 - 1, -1, -(2**31), ENABLES, ENABLES | int(ControlDWord.HomingSensor))
#: commands that make the NC read more of PLCTONC (axis, command, args)
SCENARIOS: tuple[tuple[tuple[int, str, dict[str, object]], ...], ...] = (
    (),
    ((1, "MoveVelocity", dict(Velocity=100.0)),),
    ((1, "ExtSetPointGenEnable", dict(Position=0.0, PositionType=1)),),
    ((2, "GearInDyn", dict(Master=1, GearRatio=0.5)), (1, "MoveVelocity", dict(Velocity=100.0))),
    ((1, "Home", dict(HomingMode=0)),),
    ((1, "TouchProbe", dict(EncoderID=1)), (1, "MoveAbsolute", dict(Position=200.0, Velocity=100.0))),
    ((4, "MoveModulo", dict(Position=270.0, Velocity=180.0, Direction=1)),),
    ((1, "MoveVelocity", dict(Velocity=100.0)),
     (1, "MoveSuperImposed", dict(Mode=1, Distance=10.0, VelocityDiff=20.0, Length=100.0, VelocityProcess=100.0))),
)
RAW, STRUCT, FIELD, STEPS, SILENT, COMMAND = range(6)
N_OPS = 6


def field_value(r: Reader, dt: np.dtype) -> object:
    """A value for a PLCTONC field of dtype ``dt``: from a table (even first byte) or raw."""
    table = r.u8() & 1 == 0
    if dt.kind == "f":
        return r.pick(LREALS) if table else r.f64()
    if dt.kind in "ui":
        v = r.pick(INTS) if table else int.from_bytes(r.take(dt.itemsize).ljust(dt.itemsize, b"\0"), "little")
        bits = 8 * dt.itemsize
        v &= (1 << bits) - 1
        if dt.kind == "i" and v >= 1 << (bits - 1):
            v -= 1 << bits
        return v
    return r.take(dt.itemsize)


def struct_frame(r: Reader) -> bytes:
    """PLC_FRAME_HEADER with each field right or fuzzed, then records."""
    n = r.u8() % 7
    flags = r.u8()
    h = np.zeros((), dtype=PLC_FRAME_HEADER_DTYPE)
    h["Magic"] = PLC_FRAME_MAGIC if flags & 1 == 0 else r.u32()
    h["Version"] = WIRE_VERSION if flags & 2 == 0 else r.u16()
    h["HeaderSize"] = PLC_FRAME_HEADER_DTYPE.itemsize if flags & 4 == 0 else r.u16()
    h["PlcCycle"] = r.u64()
    h["AxisCount"] = n if flags & 8 == 0 else r.u16()
    h["RecordSize"] = PLC_AXIS_RECORD_DTYPE.itemsize if flags & 16 == 0 else r.u16()
    recs = np.zeros(n, dtype=PLC_AXIS_RECORD_DTYPE)
    for k in range(n):
        recs[k]["AxisId"] = r.pick(AXIS_IDS) if r.u8() & 1 == 0 else r.u32()
        rec = recs[k]["PlcToNc"]
        rec["ControlDWord"] = ENABLES
        rec["Override"] = 1_000_000
        for _ in range(r.u8() % 4):
            name = r.pick(FIELDS)
            rec[name] = field_value(r, PLCTONC_DTYPE.fields[name][0])
    tail = r.take(r.u8() % 8) if flags & 32 else b""
    return h.tobytes() + recs.tobytes() + tail


class PlctoncNc(FuzzNc):
    """plc1's frames go through bytes and ``decode_plctonc``, as they do in nc-server."""

    def frame(self, client: str = HOLDER):  # type: ignore[no-untyped-def]
        ids = list(self.plc)
        recs = np.array(list(self.plc.values()), dtype=PLCTONC_DTYPE)
        return decode(encode_plc_frame(self.core.cycle, ids, recs), self.t)


def decode(payload: bytes, arrival: float):  # type: ignore[no-untyped-def]
    """``decode_plctonc``; None where it refuses the frame (ValueError, as documented)."""
    try:
        return decode_plctonc(payload, arrival, MAX_BYTES)
    except ValueError:
        return None


def run_scenario(nc: FuzzNc, k: int) -> None:
    for axis, cmd, args in SCENARIOS[k % len(SCENARIOS)]:
        nc.request(nc.key(cmd, axis), make_request(cmd, next(nc.ids), HOLDER, **args))


def test_one(data: bytes) -> None:
    r = Reader(data)
    setup = r.u8()
    nc = PlctoncNc(0.001 if setup & 0x80 else 0.01)
    run_scenario(nc, setup)
    steps = 0
    for _ in range(MAX_OPS):
        if r.left() <= 0:
            break
        op = r.u8() % N_OPS
        if op in (RAW, STRUCT):
            client = HOLDER if r.u8() % 4 else OTHER
            f = decode(r.blob() if op == RAW else struct_frame(r), nc.t)
            nc.step(frames=[(client, f)] if f is not None else [])
        elif op == FIELD:
            rec = nc.plc.get(r.pick(AXES))
            name = r.pick(FIELDS)
            v = field_value(r, PLCTONC_DTYPE.fields[name][0])
            if rec is not None:
                rec[name] = v
        elif op in (STEPS, SILENT):
            b = r.u8()
            n = min(1 + b % 64 if b < 224 else 100 * (b - 223), MAX_STEPS - steps)
            steps += n
            nc.step(n, feed=op == STEPS)
        else:
            run_scenario(nc, r.u8())
    nc.step(3)


def seeds() -> list[bytes]:
    out = []
    recs = np.zeros(len(AXES), dtype=PLCTONC_DTYPE)
    recs["ControlDWord"] = ENABLES
    recs["Override"] = 1_000_000
    frame = encode_plc_frame(1, AXES, recs)
    for k in range(len(SCENARIOS)):
        out.append(Writer().u8(k).u8(STEPS).u8(49).bytes())
        out.append(Writer().u8(k).u8(RAW).u8(1).blob(frame).u8(STEPS).u8(20).bytes())
        w = Writer().u8(k).u8(STRUCT).u8(1).u8(len(AXES)).u8(0).u64(7)
        for a in AXES:
            w.index(AXIS_IDS, a).u8(0)
        out.append(w.u8(STEPS).u8(20).bytes())
    # fields the NC reads in its scenarios: the external set-points, the gear ratio, the cam, override
    for k, name, value in ((2, "ExtSetPos", 1.0), (2, "ExtSetVelo", 100.0), (3, "GearRatio1", 2.0),
                           (4, "ControlDWord", ENABLES | int(ControlDWord.HomingSensor)), (1, "Override", 500_000),
                           (1, "ControlDWord", 0), (1, "PositionCorrection", 0.5)):
        w = Writer().u8(k).u8(STEPS).u8(20).u8(FIELD).index(AXES, 2 if name == "GearRatio1" else 1).index(FIELDS, name)
        dt = PLCTONC_DTYPE.fields[name][0]
        w.u8(1)
        if dt.kind == "f":
            w.f64(value)
        else:
            w.raw(int(value).to_bytes(dt.itemsize, "little"))
        out.append(w.u8(STEPS).u8(40).u8(SILENT).u8(60).bytes())
    return out


if __name__ == "__main__":
    main("plctonc", test_one, seeds)
