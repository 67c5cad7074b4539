"""Test-side control of PLC processes running ``plc_agent.py`` under ``plc-run``, and the helpers
the integration tests of the blocks share (deadline ``T``, the NC's arguments, power on, the
output rules). The fixtures ``nc`` and ``plc`` are in this folder's conftest.py.
"""
from __future__ import annotations

import itertools
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any, Callable

AGENT = Path(__file__).resolve().parents[1] / "integration" / "plc_agent.py"

#: deadline of every wait [s]: generous, a loaded 2-core machine
T = 30.0
#: the numbered example programs
EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def run_example(name: str, endpoint: str, timeout: float = 90.0) -> tuple[int, str]:
    """Run ``examples/<name>`` as its docstring says (``plc-run <file> --nc nc1=<endpoint>``) until it
    ends by itself; returns (exit code, output). Killed with its process group on a timeout."""
    cmd = [sys.executable, "-m", "plc_client.cli", str(EXAMPLES / name), "--nc", f"nc1={endpoint}"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True, env=dict(os.environ, PYTHONUNBUFFERED="1"))
    try:
        out, _ = proc.communicate(timeout=timeout)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(10)
    return proc.returncode, out
#: the watchdog is not what these tests are about: tolerate PLC stalls of a loaded machine
NC_ARGS = ("--watchdog-timeout", "3.0")
#: plc-run arguments of the block tests' PLCs: stale NC data after 100 PLC cycles (1 s), not plc-run's 20
#: (0.2 s): a loaded machine can hold the NC's frames back that long, and the blocks would end with 0x4B0F
#: (right, but not what those tests examine; staleness has its own tests, which keep the default)
STALE_ARGS = ("--stale-cycles", "100")


class Rec:
    """One output change of a block: PLC cycle ``c``, outputs ``o``, axis data ``a``."""

    __slots__ = ("c", "o", "a", "t")

    def __init__(self, c: int, o: dict[str, Any], a: dict[str, Any]) -> None:
        self.c, self.o, self.a, self.t = c, o, a, time.monotonic()

    def __repr__(self) -> str:
        on = [k for k, v in self.o.items() if v is True]
        return f"Rec(c={self.c}, {on}, ErrorID=0x{int(self.o.get('ErrorID', 0)):X}, {self.a})"


