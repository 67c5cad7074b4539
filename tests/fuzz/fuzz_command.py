"""Fuzz target: command requests through ``RequestHandler.handle`` (every command door of the NC).

One input is a scenario on a fresh NC (:mod:`tests.fuzz._nc`: real NcCore, ClaimTable, Keys): a setup
byte (cycle time 10 ms or 1 ms, which axes plc1 claims and powers), then up to 24 operations:

* a raw request: a key from a table (every axis, class and client, plus malformed keys) and raw
  payload bytes;
* a structured request: a command of protocol.json on its own key (or another one, or a fuzzed
  string), a msgpack map whose fields are typed plausible values, raw numbers or hostile values
  (wrong types, NaN, huge integers, nested containers), some missing, some unknown, ids repeated
  (dedup); this gets the fuzzer past ``parse_request`` into the core's argument checks;
* NC cycles with plc1's PLCTONC, cycles without it (the watchdog), a changed ControlDWord/Override,
  a liveliness event.

After each request the reply must unpack with an error code or 0 (never 0x4000 NC_INTERNAL), no
exception may be logged, and ``core.step()`` must still run with finite outputs (see ``_nc``).

Run: ``python -m tests.fuzz.fuzz_command [libFuzzer args] [CORPUS_DIR | CRASH_FILE ...]``.
"""
from __future__ import annotations

import math
import sys

from tests.fuzz._runner import Reader, Writer, instrument, main

with instrument():
    import msgpack

    from nc_schema import COMMAND_CLASS, COMMANDS, Keys, MC_AxisPara, make_request
    from tests.fuzz import _layout
    from tests.fuzz._nc import AXES, CLIENTS, ENGINEER, HOLDER, FuzzNc, key_table

CMDS = sorted(COMMANDS)
MAX_OPS = 24
MAX_STEPS = 1000  # NC cycles per input (the -timeout catches a stall, this keeps inputs fast)
AXIS_CHOICES = (*AXES, None, 0, 5, 2**31, -1)
LREALS = (0.0, 1.0, -1.0, 0.5, 10.0, -10.0, 50.0, 100.0, -100.0, 250.0, 359.9, 360.0, 500.0, 720.0, 1000.0,
          -300.0, 5000.0, 50000.0, 1e6, 1e-9, -1e-9, 1e300, -1e300, 1.7976931348623157e308, 5e-324, -0.0, 0.001,
          499.99999999, 500.00000001, 2.0**53, 1e-300)
INTS = (0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 14, 18, 19, 20, 21, 255, 256, -1, 2**31 - 1, -(2**31), 65535,
        1_000_000, *sorted({int(v) for v in MC_AxisPara}))
BIG = (2**31, -(2**31) - 1, 2**53 + 1, 2**63 - 1, -(2**63), 2**64 - 1, 2**32)
CTRLS = (0, 1, 3, 5, 7, 15, 0xFF, 0xFFFFFFFF, 9, 11, 13)
OVERRIDES = (1_000_000, 0, 500_000, 1, 999_999, 1_000_001, 2_000_000, 0xFFFFFFFF, 100)
FIELDS = ("x", "position", "Axis", "", "id ", "CmdNo", "Value")
STRINGS = (*CLIENTS, "", "x" * 255, "x" * 256, "plc1\n", "*", "nc/nc1/client/plc1", "\u00e9")
KEYS = key_table(Keys("nc1"))

# op codes (the first byte of an operation, modulo len)
RAW, STRUCT, STEPS, PLCTONC, LIVELINESS, SILENT = range(6)
N_OPS = 6
# argument kinds (one byte each): < OMIT omitted, < TABLE from the type's table, < NUMBER raw, else hostile
OMIT, TABLE, NUMBER = 30, 150, 200


def hostile(r: Reader, depth: int = 0) -> object:
    """A value of any msgpack type, mostly wrong for wherever it goes."""
    t = r.u8() % 11
    if t == 0:
        return r.f64()
    if t == 1:
        return r.pick(LREALS)
    if t == 2:
        return r.pick(BIG)
    if t == 3:
        return bool(r.u8() & 1)
    if t == 4:
        return None
    if t == 5:
        return r.take(r.u8() % 32).decode("utf-8", "replace")
    if t == 6:
        return r.take(r.u8() % 16)
    if t == 7:
        return [hostile(r, depth + 1) for _ in range(r.u8() % 3)] if depth < 2 else []
    if t == 8:
        return {r.pick(FIELDS): hostile(r, depth + 1) for _ in range(r.u8() % 3)} if depth < 2 else {}
    if t == 9:
        return r.i32()
    return math.nan


