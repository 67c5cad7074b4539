"""A scriptable PLC program for the integration tests, run in its own process with ``plc-run``.

stdin (one JSON object per line), applied at the start of the next PLC cycle:

* ``{"op": "set", "name": "mv", "fb": "MC_MoveAbsolute", "axis": 1, "nc": "nc1", "inputs": {...}}``
  creates block ``name`` (first time) and updates its inputs; every block is called once per
  cycle with its current inputs (ST semantics: inputs keep their values);
* ``{"op": "del", "name": "mv"}`` stops calling the block;
* ``{"op": "exit"}`` raises SystemExit in the program (the runtime shuts down cleanly, rc 1).

stdout: ``{"c": <plc cycle>, "n": <name>, "o": {<outputs>}, "a": {<axis data>}}`` whenever a
block's outputs or its axis's Valid/MotionState change, and a ``{"c": n, "tick": true}`` line
every 50 cycles (liveness).
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


class Program:
    def __init__(self) -> None:
        self.blocks: dict[str, tuple[Any, AXIS_REF, dict[str, Any]]] = {}
        self.axes: dict[tuple[str, int], AXIS_REF] = {}
        self.last: dict[str, str] = {}

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
            elif op == "exit":
                raise SystemExit("agent exit requested")
        for name, (fb, ax, inputs) in self.blocks.items():
            fb(Axis=ax, **inputs)
            out = {k: _plain(getattr(fb, k)) for k in fb._OUTPUTS}
            st = ax.Status
            axis = {"Valid": st.Valid, "State": st.MotionState.name[13:], "Locked": st.MotionCommandsLocked,
                    "ErrorId": st.ErrorId}
            key = json.dumps([out, axis], sort_keys=True)
            if self.last.get(name) != key:
                self.last[name] = key
                axis["ActPos"] = float(ax.NcToPlc["ActPos"])
                axis["NcCycle"] = st.NcCycleCounter
                print(json.dumps({"c": plc.cycle, "n": name, "o": out, "a": axis}), flush=True)
        if plc.cycle % 50 == 0:
            print(json.dumps({"c": plc.cycle, "tick": True}), flush=True)
