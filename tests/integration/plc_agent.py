"""A scriptable PLC program for the integration tests, run in its own process with ``plc-run``.

stdin (one JSON object per line), applied at the start of the next PLC cycle:

* ``{"op": "set", "name": "mv", "fb": "MC_MoveAbsolute", "axis": 1, "nc": "nc1", "inputs": {...}}``
  creates block ``name`` (first time) and updates its inputs; every block is called once per
  cycle with its current inputs (ST semantics: inputs keep their values);
  (AXACT, which has no Axis input, is called without one; ``axis`` then only chooses the axis
  data reported with it);
* ``{"op": "del", "name": "mv"}`` stops calling the block;
* ``{"op": "sync", "id": k}`` prints ``{"c": <cycle>, "sync": k}``: every message before it was
  applied in this cycle or earlier, and every message after it is applied in a later cycle (the
  drain of this cycle stops at the sync) - so the blocks are called at least once with the inputs
  set before it (an Execute FALSE before a TRUE is a real falling edge);
* ``{"op": "trace", "axis": 1, "nc": "nc1", "on": true}`` prints the axis's data every cycle
  (``{"c": n, "tr": <axis>, "a": {...}}``) until switched off;
* ``{"op": "exit"}`` raises SystemExit in the program (the runtime shuts down cleanly, rc 1);
* ``{"op": "get", "name": "rps", "attr": "Parameter", "id": k}`` prints ``{"c": n, "get": k, "v": ...}``: the
  block's attribute (a struct as the map of its members, e.g. MC_ReadParameterSet's ST_AxisParameterSet).

stdout: ``{"c": <plc cycle>, "n": <name>, "o": {<outputs>}, "a": {<axis data>}}`` whenever a
block's outputs or its axis's Valid/MotionState/Locked/ErrorId/Homed change (the record also
carries ActPos, SetPos, SetVelo, HasJob, the snapshot's NC cycle and AXIS_REF.nc_epoch as Epoch), and a
``{"c": n, "tick": true}`` line every 50 cycles (liveness).
"""
from __future__ import annotations

import json
import queue
import sys
import threading
from typing import Any

import plc_client
from plc_client import AXIS_REF

_inbox: "queue.SimpleQueue[dict[str, Any]]" = queue.SimpleQueue()


def _reader() -> None:
    for line in sys.stdin:
        line = line.strip()
        if line:
            try:
                _inbox.put(json.loads(line))
            except ValueError:
                print(json.dumps({"bad": line}), flush=True)


threading.Thread(target=_reader, daemon=True, name="agent-stdin").start()


def _plain(v: Any) -> Any:
    if isinstance(v, bool) or v is None or isinstance(v, (int, float, str)):
        return v
    try:
        return float(v)
    except (TypeError, ValueError):
        return str(v)


def _state(ax: AXIS_REF) -> dict[str, Any]:
    """The axis data whose change makes a new record."""
    st = ax.Status
    return {"Valid": st.Valid, "State": st.MotionState.name[13:], "Locked": st.MotionCommandsLocked,
            "ErrorId": st.ErrorId, "Homed": st.Homed}


def _data(ax: AXIS_REF, state: dict[str, Any]) -> dict[str, Any]:
    """``state`` plus the positions, velocity and NC cycle of the snapshot (reported, not compared)."""
    rec = ax.NcToPlc
    return {**state, "ActPos": float(rec["ActPos"]), "SetPos": float(rec["SetPos"]),
            "SetVelo": float(rec["SetVelo"]), "HasJob": ax.Status.HasJob, "NcCycle": ax.Status.NcCycleCounter,
            "Epoch": ax.nc_epoch}


class Program:
    def __init__(self) -> None:
        self.blocks: dict[str, tuple[Any, AXIS_REF, dict[str, Any]]] = {}
        self.axes: dict[tuple[str, int], AXIS_REF] = {}
        self.last: dict[str, str] = {}
        self.traced: set[tuple[str, int]] = set()

    def _axis(self, nc: str, axis_id: int) -> AXIS_REF:
        key = (nc, axis_id)
        if key not in self.axes:
            self.axes[key] = AXIS_REF(nc=nc, axis_id=axis_id)
        return self.axes[key]

    def cycle(self, plc: Any) -> None:
        while True:
            try:
                msg = _inbox.get_nowait()
            except queue.Empty:
                break
            op = msg.get("op")
            if op == "set":
                name = msg["name"]
                if name not in self.blocks:
                    fb = getattr(plc_client, msg["fb"])(**msg.get("init", {}))
                    self.blocks[name] = (fb, self._axis(msg.get("nc", "nc1"), int(msg.get("axis", 1))), {})
                self.blocks[name][2].update(msg.get("inputs", {}))
            elif op == "del":
                self.blocks.pop(msg["name"], None)
            elif op == "trace":
                key = (msg.get("nc", "nc1"), int(msg.get("axis", 1)))
                if msg.get("on", True):
                    self.traced.add(key)
                else:
                    self.traced.discard(key)
            elif op == "sync":
                print(json.dumps({"c": plc.cycle, "sync": msg["id"]}), flush=True)
                break  # what comes after the sync: a later cycle
            elif op == "exit":
                raise SystemExit("agent exit requested")
            elif op == "get":
                entry = self.blocks.get(msg["name"])
                v = getattr(entry[0], msg["attr"], None) if entry else None
                v = v.as_dict() if hasattr(v, "as_dict") else _plain(v)
                print(json.dumps({"c": plc.cycle, "get": msg["id"], "v": v}), flush=True)
        for name, (fb, ax, inputs) in self.blocks.items():
            if isinstance(fb, plc_client.AXACT):
                fb(**inputs)
            else:
                fb(Axis=ax, **inputs)
            out = {k: _plain(getattr(fb, k)) for k in fb._OUTPUTS}
            axis = _state(ax)
            key = json.dumps([out, axis], sort_keys=True)
            if self.last.get(name) != key:
                self.last[name] = key
                print(json.dumps({"c": plc.cycle, "n": name, "o": out, "a": _data(ax, axis)}), flush=True)
        for nc, axis_id in self.traced:
            ax = self._axis(nc, axis_id)
            print(json.dumps({"c": plc.cycle, "tr": axis_id, "a": _data(ax, _state(ax))}), flush=True)
        if plc.cycle % 50 == 0:
            print(json.dumps({"c": plc.cycle, "tick": True}), flush=True)