def arg_value(r: Reader, typ: str) -> tuple[bool, object]:
    """(present, value) of one request argument of protocol type ``typ``."""
    k = r.u8()
    if k < OMIT:
        return False, None
    if typ == "STRING" and k < NUMBER:
        return True, r.pick(STRINGS) if k < TABLE else r.take(r.u8()).decode("utf-8", "replace")
    if k < TABLE:
        if typ == "INT":
            return True, r.pick(INTS)
        if typ == "BOOL":
            return True, bool(r.u8() & 1)
        if typ == "LREAL|BOOL":
            b = r.u8()
            return True, (bool(b & 1) if b & 2 else r.pick(LREALS))
        return True, r.pick(LREALS)
    if k < NUMBER:
        if typ == "INT":
            return True, r.i32()
        if typ == "BOOL":
            return True, bool(r.u8() & 1)
        return True, r.f64()
    return True, hostile(r)


def structured(nc: FuzzNc, r: Reader) -> None:
    cmd = r.pick(CMDS)
    spec = COMMANDS[cmd]
    axis = r.pick(AXIS_CHOICES)
    if spec.get("scope", "axis") == "nc" and r.u8() & 1:
        axis = None
    key_client = r.pick(CLIENTS)
    km = r.u8() % 8
    try:
        if km < 5:
            key = nc.key(cmd, axis, key_client)
        elif km == 5:
            key = _layout.class_key(nc.keys, axis if axis is None or axis >= 0 else 1,
                                    r.pick(_layout.CLASSES), key_client)
        elif km == 6:
            key = r.take(r.u8() % 48).decode("utf-8", "replace")
        else:
            key = r.pick(KEYS)
    except (ValueError, TypeError, KeyError):  # a key the client side cannot even build
        key = r.pick(KEYS)
    msg: dict[object, object] = {}
    im = r.u8() % 8
    msg["id"] = next(nc.ids) if im < 6 else (r.u8() % 4 if im == 6 else hostile(r))
    cm = r.u8() % 8
    if cm in (1, 2, 3, 4):
        msg["client"] = key_client
    elif cm == 5:
        msg["client"] = r.pick(CLIENTS + ("",))
    elif cm == 6:
        msg["client"] = hostile(r)
    msg["cmd"] = cmd if r.u8() % 16 else hostile(r)
    for name, aspec in spec["args"].items():
        present, v = arg_value(r, aspec["type"])
        if present:
            msg[name] = v
    if r.u8() % 16 == 0:
        msg[r.pick(FIELDS)] = hostile(r)
    try:
        payload = msgpack.packb(msg, use_bin_type=True)
    except (OverflowError, TypeError, ValueError):  # nothing a client could send
        return
    nc.request(key, payload)


def test_one(data: bytes) -> None:
    r = Reader(data)
    setup = r.u8()
    held = [a for k, a in enumerate(AXES) if not setup >> k & 1]
    nc = FuzzNc(0.001 if setup & 0x10 else 0.01, held)
    steps = 0
    for _ in range(MAX_OPS):
        if r.left() <= 0:
            break
        op = r.u8() % N_OPS
        if op == RAW:
            nc.request(r.pick(KEYS), r.blob())
        elif op == STRUCT:
            structured(nc, r)
        elif op in (STEPS, SILENT):
            b = r.u8()
            n = min(1 + b % 64 if b < 224 else 100 * (b - 223), MAX_STEPS - steps)
            steps += n
            nc.step(n, feed=op == STEPS)
        elif op == PLCTONC:
            a = r.pick(AXES)
            rec = nc.plc.get(a)
            b = r.u8()
            if rec is not None:
                rec["ControlDWord"] = r.pick(CTRLS) if b & 1 else r.u32()
                rec["Override"] = r.pick(OVERRIDES) if b & 2 else r.u32()
        else:
            client = r.pick(CLIENTS)
            if r.u8() & 1:
                nc.handler.client_alive(client)
                nc.feeding = nc.feeding or client == HOLDER
            else:
                nc.handler.client_gone(client)
                nc.feeding = nc.feeding and client != HOLDER
    nc.step(3)


