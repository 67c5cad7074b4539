"""MC_GearIn / MC_GearInFloat / MC_GearInDyn / MC_GearOut / MC_GearOutExt through the real distributed
path: an ``nc-server`` process (default configuration: axes 1, 2 linear with AxisVeloMax 500, axis 3
with -300..5 and AxisAcc 2500) and a ``plc-run`` process on 127.0.0.1, free ports, both killed with
their process groups at the end, pass or fail.

The PLC program is :data:`EXT_AGENT` (written to a temporary file): plc_agent.py's protocol plus the
VAR_IN_OUT arguments the coupling, probe and external set-point blocks need (``refs``: Master,
Slave, TriggerInput) and per-cycle *hooks*: Python code the test sends, run in every PLC cycle
inside the PLC program (a gear check, a set-point ramp, a PlcEvent signal), which reports with
block-like records. :class:`ExtPlc` and the fixture ``xplc`` are shared with
test_plc_superposition_probe.py.

As in test_plc_blocks_engine.py: positions, relations between the axes of one NC frame and the
order of the outputs are asserted, never how fast anything happened (the simulated axes move by
NC cycles, the wall clock of a loaded 2-core machine is not theirs).
"""
from __future__ import annotations

import math
import os
import re
import signal
from pathlib import Path
from typing import Any, Callable, Iterator

import pytest

from znc_testing import plc_harness
from znc_testing.plc_harness import STALE_ARGS, T, PlcProcess, Rec, ended, exclusive
from znc_testing import NcServerProcess