class PlcProcess:
    """A ``plc-run tests/integration/plc_agent.py`` process.

    Args:
        endpoint: the NC's zenoh endpoint.
        client_id: the PLC's client id.
        nc: NC name.
        extra: more plc-run arguments.
    """

    def __init__(self, endpoint: str, client_id: str, nc: str = "nc1", extra: list[str] | None = None) -> None:
        self.client_id = client_id
        cmd = [sys.executable, "-m", "plc_client.cli", str(AGENT), "--nc", f"{nc}={endpoint}",
               "--client-id", client_id, "--cycle-time", "0.01", *(extra or [])]
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        self.proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     text=True, bufsize=1, env=env, start_new_session=True)
        self.records: dict[str, list[Rec]] = {}
        self.samples: dict[int, list[Rec]] = {}
        self.synced: dict[int, int] = {}
        self.got: dict[int, Any] = {}
        self._ids = itertools.count(1)
        self.cycle = 0
        self.lines: list[str] = []
        self.err_lines: list[str] = []
        self._cv = threading.Condition()
        threading.Thread(target=self._read, daemon=True).start()
        threading.Thread(target=self._read_err, daemon=True).start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            with self._cv:
                self.lines.append(line)
                try:
                    m = json.loads(line)
                except ValueError:
                    self._cv.notify_all()
                    continue
                if "c" in m:
                    self.cycle = max(self.cycle, int(m["c"]))
                if "n" in m:
                    self.records.setdefault(m["n"], []).append(Rec(m["c"], m["o"], m["a"]))
                elif "tr" in m:
                    self.samples.setdefault(int(m["tr"]), []).append(Rec(m["c"], {}, m["a"]))
                elif "sync" in m:
                    self.synced[int(m["sync"])] = int(m["c"])
                elif "get" in m:
                    self.got[int(m["get"])] = m["v"]
                self._cv.notify_all()
        with self._cv:
            self._cv.notify_all()

    def _read_err(self) -> None:
        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            self.err_lines.append(line)

    # -- commands --------------------------------------------------------------------------
    def set(self, name: str, fb: str | None = None, axis: int = 1, nc: str = "nc1",
            init: dict[str, Any] | None = None, **inputs: Any) -> None:
        """Create block ``name`` of type ``fb`` on ``axis`` (first time) and set its inputs."""
        msg: dict[str, Any] = {"op": "set", "name": name, "axis": axis, "nc": nc, "inputs": inputs}
        if fb:
            msg["fb"] = fb
        if init:
            msg["init"] = init
        self._send(msg)

    def delete(self, name: str) -> None:
        self._send({"op": "del", "name": name})

    def sync(self, timeout: float = T) -> int:
        """Wait until the PLC applied every message sent so far; returns the PLC cycle in which it
        did (the blocks ran with those inputs in that cycle; later messages apply in later cycles)."""
        k = next(self._ids)
        self._send({"op": "sync", "id": k})
        deadline = time.monotonic() + timeout
        with self._cv:
            while k not in self.synced:
                left = deadline - time.monotonic()
                if left <= 0 or self.proc.poll() is not None:
                    raise AssertionError(f"{self.client_id}: no sync {k} in {timeout} s (rc={self.proc.poll()}): "
                                         f"{''.join(self.err_lines[-10:])}")
                self._cv.wait(min(left, 0.1))
            return self.synced[k]

    def get(self, name: str, attr: str, timeout: float = T) -> Any:
        """Attribute ``attr`` of block ``name`` as the PLC has it now (a struct: the map of its members)."""
        k = next(self._ids)
        self._send({"op": "get", "name": name, "attr": attr, "id": k})
        deadline = time.monotonic() + timeout
        with self._cv:
            while k not in self.got:
                left = deadline - time.monotonic()
                if left <= 0 or self.proc.poll() is not None:
                    raise AssertionError(f"{self.client_id}: no answer to get {name}.{attr} in {timeout} s")
                self._cv.wait(min(left, 0.1))
            return self.got.pop(k)

    def edge(self, name: str, input: str = "Execute", **inputs: Any) -> int:
        """A rising edge of ``input`` of block ``name``: FALSE for at least one PLC cycle, then TRUE
        together with ``inputs``. Returns the cycle with FALSE (the edge's records are later)."""
        self.set(name, **{input: False})
        c = self.sync()
        self.set(name, **{input: True}, **inputs)
        return c

    def trace(self, axis: int = 1, on: bool = True, nc: str = "nc1") -> None:
        """Record the axis's data every PLC cycle (in ``samples[axis]``) while ``on``."""
        self._send({"op": "trace", "axis": axis, "nc": nc, "on": on})

    def trace_of(self, axis: int = 1) -> list[Rec]:
        with self._cv:
            return list(self.samples.get(axis, []))

    def _send(self, msg: dict[str, Any]) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(json.dumps(msg) + "\n")
        self.proc.stdin.flush()

    # -- observation -----------------------------------------------------------------------
    def last(self, name: str) -> Rec | None:
        with self._cv:
            recs = self.records.get(name)
            return recs[-1] if recs else None

    def history(self, name: str) -> list[Rec]:
        with self._cv:
            return list(self.records.get(name, []))

    def wait(self, name: str, pred: Callable[[Rec], bool], timeout: float = T) -> Rec:
        """Wait until block ``name`` is in a state satisfying ``pred``: its current state (newest
        record) or any record that arrives while waiting (so one-cycle pulses are not missed).

        Raises:
            AssertionError: timeout or the process ended; the message shows the history.
        """
        return self._wait(lambda: self.records.get(name), name, pred, timeout)

    def wait_trace(self, axis: int, pred: Callable[[Rec], bool], timeout: float = T) -> Rec:
        """Like :meth:`wait` on the axis's samples (``trace`` must be on)."""
        return self._wait(lambda: self.samples.get(axis), f"trace {axis}", pred, timeout)

    def _wait(self, get: Callable[[], list[Rec] | None], what: str, pred: Callable[[Rec], bool],
              timeout: float) -> Rec:
        deadline = time.monotonic() + timeout
        with self._cv:
            start = max(0, len(get() or []) - 1)
            while True:
                recs = get()
                if recs:
                    for r in recs[start:]:
                        if pred(r):
                            return r
                    start = len(recs)
                if self.proc.poll() is not None:
                    raise AssertionError(f"PLC {self.client_id} exited rc={self.proc.returncode}: "
                                         f"{''.join(self.err_lines[-20:])}")
                left = deadline - time.monotonic()
                if left <= 0:
                    raise AssertionError(f"{self.client_id}/{what}: condition not met in {timeout} s; "
                                         f"history: {recs[-8:] if recs else None}\n{''.join(self.err_lines[-10:])}")
                self._cv.wait(min(left, 0.1))

    def wait_cycles(self, n: int, timeout: float = 10.0) -> None:
        """Wait until the PLC has run ``n`` more cycles (needs the 50-cycle ticks or records)."""
        target = self.cycle + n
        deadline = time.monotonic() + timeout
        with self._cv:
            while self.cycle < target:
                left = deadline - time.monotonic()
                if left <= 0 or self.proc.poll() is not None:
                    raise AssertionError(f"{self.client_id}: only at cycle {self.cycle}, wanted {target}")
                self._cv.wait(min(left, 0.1))

    def wait_started(self, timeout: float = 60.0) -> None:  # (15 s was too short in a loaded CI run)
        deadline = time.monotonic() + timeout
        with self._cv:
            while not any(line.startswith("plc-run ") for line in self.lines):
                left = deadline - time.monotonic()
                if left <= 0 or self.proc.poll() is not None:
                    raise AssertionError(f"plc-run did not start: {''.join(self.err_lines[-20:])}")
                self._cv.wait(min(left, 0.1))

    # -- end -------------------------------------------------------------------------------
    def stop(self, timeout: float = 10.0) -> int:
        """SIGTERM and wait (the runtime releases its claims); after ``timeout`` SIGKILL; in the end
        its whole process group is killed (it has its own session)."""
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                pass
        try:
            os.killpg(self.proc.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass
        self.proc.wait(5)
        return self.proc.returncode

    def __enter__(self) -> PlcProcess:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.stop()


# ---- shared by the tests of the blocks -------------------------------------------------------
def power_on(p: PlcProcess, axis: int = 1, name: str = "pw") -> Rec:
    """MC_Power ``name`` on ``axis`` with both feed enables; returns its first record with Status."""
    p.set(name, "MC_Power", axis=axis, Enable=True, Enable_Positive=True, Enable_Negative=True)
    return p.wait(name, lambda r: r.o["Status"], T)


def exclusive(recs: list[Rec]) -> None:
    """PLCopen output rules: Busy/Done/InVelocity/InEndVelocity/Error/CommandAborted mutually
    exclusive (MC_Stop's Busy+Active+Done while locked excepted), Active only with Busy."""
    for r in recs:
        on = [k for k in ("Busy", "Done", "InVelocity", "InEndVelocity", "Error", "CommandAborted") if r.o.get(k)]
        locked_stop = set(on) == {"Busy", "Done"} and r.o.get("Active") and r.a.get("Locked")
        assert len(on) <= 1 or locked_stop, r
        assert not r.o.get("Active") or r.o.get("Busy"), r


def first_cycle(recs: list[Rec], output: str) -> int:
    """The PLC cycle of the first record in which ``output`` is TRUE."""
    return next(r.c for r in recs if r.o.get(output))


def ended(r: Rec) -> bool:
    """The block has a result (whichever)."""
    return any(r.o.get(k) for k in ("Done", "InVelocity", "InEndVelocity", "Error", "CommandAborted"))