# ---- seeds: valid scenarios ------------------------------------------------------------------
#: plausible arguments per command (axis, args); others get 10.0 / 1 / True for required args
SAMPLES: dict[str, tuple[int, dict[str, object]]] = {
    "MoveAbsolute": (1, dict(Position=100.0, Velocity=200.0)),
    "MoveRelative": (2, dict(Distance=50.0, Velocity=100.0, BufferMode=1)),
    "MoveAdditive": (1, dict(Distance=20.0, Velocity=100.0)),
    "MoveModulo": (4, dict(Position=90.0, Velocity=180.0, Direction=2)),
    "MoveVelocity": (1, dict(Velocity=100.0, Direction=1)),
    "MoveContinuousAbsolute": (1, dict(Position=200.0, Velocity=200.0, EndVelocity=50.0)),
    "MoveContinuousRelative": (2, dict(Distance=100.0, Velocity=100.0, EndVelocity=20.0)),
    "MoveAbsoluteOrRestart": (1, dict(Position=300.0, Velocity=100.0)),
    "Halt": (1, dict(Deceleration=1000.0, Jerk=10000.0)),
    "Stop": (1, {}),
    "SetOverride": (1, dict(Override=50.0)),
    "ReadParameter": (1, dict(ParameterNumber=9)),
    "WriteParameter": (1, dict(ParameterNumber=9, Value=400.0)),
    "NewPos": (1, dict(NewPos=50.0)),
    "NewPosAndVelo": (1, dict(Mode=3, NewPos=80.0, NewVelo=150.0)),
    "ChangeDynParam": (1, dict(Acceleration=2000.0, Deceleration=2000.0, Jerk=20000.0)),
    "Jog": (1, dict(Mode=3, Direction=1, Position=5.0, Velocity=50.0)),
    "Home": (1, dict(HomingMode=4, Position=0.0)),
    "OrientedStop": (4, dict(Position=90.0)),
    "SetActualPosition": (1, dict(Position=10.0)),
    "SetActualPositionOnTheFly": (1, dict(ActualPosition=5.0, PreviousPosition=0.0)),
    "SetReferenceFlag": (1, dict(ReferenceFlag=True)),
    "GearIn": (2, dict(Master=1, RatioNumerator=1, RatioDenominator=2)),
    "GearInFloat": (2, dict(Master=1, GearRatio=0.5)),
    "GearInDyn": (2, dict(Master=1, GearRatio=0.5)),
    "GearOutExt": (2, dict(Mode=1, Position=20.0, Velocity=50.0)),
    "MoveSuperImposed": (1, dict(Mode=4, Distance=5.0, VelocityDiff=20.0, Length=100.0, VelocityProcess=50.0)),
    "ExtSetPointGenEnable": (1, dict(Position=0.0, PositionType=1)),
    "TouchProbe": (1, dict(EncoderID=1, TouchProbe=1, Edge=0)),
    "SimProbeSignal": (1, dict(Level=True, Offset=0.0)),
}
_DEFAULT = {"LREAL": 10.0, "INT": 1, "BOOL": True, "LREAL|BOOL": 1.0, "STRING": "plc2"}


def sample(cmd: str) -> tuple[int | None, dict[str, object]]:
    if cmd in SAMPLES:
        return SAMPLES[cmd]
    spec = COMMANDS[cmd]
    axis = None if spec.get("scope", "axis") == "nc" else 1
    return axis, {n: _DEFAULT[a["type"]] for n, a in spec["args"].items() if a.get("required")}


def w_struct(w: Writer, cmd: str, axis: int | None = None, args: dict[str, object] | None = None,
             client: str | None = None) -> Writer:
    """A structured request exactly as ``structured`` reads it (valid, on its own key; by plc1, or
    eng1 for an engineer's command)."""
    client = client or (ENGINEER if COMMAND_CLASS[cmd] == "eng" else HOLDER)
    a0, a1 = sample(cmd)
    axis = a0 if axis is None else axis
    args = a1 if args is None else args
    w.u8(STRUCT).index(CMDS, cmd).index(AXIS_CHOICES, axis)
    if COMMANDS[cmd].get("scope", "axis") == "nc":
        w.u8(1 if axis is None else 0)
    w.index(CLIENTS, client).u8(0)  # key: its own
    w.u8(0).u8(1).u8(1)  # a fresh id, client = the key's, cmd
    for name, aspec in COMMANDS[cmd]["args"].items():
        if name not in args:
            w.u8(0)
            continue
        v = args[name]
        if aspec["type"] == "STRING":
            b = str(v).encode()
            w.u8(TABLE).u8(len(b)).raw(b)  # raw text
            continue
        w.u8(NUMBER - 1)  # a raw number
        if aspec["type"] == "INT":
            w.i32(int(v))  # type: ignore[arg-type]
        elif aspec["type"] == "BOOL" or isinstance(v, bool):
            w.u8(int(bool(v)))
        else:
            w.f64(float(v))  # type: ignore[arg-type]
    return w.u8(1)  # no unknown field