# ---- the PLC program --------------------------------------------------------------------------
EXT_AGENT = r'''
"""plc_agent.py's protocol (set/del/sync/trace/exit, the same records) plus:

* ``set`` takes ``refs``, VAR_IN_OUT arguments by name: an int is the AXIS_REF of that AxisId
  (Master, Slave, AxisRefOut), a str the MC_InputRef of that name (TriggerInput). A block given a
  ``Slave`` is called without ``Axis``, and its records carry the slave's data;
* ``{"op": "iref", "name": n, "fields": {...}}`` creates MC_InputRef ``n`` or sets its fields;
* ``{"op": "hook", "name": n, "src": code, "env": {...}}`` runs ``code`` in every PLC cycle before
  the blocks, in a namespace kept between cycles (preset with ``env``) offering ``ax(id)``,
  ``fb(name)``, ``iref(name)``, ``emit(**values)`` (prints the record ``{"c", "n": n, "o": values,
  "a": {}}``), ``Feed`` (MC_ExtSetPointGenFeed), ``now()`` (time.monotonic), ``math``, ``plc``;
  ``{"op": "var", "name": n, "values": {...}}`` sets variables of its namespace,
  ``{"op": "unhook", "name": n}``. A hook that raises is removed; it emits ``{"raised": text}``;
* the axis data also carry SetAcc, CoupleState, AxisState, StateDWord, TouchProbeState, CmdNo.
"""
import json
import math
import queue
import sys
import threading
import time
import traceback

import plc_client
from plc_client import AXIS_REF, MC_ExtSetPointGenFeed, MC_InputRef

_inbox = queue.SimpleQueue()


def _reader():
    for line in sys.stdin:
        line = line.strip()
        if line:
            try:
                _inbox.put(json.loads(line))
            except ValueError:
                print(json.dumps({"bad": line}), flush=True)


threading.Thread(target=_reader, daemon=True, name="agent-stdin").start()


def _plain(v):
    if isinstance(v, bool) or v is None or isinstance(v, (int, float, str)):
        return v
    try:
        return float(v)
    except (TypeError, ValueError):
        return str(v)


def _state(ax):
    st = ax.Status
    return {"Valid": st.Valid, "State": st.MotionState.name[13:], "Locked": st.MotionCommandsLocked,
            "ErrorId": st.ErrorId, "Homed": st.Homed}


def _data(ax, state):
    rec = ax.NcToPlc
    return {**state, "ActPos": float(rec["ActPos"]), "SetPos": float(rec["SetPos"]),
            "SetVelo": float(rec["SetVelo"]), "SetAcc": float(rec["SetAcc"]),
            "NcCycle": int(ax.Status.NcCycleCounter), "CoupleState": int(rec["CoupleState"]),
            "AxisState": int(rec["AxisState"]), "StateDWord": int(rec["StateDWord"]),
            "TouchProbeState": int(rec["TouchProbeState"]), "CmdNo": int(rec["CmdNo"])}


class Program:
    def __init__(self):
        self.blocks = {}   # name -> [fb, axis, refs, inputs]
        self.axes = {}
        self.irefs = {}
        self.hooks = {}    # name -> (code, namespace)
        self.last = {}
        self.traced = set()
        self.plc = None

    def ax(self, axis_id, nc="nc1"):
        key = (nc, int(axis_id))
        if key not in self.axes:
            self.axes[key] = AXIS_REF(nc=nc, axis_id=int(axis_id))
        ax = self.axes[key]
        if ax.task is None:
            self.plc.register(ax)
        return ax

    def _ref(self, v, nc):
        if isinstance(v, str):
            return self.irefs[v]
        return self.ax(v, nc)

    def _emitter(self, name):
        def emit(**values):
            print(json.dumps({"c": self.plc.cycle, "n": name, "o": {k: _plain(v) for k, v in values.items()},
                              "a": {}}), flush=True)
        return emit

    def cycle(self, plc):
        self.plc = plc
        while True:
            try:
                msg = _inbox.get_nowait()
            except queue.Empty:
                break
            op = msg.get("op")
            nc = msg.get("nc", "nc1")
            if op == "set":
                name = msg["name"]
                if name not in self.blocks:
                    fb = getattr(plc_client, msg["fb"])(**msg.get("init", {}))
                    self.blocks[name] = [fb, self.ax(int(msg.get("axis", 1)), nc), {}, {}]
                b = self.blocks[name]
                b[2].update({k: self._ref(v, nc) for k, v in (msg.get("refs") or {}).items()})
                b[3].update(msg.get("inputs", {}))
            elif op == "del":
                self.blocks.pop(msg["name"], None)
            elif op == "iref":
                ref = self.irefs.setdefault(msg["name"], MC_InputRef())
                for k, v in msg.get("fields", {}).items():
                    setattr(ref, k, v)
            elif op == "hook":
                name = msg["name"]
                ns = {"ax": self.ax, "fb": lambda n: self.blocks[n][0], "iref": self.irefs.get,
                      "emit": self._emitter(name), "Feed": MC_ExtSetPointGenFeed, "now": time.monotonic,
                      "math": math, "plc": plc, **msg.get("env", {})}
                self.hooks[name] = (compile(msg["src"], f"<hook {name}>", "exec"), ns)
            elif op == "unhook":
                self.hooks.pop(msg["name"], None)
            elif op == "var":
                self.hooks[msg["name"]][1].update(msg.get("values", {}))
            elif op == "trace":
                key = (nc, int(msg.get("axis", 1)))
                if msg.get("on", True):
                    self.ax(key[1], nc)
                    self.traced.add(key)
                else:
                    self.traced.discard(key)
            elif op == "sync":
                print(json.dumps({"c": plc.cycle, "sync": msg["id"]}), flush=True)
                break
            elif op == "exit":
                raise SystemExit("agent exit requested")
        for name, (code, ns) in list(self.hooks.items()):
            try:
                exec(code, ns)
            except Exception:
                self.hooks.pop(name, None)
                self._emitter(name)(raised=traceback.format_exc())
        for name, (fb, ax, refs, inputs) in self.blocks.items():
            if "Slave" in refs:
                fb(**refs, **inputs)
                ax = refs["Slave"]
            else:
                fb(Axis=ax, **refs, **inputs)
            out = {k: _plain(getattr(fb, k)) for k in fb._OUTPUTS}
            axis = _state(ax)
            key = json.dumps([out, axis], sort_keys=True)
            if self.last.get(name) != key:
                self.last[name] = key
                print(json.dumps({"c": plc.cycle, "n": name, "o": out, "a": _data(ax, axis)}), flush=True)
        for nc, axis_id in self.traced:
            ax = self.axes[(nc, axis_id)]
            print(json.dumps({"c": plc.cycle, "tr": axis_id, "a": _data(ax, _state(ax))}), flush=True)
        if plc.cycle % 50 == 0:
            print(json.dumps({"c": plc.cycle, "tick": True}), flush=True)
'''


