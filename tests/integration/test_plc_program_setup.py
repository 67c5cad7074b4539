"""Writing a program as a newcomer does, through real ``nc-server`` and ``plc-run`` processes:

* ``nc-server --set axis.2.AxisVeloMax=300 --config-overlay over.toml``: the NC applies both on top of
  the embedded default (a move faster than 300 is refused with 0x4221; the overlay's value is read back);
  a bad ``--set`` ends nc-server with exit code 2 and one error line, nothing started;
* ``plc-run monitor.py --arg axis=2 --arg every=5``: a program without any function block that only
  declares its AXIS_REF sees it Valid with the NC's data (axes bound at load), prints ``X.NcToPlc.SetVelo``,
  ``.CmdNo``, ``.StateDWord``, ``.CamCouplingState`` straight into JSON, and takes its axis id from
  ``--arg``; a bad ``--arg`` is exit code 2 with one line, no traceback.

Deadlines are generous (loaded 2-core machine); every process is killed with its process group.
"""
from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import textwrap
import threading
from pathlib import Path
from typing import Any, Callable

from nc_schema import StateDWord
from znc_testing.plc_harness import NC_ARGS, T
from znc_testing import NcServerProcess, NcTestClient, wait_until

MONITOR = """
    import json
    from plc_client import AXIS_REF, program_args

    args = program_args(axis=1, every=10)
    X = AXIS_REF(nc="nc1", axis_id=args.axis)   # no block is ever called with it

    def cycle(plc):
        if plc.cycle % args.every == 0:
            n = X.NcToPlc
            print(json.dumps({"Valid": X.Status.Valid, "AxisId": n.AxisId, "SetPos": n.SetPos,
                              "SetVelo": n.SetVelo, "CmdNo": n.CmdNo, "StateDWord": n.StateDWord,
                              "CamCouplingState": n.CamCouplingState, "State": X.Status.MotionState.name,
                              "all": n.as_dict()}), flush=True)
"""