def w_steps(w: Writer, n: int, feed: bool = True) -> Writer:
    return w.u8(STEPS if feed else SILENT).u8(n - 1 if n <= 64 else 223 + max(1, n // 100))


def w_raw(w: Writer, cmd: str, client: str | None = None) -> Writer:
    client = client or (ENGINEER if COMMAND_CLASS[cmd] == "eng" else HOLDER)
    axis, args = sample(cmd)
    key = _layout.command_key(Keys("nc1"), cmd, axis, client)
    return w.u8(RAW).index(KEYS, key).blob(make_request(cmd, 7, client, **args))


def seeds() -> list[bytes]:
    out = []
    for cmd in CMDS:
        out.append(w_steps(w_struct(Writer().u8(0), cmd), 20).bytes())
        out.append(w_steps(w_raw(Writer().u8(0), cmd), 5).bytes())
    scen = [
        [("MoveAbsolute", 1, None), 80, ("NewPos", 1, None), 50, ("Halt", 1, None), 100],
        [("MoveVelocity", 1, None), 100, ("Stop", 1, None), 100, ("StopRelease", 1, {}), ("Reset", 1, {}), 10],
        [("GearIn", 2, None), ("MoveVelocity", 1, None), 300, ("MoveSuperImposed", 2,
                                                                dict(Mode=1, Distance=5.0, VelocityDiff=20.0, Length=100.0,
                                                                     VelocityProcess=50.0)),
         100, ("GearOutExt", 2, None), 100],
        [("GearInDyn", 2, None), ("MoveAbsolute", 1, None), 200, ("GearOut", 2, {}), 50],
        [("MoveModulo", 4, None), 100, ("OrientedStop", 4, None), 300],
        [("ExtSetPointGenEnable", 1, None), 100, ("ExtSetPointGenDisable", 1, {}), 10],
        [("TouchProbe", 1, None), ("MoveVelocity", 1, None), 50, ("SimProbeSignal", 1, None), 5,
         ("SimProbeSignal", 1, dict(Level=False)), 5, ("AbortTrigger", 1, {}), 5],
        [("MoveAbsolute", 1, dict(Position=100.0, Velocity=100.0, BufferMode=0)),
         ("MoveRelative", 1, dict(Distance=50.0, Velocity=100.0, BufferMode=18)), 500],
        [("Jog", 1, dict(Mode=0, Direction=1)), 100, ("Halt", 1, {}), 100],
        [("Home", 1, dict(HomingMode=0)), 500],
        [("WriteParameter", 3, dict(ParameterNumber=9, Value=100.0)), ("ReadParameter", 3, dict(ParameterNumber=9)),
         ("MoveVelocity", 3, dict(Velocity=90.0, Direction=3)), 200],
        [("Claim", 1, {}), ("Release", 1, {}), ("Info", None, {}), 5],
        [("MoveVelocity", 1, None), 20, ("HandOver", 1, dict(To="plc2")), 20, ("Claim", 2, {}, "plc2"), 20],
        [("MoveContinuousAbsolute", 1, None), ("ChangeDynParam", 1, None), 300,
         ("NewPosAndVelo", 1, dict(Mode=9, NewPos=400.0, NewVelo=80.0, ActivationPos=250.0)), 300],
        [("MoveVelocity", 1, None), 50, ("SetActualPositionOnTheFly", 1, None), ("SetOverride", 1, None), 100],
    ]
    for sc in scen:
        w = Writer().u8(0)
        for item in sc:
            if isinstance(item, int):
                w_steps(w, min(item, 60))  # short: the seeds run at every start (make test)
            else:
                w_struct(w, *item)
        out.append(w.bytes())
    # the watchdog: plc1 falls silent while moving; another client's commands
    w = w_struct(Writer().u8(0), "MoveVelocity")
    w_steps(w_steps(w, 20), 100, feed=False)
    out.append(w_struct(w, "Reset", 1, {}).bytes())
    w = w_struct(Writer().u8(0), "MoveVelocity", client="plc2")
    w.u8(LIVELINESS).index(CLIENTS, HOLDER).u8(0)
    out.append(w_steps(w, 100).bytes())
    w = Writer().u8(0).u8(PLCTONC).index(AXES, 1).u8(3).index(CTRLS, 1).index(OVERRIDES, 500_000)
    out.append(w_steps(w_struct(w, "MoveAbsolute"), 50).bytes())
    return out


if __name__ == "__main__":
    main("command", test_one, seeds)