class ExtPlc(PlcProcess):
    """A ``plc-run`` process running :data:`EXT_AGENT` (written to ``program``); the records and
    waits of :class:`plc_harness.PlcProcess`, plus ``refs``, hooks and MC_InputRefs."""

    def __init__(self, endpoint: str, client_id: str, program: Path, nc: str = "nc1",
                 extra: list[str] | None = None) -> None:
        program.write_text(EXT_AGENT)
        # PlcProcess runs plc_harness.AGENT: point it at our program while the process starts
        saved = plc_harness.AGENT
        plc_harness.AGENT = program
        try:
            super().__init__(endpoint, client_id, nc, extra)
        finally:
            plc_harness.AGENT = saved

    def set(self, name: str, fb: str | None = None, axis: int = 1, nc: str = "nc1",  # type: ignore[override]
            init: dict[str, Any] | None = None, refs: dict[str, int | str] | None = None, **inputs: Any) -> None:
        msg: dict[str, Any] = {"op": "set", "name": name, "axis": axis, "nc": nc, "inputs": inputs}
        if fb:
            msg["fb"] = fb
        if init:
            msg["init"] = init
        if refs:
            msg["refs"] = refs
        self._send(msg)

    def iref(self, name: str, **fields: Any) -> None:
        self._send({"op": "iref", "name": name, "fields": fields})

    def hook(self, name: str, src: str, **env: Any) -> None:
        self._send({"op": "hook", "name": name, "src": src, "env": env})

    def var(self, name: str, **values: Any) -> None:
        """Set variables of hook ``name``'s namespace (from its next run on)."""
        self._send({"op": "var", "name": name, "values": values})

    def unhook(self, name: str) -> None:
        self._send({"op": "unhook", "name": name})

    def hook_records(self, name: str) -> list[Rec]:
        recs = self.history(name)
        raised = [r for r in recs if "raised" in r.o]
        assert not raised, raised[0].o["raised"]
        return recs


def axis_config(text: str, axis_id: int, **params: Any) -> str:
    """``text`` (an nc-server TOML) with ``params`` set in the [[axis]] table of ``axis_id``."""
    head, *tables = text.split("[[axis]]")
    for k, t in enumerate(tables):
        if re.search(rf"^AxisId = {axis_id}\s*$", t, re.M):
            for key, value in params.items():
                v = ("true" if value else "false") if isinstance(value, bool) else repr(float(value))
                line = f"{key} = {v}"
                t, n = re.subn(rf"^{key} = .*$", line, t, flags=re.M)
                if not n:
                    t = t.rstrip("\n") + f"\n{line}\n\n"
            tables[k] = t
            return "[[axis]]".join([head, *tables])
    raise KeyError(f"no axis {axis_id}")


@pytest.fixture
def xplc(tmp_path: Path) -> Iterator[Callable[..., ExtPlc]]:
    """``xplc(nc, client_id="plc-x")`` -> a started :class:`ExtPlc`; every one is stopped (its
    process group killed) at the end, pass or fail."""
    started: list[ExtPlc] = []

    def make(nc: NcServerProcess, client_id: str = "plc-x") -> ExtPlc:
        p = ExtPlc(nc.endpoint, client_id, tmp_path / f"ext_agent_{len(started)}.py", extra=list(STALE_ARGS))
        started.append(p)
        p.wait_started()
        return p

    try:
        yield make
    finally:
        for p in started:
            p.stop()