class PlcRun:
    """``plc-run`` on a program file, its stdout lines collected by a thread."""

    def __init__(self, program: Path, endpoint: str, *args: str) -> None:
        cmd = [sys.executable, "-m", "plc_client.cli", str(program), "--nc", f"nc1={endpoint}", "--client-id",
               "monitor", *args]
        self.proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     text=True, start_new_session=True, env=dict(os.environ, PYTHONUNBUFFERED="1"))
        self.lines: list[str] = []
        self._t = threading.Thread(target=self._read, daemon=True)
        self._t.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.append(line.rstrip("\n"))

    def records(self) -> list[dict[str, Any]]:
        return [json.loads(ln) for ln in list(self.lines) if ln.startswith("{")]

    def kill(self) -> None:
        try:
            os.killpg(self.proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        self.proc.wait(10)


def test_monitor_program_with_args_on_an_nc_with_overrides(tmp_path: Path, start_nc: Callable[..., NcServerProcess],
                                                           nc_client: Callable[..., NcTestClient]) -> None:
    overlay = tmp_path / "over.toml"
    overlay.write_text("[axis.2]\nAxisAcc = 2000.0\n")
    nc = start_nc(extra_args=(*NC_ARGS, "--set", "axis.2.AxisVeloMax=300", "--config-overlay", str(overlay)))
    prog = tmp_path / "monitor.py"
    prog.write_text(textwrap.dedent(MONITOR))
    plc = PlcRun(prog, nc.endpoint, "--arg", "axis=2", "--arg", "every=5")
    try:
        # valid without any block, the NC's data of axis 2 (not 1: the --arg)
        first = wait_until(lambda: next((r for r in plc.records() if r["Valid"]), None), 3 * T,
                           "a valid record (plc-run starting: imports alone took 25 s on a loaded machine)")
        assert first["AxisId"] == 2 and first["State"] == "MC_AXISSTATE_DISABLED" and first["SetVelo"] == 0.0
        assert first["CamCouplingState"] == [0] * 8 and first["all"]["AxisId"] == 2
        # the overrides are the NC's parameters
        cl = nc_client(nc.port, "mover")
        assert cl.request("ReadParameter", axis=2, ParameterNumber=1003)["Value"] == 300.0  # AxisVeloMax (--set)
        acc = cl.request("ReadParameter", axis=2, ParameterNumber=1004)  # AxisAcc (the overlay)
        assert acc["error"] == 0 and acc["Value"] == 2000.0, acc
        assert cl.request("ReadParameter", axis=1, ParameterNumber=1003)["Value"] == 500.0  # axis 1 untouched
        cl.claim(2)
        cl.feed_plctonc([2])
        clc = int(StateDWord.ControlLoopClosed)
        wait_until(lambda: plc.records()[-1]["StateDWord"] & clc, T, "axis 2 enabled (seen by the monitor)")
        too_fast = cl.request("MoveVelocity", axis=2, Velocity=400.0, Direction=1)
        assert too_fast["error"] == 0x4221, too_fast
        r = cl.request("MoveVelocity", axis=2, Velocity=250.0, Direction=1)
        assert r["error"] == 0, r
        def seen_moving() -> dict[str, Any] | None:
            return next((x for x in plc.records()[-3:] if x["Valid"] and math.isclose(x["SetVelo"], 250.0)
                         and x["CmdNo"] == r["CmdNo"]), None)

        moving = wait_until(seen_moving, T, "the monitor seeing the move")
        assert moving["SetPos"] > 0.0 and moving["State"] == "MC_AXISSTATE_CONTINOUSMOTION"
        assert plc.proc.poll() is None, "the monitor ended (json.dumps of a value failed?)"
    finally:
        plc.kill()


def test_bad_program_argument_is_one_line_and_exit_2(tmp_path: Path) -> None:
    prog = tmp_path / "monitor.py"
    prog.write_text(textwrap.dedent(MONITOR))
    plc = PlcRun(prog, "tcp/127.0.0.1:1", "--arg", "axis=two")
    try:
        assert plc.proc.wait(T) == 2
        assert plc.proc.stderr is not None
        err = plc.proc.stderr.read()
        assert err.strip() == "plc-run: --arg axis=two: axis must be an integer (default 1)", err
        assert "Traceback" not in err and not plc.lines
    finally:
        plc.kill()


def test_bad_set_stops_nc_server_before_it_starts(start_nc: Callable[..., NcServerProcess]) -> None:
    for args, text in ((("--set", "axis.9.AxisAcc=1"), "--set axis.9.AxisAcc: no axis with AxisId 9"),
                       (("--set", "axis.1.AxisVeloMax=fast"), "--set axis.1.AxisVeloMax: must be a number"),
                       (("--set", "axis.1.AxisVeloMax=1e12"), "(MC_AxisPara")):
        srv = start_nc(extra_args=args, wait=False)
        assert srv.proc.wait(T) == 2
        srv._reader.join(5)
        assert srv.ready_line() is None
        err = srv.stderr()
        assert "nc-server: configuration error: " in err and text in err and "Traceback" not in err, err


def test_example_05_monitor_with_arguments(start_nc: Callable[..., NcServerProcess]) -> None:
    """examples/05 as its docstring says: no block, its axes from --arg, valid data printed."""
    nc = start_nc()
    example = Path(__file__).resolve().parents[2] / "examples" / "05_status_monitor.py"
    plc = PlcRun(example, nc.endpoint, "--arg", "axes=2,4", "--arg", "every=5")
    try:
        line, = wait_until(lambda: [ln for ln in list(plc.lines) if ln.startswith("2:") and "DISABLED" in ln][:1],
                           T, "a line of valid data")  # a list: a str would mean "not yet"
        assert "4:" in line and "1:" not in line and "no data" not in line, line
    finally:
        plc.kill()
