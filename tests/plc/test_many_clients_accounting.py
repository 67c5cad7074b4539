"""bench/many_clients_program.py counts what the NC numbers (in-process NcCore, virtual time).

The bench's "no lost or doubled command" check compares the NC's NewestCmdNo progress with the
program's accepted moves. The PLC task also sends motion commands of its own: the Halt that stops
a move whose block gave up when the NC's data was lost (plc_client/task.py orphans). The NC numbers
that Halt too, so the progress is accepted + 1 without any doubled command; the program must count
it (``task_accepted``) for the check to be exact.
"""
from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from typing import Any

import pytest

from nc_schema import ErrorCodes
from znc_testing.plc_rig import Rig, ScriptNc

PROGRAM = Path(__file__).resolve().parents[2] / "bench" / "many_clients_program.py"


@pytest.fixture
def program_module(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Any:
    monkeypatch.setenv("MANY_AXES", "1")
    monkeypatch.setenv("MANY_REPORT", str(tmp_path / "report.json"))
    monkeypatch.setenv("MANY_STOP", str(tmp_path / "stop"))
    spec = importlib.util.spec_from_file_location("many_clients_program_under_test", PROGRAM)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    yield mod
    sys.modules.pop("many_clients_program_under_test", None)


def test_the_tasks_halt_of_an_orphaned_move_is_counted(program_module: Any, tmp_path: Path) -> None:
    rig = Rig(n_axes=1)
    prog = program_module.Program()
    rig.plc("plc1", prog.cycle)
    a = prog.axes[0]
    rig.run_until(lambda: a.accepted >= 2 and a.execute, 500)  # a few moves, one running now
    # the NC freezes: the running move's block ends with 0x4B0F; the NC comes back still running it
    rig.nc_running = False
    rig.run_until(lambda: not a.execute, 100)
    assert a.errors.get(f"0x{int(ErrorCodes.MC_NO_NC_CYCLE_UPDATE):04X}") == 1, a.errors
    rig.nc_running = True
    (tmp_path / "stop").touch()
    rig.run_until(lambda: prog.final, 500)
    rep = a.report()
    delta = rep["cmdno"] - rep["cmdno0"]
    assert rep["task_sent"] == 1 and rep["task_accepted"] == 1, rep  # the task's Halt
    assert rep["refused"] == 0 and rep["sent"] == rep["accepted"], rep  # no doubled or lost move
    assert delta == rep["accepted"] + 1, rep  # what the old check reported as "progress = sent + 1"
    assert delta == rep["accepted"] + rep["task_accepted"], rep


def test_a_late_answer_of_a_move_whose_block_gave_up_is_counted(program_module: Any) -> None:
    """The block of a move without an answer gives up (0x745) and the program sends its next move; when
    the first move's answer comes after all, it is counted: sent = accepted + refused + unanswered at every
    moment (the old program kept one request per axis and lost the first)."""
    nc = ScriptNc()
    prog = program_module.Program()
    nc.calls.append(lambda: prog.cycle(nc))
    a = prog.axes[0]
    claimed: set[int] = set()
    for _ in range(20):  # the claim answered, then the first move goes out
        nc.cycle_once()
        for p in nc.port.sent:
            if p.cmd == "Claim" and id(p) not in claimed:
                nc.port.answer(p, cycle=nc.nc_cycle)
                claimed.add(id(p))
        if a.sent:
            break
    first = nc.last_sent("MoveAbsolute")
    nc.cycle_once(150)  # no answer: the block times out, the next move goes out
    assert a.errors.get("0x0745") == 1, a.errors
    second = nc.last_sent("MoveAbsolute")
    assert second is not first and a.sent == 2 and a.report()["pending"] == 2
    nc.port.answer(first, cycle=nc.nc_cycle, cmdno=1)  # late
    nc.port.answer(second, cycle=nc.nc_cycle, cmdno=2)
    nc.cycle_once(3)
    rep = a.report()
    assert rep["accepted"] == 2, rep
    assert rep["sent"] == rep["accepted"] + rep["refused"] + rep["pending"], rep


def test_an_mc_reset_that_never_ends_is_given_up(program_module: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    """(review) An axis error is reset with MC_Reset; one that is never Done nor Error left ``resetting`` true for
    ever: no further reset, ever. After RESET_TIMEOUT_S it is given up (Execute off, counted) and tried again."""
    from types import SimpleNamespace as NS
    now = [100.0]
    monkeypatch.setattr(program_module, "time", NS(monotonic=lambda: now[0]))
    a = program_module._Axis(1)
    calls: list[bool] = []
    a.ax = NS(Status=NS(Valid=True, Error=True, ErrorId=0x4655, NcCycleCounter=1))
    a.power = lambda **k: NS(Active=True, Error=False, ErrorID=0, Status=False)

    class Reset:  # (an MC_Reset whose request never gets an answer)
        request = None

        def __call__(self, Axis: Any, Execute: bool) -> Any:
            calls.append(Execute)
            return NS(Done=False, Error=False)
    a.reset = Reset()
    a.move = lambda **k: NS(Done=False, Error=False, CommandAborted=False)
    a.cycle(False)
    assert a.resetting and a.resets == 1 and calls == [True]
    t0 = now[0]
    for _ in range(20):  # (not ended: held until the deadline)
        now[0] += 0.4
        a.cycle(False)
        if not a.resetting:
            break
    assert now[0] - t0 >= program_module.RESET_TIMEOUT_S
    assert not a.resetting and a.errors.get("axis:reset-timeout") == 1, a.errors
    assert calls[-1] is False
    now[0] += 1.0
    a.cycle(False)
    assert a.resetting and a.resets == 2  # (tried again)


def test_a_reset_during_the_error_stop_ramp_is_counted(program_module: Any, tmp_path: Path) -> None:
    """An axis error during a move (0x4655: the drive inputs too old, bench/many_clients.py --standby on a starved
    machine) starts the NC's error stop ramp; the program's MC_Reset comes while it still runs, and the ramp goes
    on as a numbered stop job (the axis shows Stopping, not StandStill, while it brakes). That number is the
    reset's: its reply carries it, the program counts it (``reset_numbered``), and every number of the
    NewestCmdNo progress is one accepted reply's (the old check saw progress = accepted + 1)."""
    rig = Rig(n_axes=1)
    prog = program_module.Program()
    rig.plc("plc1", prog.cycle)
    a = prog.axes[0]
    rig.run_until(lambda: a.accepted >= 2 and a.execute and abs(rig.core.axes.set_velo[0]) > 50.0, 500)
    rig.core.fault(0, ErrorCodes.NC_DRIVE_IO_DATA_INVALID)
    rig.run_until(lambda: a.reset_numbered == 1, 20)  # (the ramp lasts ~90 ms: the reset comes within it)
    assert a.resets == 1 and a.errors.get("axis:0x4655") == 1, a.errors
    rig.run_until(lambda: a.accepted >= 4, 500)  # it moves on
    # the axis error is counted once, as the axis's: MC_Power's Error/ErrorID show it too (TcMC 4.1), which is
    # not an MC_Power error of its own (power:<id>)
    assert not [k for k in a.errors if k.startswith("power:")], a.errors
    (tmp_path / "stop").touch()
    rig.run_until(lambda: prog.final, 500)
    rep = a.report()
    delta = rep["cmdno"] - rep["cmdno0"]
    assert rep["task_accepted"] == 0 and rep["refused"] == 0 and rep["sent"] == rep["accepted"], rep
    assert delta == rep["accepted"] + rep["reset_numbered"], rep
    assert rep["unexplained"] == [] and rep["doubled"] == [], rep


def test_unexplained_numbers_wrap_like_newest_cmdno(program_module: Any) -> None:
    f = program_module._unexplained
    assert f(65533, 2, [65534, 1, 2]) == ([65535], [])  # 65535 wraps to 1 (0 is never a number)
    assert f(10, 13, [11, 12, 12, 13, 14]) == ([], [12])  # (14: newer than the frame, not counted)
    assert f(None, 5, [1]) == ([], [])