@pytest.fixture
def xp(nc: NcServerProcess, xplc: Callable[..., ExtPlc]) -> ExtPlc:
    """An ExtPlc against the default ``nc`` fixture."""
    return xplc(nc)


# ---- helpers ------------------------------------------------------------------------------------
SLAVE, MASTER = 3, 1  # CoupleState
SYNCHRON = 13  # AxisState SLAVE_SYNCHRON
CONSTANT_VELOCITY, CONTINUOUS_MOTION, HAS_JOB = 1 << 12, 1 << 19, 1 << 8
#: target window of axes 1 and 2
WINDOW = 0.02
#: moderate dynamics for the masters: ratio x master stays within every slave's limits
DYN = {"Acceleration": 1000.0, "Deceleration": 1000.0}

#: every PLC cycle: slave SetPos against s0 + R * (master SetPos - m0) of the same NC frame, from
#: the first cycle the slave shows itself coupled and synchronous (s0, m0 = the positions then)
GEAR_CHECK = """
m, s = ax(M), ax(S)
if m.Status.Valid and s.Status.Valid:
    mr, sr = m.NcToPlc, s.NcToPlc
    coupled = int(sr["CoupleState"]) == 3 and int(sr["AxisState"]) == 13
    if base is None and coupled:
        base = (float(sr["SetPos"]), float(mr["SetPos"]))
    if base is not None:
        emit(m=float(mr["SetPos"]), s=float(sr["SetPos"]), vm=float(mr["SetVelo"]), vs=float(sr["SetVelo"]),
             err=float(sr["SetPos"]) - (base[0] + R * (float(mr["SetPos"]) - base[1])),
             verr=float(sr["SetVelo"]) - R * float(mr["SetVelo"]),
             nc=int(s.Status.NcCycleCounter), mnc=int(m.Status.NcCycleCounter), coupled=coupled,
             mcs=int(mr["CoupleState"]), s0=base[0], m0=base[1])
"""


def gear_in(p: ExtPlc, name: str, fb: str, master: int, slave: int, **inputs: Any) -> Rec:
    """Start ``fb`` (a gear-in block) ``name`` coupling ``slave`` to ``master``; returns its InGear record."""
    p.set(name, fb, refs={"Master": master, "Slave": slave}, Execute=True, **inputs)
    r = p.wait(name, lambda r: r.o["InGear"] or ended(r), T)
    assert r.o["InGear"] and r.o["Busy"], (r, p.history(name))
    return r


def check_gearing(recs: list[Rec], tol: float = 1e-9) -> None:
    """Every PLC cycle's check: the slave at s0 + R (master - m0), velocity R x master's, one NC frame."""
    assert recs, "no gear check ran"
    for r in recs:
        assert r.o["nc"] == r.o["mnc"], f"two NC frames in one PLC cycle: {r}"
        assert abs(r.o["err"]) <= tol, f"slave off its master: {r}"
        assert abs(r.o["verr"]) <= 1e-9 * max(1.0, abs(r.o["vm"])), f"slave velocity off: {r}"


def clean(recs: list[Rec]) -> None:
    """The output rules held; no Error, no CommandAborted."""
    exclusive(recs)
    assert not any(r.o.get("Error") or r.o.get("CommandAborted") for r in recs), recs


def power_both(p: ExtPlc, *axes: int) -> None:
    for a in axes:
        p.set(f"pw{a}", "MC_Power", axis=a, Enable=True, Enable_Positive=True, Enable_Negative=True)
    for a in axes:
        p.wait(f"pw{a}", lambda r: r.o["Status"], T)


# ---- MC_GearIn ----------------------------------------------------------------------------------
def test_gear_in_slave_follows_the_master_every_plc_cycle(xp: ExtPlc) -> None:
    power_both(xp, 1, 2)
    xp.hook("chk", GEAR_CHECK, M=1, S=2, R=0.5, base=None)
    gi = gear_in(xp, "gi", "MC_GearIn", 1, 2, RatioNumerator=1, RatioDenominator=2)
    # the slave's NcToPlc shows the coupling when the block is InGear
    assert gi.a["CoupleState"] == SLAVE and gi.a["AxisState"] == SYNCHRON, gi
    assert gi.a["State"] == "SYNCHRONIZEDMOTION", gi
    first = xp.wait("chk", lambda r: True, T)
    assert first.o["mcs"] == MASTER, f"the master shows CoupleState MASTER: {first}"
    m0, s0 = first.o["m0"], first.o["s0"]
    xp.set("mv", "MC_MoveAbsolute", axis=1, Execute=True, Position=m0 + 100.0, Velocity=200.0, **DYN)
    mv = xp.wait("mv", ended, T)
    assert mv.o["Done"], (mv, xp.history("mv"))
    end = xp.wait("chk", lambda r: r.c >= mv.c and r.o["vm"] == 0.0, T)
    recs = xp.hook_records("chk")
    moving = [r for r in recs if r.o["vm"] != 0.0]
    assert len(moving) >= 10 and max(r.o["vm"] for r in moving) > 100.0, "compared while the master moved"
    check_gearing(recs)
    assert math.isclose(end.o["m"], m0 + 100.0, abs_tol=1e-9) and math.isclose(end.o["s"], s0 + 50.0, abs_tol=1e-9), end
    # still coupled, the block still InGear and Busy (it is responsible for the coupling)
    xp.wait_cycles(5)
    last = xp.last("gi")
    assert last.o["InGear"] and last.o["Busy"] and last.a["CoupleState"] == SLAVE, last
    clean(xp.history("gi"))
    clean(xp.history("mv"))


def test_gear_in_float_negative_ratio(xp: ExtPlc) -> None:
    power_both(xp, 1, 3)  # slave Z: soft limits -300..5, so it must go negative
    xp.hook("chk", GEAR_CHECK, M=1, S=3, R=-0.5, base=None)
    gi = gear_in(xp, "gf", "MC_GearInFloat", 1, 3, GearRatio=-0.5)
    assert gi.a["CoupleState"] == SLAVE and gi.a["AxisState"] == SYNCHRON, gi
    first = xp.wait("chk", lambda r: True, T)
    xp.set("mv", "MC_MoveAbsolute", axis=1, Execute=True, Position=first.o["m0"] + 80.0, Velocity=200.0, **DYN)
    mv = xp.wait("mv", ended, T)
    assert mv.o["Done"], mv
    end = xp.wait("chk", lambda r: r.c >= mv.c and r.o["vm"] == 0.0, T)
    recs = xp.hook_records("chk")
    check_gearing(recs)
    assert min(r.o["vs"] for r in recs) < -50.0, "the slave moved against its master"
    assert math.isclose(end.o["s"], first.o["s0"] - 40.0, abs_tol=1e-9), end
    clean(xp.history("gf"))


def test_gear_in_dyn_ratio_changed_while_moving(xp: ExtPlc) -> None:
    power_both(xp, 1, 2)
    gi = gear_in(xp, "gd", "MC_GearInDyn", 1, 2, GearRatio=0.5)
    xp.trace(2)
    xp.set("mv", "MC_MoveVelocity", axis=1, Execute=True, Velocity=100.0, **DYN)
    iv = xp.wait("mv", lambda r: r.o["InVelocity"] or ended(r), T)
    assert iv.o["InVelocity"], iv
    s = xp.wait_trace(2, lambda s: s.c > iv.c and abs(s.a["SetVelo"] - 50.0) < 1e-6, T)
    # a new ratio while Execute stays TRUE: taken every cycle (within the ratio's rate limit)
    xp.set("gd", GearRatio=0.8)
    s = xp.wait_trace(2, lambda s: abs(s.a["SetVelo"] - 80.0) < 1e-6, T)
    assert s.a["CoupleState"] == SLAVE, s
    hist = xp.history("gd")
    assert all(r.o["Busy"] for r in hist if r.c >= gi.c), "Busy while Execute is TRUE"
    assert max(abs(x.a["SetVelo"]) for x in xp.trace_of(2)) <= 80.0 + 1e-6, "no overshoot of ratio x master"
    # the falling edge ends the block (no result output); the coupling keeps the last ratio
    c = xp.sync()
    xp.set("gd", Execute=False)
    off = xp.wait("gd", lambda r: r.c > c and not r.o["Busy"], T)
    assert not off.o["InGear"] and not off.o["Error"] and not off.o["CommandAborted"], off
    xp.wait_cycles(20)
    later = [x for x in xp.trace_of(2) if x.c > off.c]
    assert len(later) >= 10, later
    for x in later:
        assert x.a["CoupleState"] == SLAVE and abs(x.a["SetVelo"] - 80.0) < 1e-6, f"the ratio stays 0.8: {x}"
    clean(xp.history("gd"))


# ---- MC_GearOut, MC_GearOutExt -----------------------------------------------------------------
def test_gear_out_of_a_moving_slave_continues_at_constant_velocity(xp: ExtPlc) -> None:
    power_both(xp, 1, 2)
    gear_in(xp, "gi", "MC_GearIn", 1, 2, RatioNumerator=1, RatioDenominator=2)
    xp.trace(2)
    xp.set("mv", "MC_MoveVelocity", axis=1, Execute=True, Velocity=100.0, **DYN)
    iv = xp.wait("mv", lambda r: r.o["InVelocity"] or ended(r), T)
    assert iv.o["InVelocity"], iv
    xp.wait_trace(2, lambda s: s.c > iv.c and abs(s.a["SetVelo"] - 50.0) < 1e-9, T)
    xp.set("go", "MC_GearOut", refs={"Slave": 2}, Execute=True)
    go = xp.wait("go", ended, T)
    assert go.o["Done"] and go.a["CoupleState"] == 0, f"Done shows the slave decoupled: {go}"
    # the gear-in block ends with InGear as its result (Execute still TRUE): Busy falls, no Error,
    # no CommandAborted
    gi = xp.wait("gi", lambda r: not r.o["Busy"], T)
    assert gi.o["InGear"] and not gi.o["CommandAborted"] and not gi.o["Error"], gi
    clean(xp.history("gi"))
    clean(xp.history("go"))
    # the slave goes on at the velocity it had (master at constant velocity: exactly 50)
    xp.wait_cycles(20)
    later = [s for s in xp.trace_of(2) if s.c > go.c + 2]
    assert len(later) >= 10, later
    for s in later:
        assert abs(s.a["SetVelo"] - 50.0) < 1e-9 and s.a["CoupleState"] == 0, s
        assert s.a["StateDWord"] & CONTINUOUS_MOTION and s.a["StateDWord"] & CONSTANT_VELOCITY, s
        assert s.a["State"] == "CONTINOUSMOTION", s
    assert later[-1].a["SetPos"] > later[0].a["SetPos"], "moving"
    assert not any(ended(r) for r in xp.history("mv") if not r.o["InVelocity"]), "the master goes on"


def test_gear_out_ext_newpos_ends_at_position(xp: ExtPlc) -> None:
    power_both(xp, 1, 2)
    gear_in(xp, "gi", "MC_GearIn", 1, 2, RatioNumerator=1, RatioDenominator=2)
    xp.trace(2)
    # slow (the slave at 10 u/s): the decoupling has 5.5 s to land before the slave passes 60
    xp.set("mv", "MC_MoveVelocity", axis=1, Execute=True, Velocity=20.0, **DYN)
    xp.wait_trace(2, lambda s: s.a["SetPos"] > 5.0 and abs(s.a["SetVelo"] - 10.0) < 1e-9, T)
    xp.set("goe", "MC_GearOutExt", refs={"Slave": 2}, Execute=True, Mode=4, Position=90.0)  # NEWPOS
    busy = xp.wait("goe", lambda r: r.o["Busy"] or ended(r), T)
    assert busy.a["SetPos"] < 60.0, f"issued too late for the test: {busy}"
    r = xp.wait("goe", ended, T)
    assert r.o["Done"], (r, xp.history("goe"))
    assert abs(r.a["ActPos"] - 90.0) <= WINDOW and math.isclose(r.a["SetPos"], 90.0, abs_tol=1e-9), r
    assert r.a["CoupleState"] == 0 and r.a["State"] == "STANDSTILL", r
    clean(xp.history("goe"))
    gi = xp.last("gi")
    assert not gi.o["Busy"] and gi.o["InGear"] and not gi.o["CommandAborted"], gi  # (the coupling's result)
    clean(xp.history("gi"))
    # seamless: no velocity step of the slave at the decoupling (PLC samples 10 NC cycles apart)
    tr = xp.trace_of(2)
    for a, b in zip(tr, tr[1:]):
        dt = (b.a["NcCycle"] - a.a["NcCycle"]) * 0.001
        assert abs(b.a["SetVelo"] - a.a["SetVelo"]) <= 5000.0 * dt * (1 + 1e-6) + 1e-6, (a, b)


# ---- refusals, MC_Stop ------------------------------------------------------------------------
def test_refused_couplings_and_commands_to_a_slave(xp: ExtPlc) -> None:
    power_both(xp, 1, 2)
    xp.set("bad", "MC_GearIn", refs={"Master": 1, "Slave": 2}, Execute=True, RatioNumerator=1, RatioDenominator=0)
    r = xp.wait("bad", ended, T)
    assert r.o["Error"] and r.o["ErrorID"] == 0x4B06 and not r.o["InGear"], r
    assert r.a["CoupleState"] == 0, "nothing coupled"
    gi = gear_in(xp, "gi", "MC_GearIn", 1, 2, RatioNumerator=1, RatioDenominator=2)
    # a motion command to the coupled slave (AxisAllowMotionCmdToSlave off by default)
    xp.set("mv2", "MC_MoveAbsolute", axis=2, Execute=True, Position=10.0, Velocity=100.0)
    r = xp.wait("mv2", ended, T)
    assert r.o["Error"] and r.o["ErrorID"] == 0x4266, r
    # a second coupling of the slave
    xp.set("gi2", "MC_GearInFloat", refs={"Master": 3, "Slave": 2}, Execute=True, GearRatio=1.0)
    r = xp.wait("gi2", ended, T)
    assert r.o["Error"] and r.o["ErrorID"] == 0x4B08, r
    # the coupling goes on
    xp.wait_cycles(5)
    last = xp.last("gi")
    assert last.o["InGear"] and last.o["Busy"] and last.a["CoupleState"] == SLAVE, last
    assert [x for x in xp.history("gi") if x.c >= gi.c and not x.o["InGear"]] == []
    clean(xp.history("gi"))


def test_stop_of_the_master_stops_both_and_the_slave_stays_coupled(xp: ExtPlc) -> None:
    power_both(xp, 1, 2)
    gear_in(xp, "gi", "MC_GearIn", 1, 2, RatioNumerator=1, RatioDenominator=2)
    xp.hook("chk", GEAR_CHECK, M=1, S=2, R=0.5, base=None)
    xp.set("mv", "MC_MoveVelocity", axis=1, Execute=True, Velocity=100.0, **DYN)
    iv = xp.wait("mv", lambda r: r.o["InVelocity"] or ended(r), T)
    assert iv.o["InVelocity"], iv
    xp.set("st", "MC_Stop", axis=1, Execute=True)
    st = xp.wait("st", lambda r: r.o["Done"] or r.o["Error"], T)
    assert st.o["Done"] and not st.o["Error"], st
    end = xp.wait("chk", lambda r: r.c >= st.c and r.o["vm"] == 0.0 and r.o["vs"] == 0.0, T)
    assert end.o["coupled"], f"the slave is still coupled and synchronous: {end}"
    check_gearing(xp.hook_records("chk"))
    xp.wait_cycles(5)
    gi = xp.last("gi")
    assert gi.o["InGear"] and gi.o["Busy"] and gi.a["CoupleState"] == SLAVE and gi.a["SetVelo"] == 0.0, gi
    clean(xp.history("gi"))


# ---- losing the master's controlling client -------------------------------------------------------
def test_the_master_client_killed_its_slave_follows_the_master_stop(nc: NcServerProcess,
                                                                    xplc: Callable[..., ExtPlc]) -> None:
    """Client A runs the master (MC_Power + MC_MoveVelocity), client B the slave (MC_Power + MC_GearIn
    1:2). A is killed (SIGKILL of its process group) mid-motion: the NC faults the master (0x8F01,
    its controlling client lost) and stops it on its ramp; the slave follows it down still coupled
    and without an error of its own (the documented reaction: a master's error stops its slaves
    synchronously). When the NC then releases A's claim, the master has no enable any more, which
    ends the coupling (ABORTED: B's MC_GearIn reports CommandAborted); the slave stands."""
    pa, pb = xplc(nc, "plc-a"), xplc(nc, "plc-b")
    power_both(pa, 1)
    power_both(pb, 2)
    gear_in(pb, "gi", "MC_GearIn", 1, 2, RatioNumerator=1, RatioDenominator=2)
    pa.set("mv", "MC_MoveVelocity", axis=1, Execute=True, Velocity=100.0, **DYN)
    pa.wait("mv", lambda r: r.o["InVelocity"] or ended(r), T)
    pb.trace(1)
    pb.trace(2)
    moving = pb.wait_trace(2, lambda s: abs(s.a["SetVelo"] - 50.0) < 1e-9, T)
    os.killpg(pa.proc.pid, signal.SIGKILL)
    pa.proc.wait(10)
    stopped = pb.wait_trace(1, lambda s: s.c > moving.c and s.a["ErrorId"] != 0 and s.a["SetVelo"] == 0.0, T)
    assert stopped.a["ErrorId"] in (0x8F01, 0x8F02), stopped
    gi = pb.wait("gi", ended, T)
    assert gi.o["CommandAborted"] and not gi.o["Error"], (gi, pb.history("gi"))
    rest = pb.wait_trace(2, lambda s: s.c > gi.c and s.a["SetVelo"] == 0.0, T)
    assert rest.a["CoupleState"] == 0 and rest.a["ErrorId"] == 0, rest
    t1, t2 = pb.trace_of(1), pb.trace_of(2)
    assert all(r.a["ErrorId"] == 0 for r in t2 if r.c > moving.c), "the slave has no error of its own"
    # while it was coupled the slave braked with its master: half the master's velocity, same frame
    by_cycle = {r.a["NcCycle"]: r.a["SetVelo"] for r in t1 if r.c > moving.c}
    pairs = [(by_cycle[r.a["NcCycle"]], r.a["SetVelo"]) for r in t2
             if r.c > moving.c and r.a["CoupleState"] == SLAVE and r.a["NcCycle"] in by_cycle]
    assert len(pairs) >= 5 and any(0.0 < vm < 100.0 for vm, _ in pairs), pairs  # (some while braking)
    assert all(abs(vs - 0.5 * vm) <= 1e-9 * max(1.0, vm) for vm, vs in pairs), pairs[:5]
