"""A stale-data episode (no new NC frame for longer than stale_cycles) and the example programs.

MC_Power.Status falls while the axis data is stale (0x4B0F) and rises again with fresh frames
(zenoh-nc's choice, see MC_Power's docstring). The old README pattern
``move(Execute=power.Status, ...)`` then saw a new rising edge and sent a second move; the
programs of the READMEs, examples/01 and the demo start motion from a latched step sequence and
must not. The scripted NC (plc_rig.ScriptNc) answers like an NC would; a stale episode is a
stretch of PLC cycles in which its frames do not advance.
"""
from __future__ import annotations

import re
from pathlib import Path
from typing import Any, Callable

import pytest

from nc_schema import ErrorCodes
from plc_client import AXIS_REF, MC_MoveAbsolute, MC_Power, demo_program
from plc_client.cli import load_program
from znc_testing.plc_rig import ACTIVE, MOVING, ScriptNc

ROOT = Path(__file__).resolve().parents[2]
MOTION = ("MoveAbsolute", "MoveRelative", "MoveVelocity")


class ServedNc:
    """The scripted NC of axis 1 answering like a real one: Claim and Reset accepted, a move
    accepted with the next CmdNo, shown active in the next frame and Done ``move_cycles`` later
    (the NC goes on during a stale episode: only the PLC sees no new frame)."""

    def __init__(self, program: Callable[[ScriptNc], Any], move_cycles: int = 5) -> None:
        self.nc = ScriptNc()
        self.nc.calls.append(lambda: program(self.nc))
        self.move_cycles = move_cycles
        self._seen = 0
        self._cmdno = 0
        self._left = 0  # PLC cycles until the running move ends

    @property
    def moves(self) -> list[Any]:
        """The motion requests the PLC sent, in order."""
        return [p for p in self.nc.port.sent if p.cmd in MOTION]

    def run(self, n: int = 1, until: Callable[[], bool] | None = None) -> None:
        """``n`` PLC cycles (fewer if ``until()`` becomes true)."""
        nc = self.nc
        for _ in range(n):
            nc.step()
            nxt = nc.nc_cycle + 10
            for p in nc.port.sent[self._seen:]:
                if p.cmd in MOTION:
                    assert p.axis_id == 1
                    self._cmdno += 1
                    nc.port.answer(p, cycle=nxt, cmdno=self._cmdno)
                    nc.state(MOVING)
                    nc.set_jobs(active=(self._cmdno, ACTIVE))
                    self._left = self.move_cycles
                else:  # Claim, Reset, ...
                    nc.port.answer(p, cycle=nxt)
            self._seen = len(nc.port.sent)
            if self._left:
                self._left -= 1
                if not self._left:
                    nc.job_done(self._cmdno)
            nc.nc_cycle = nxt  # the NC goes on (during a stale episode the PLC does not see it)
            if until is not None and until():
                return

    def stale(self, n: int) -> None:
        """``n`` PLC cycles in which no newer frame arrives: the last one stays the newest."""
        nc = self.nc
        cycle, recs, index, jobs = nc._frames["nc1"]
        nc._frames["nc1"] = (cycle, recs.copy(), index, None if jobs is None else jobs.copy())
        nc._take_frames = lambda: None  # type: ignore[method-assign]
        try:
            self.run(n)
        finally:
            del nc._take_frames  # the class's again: the newest frame each cycle


def _readme_program(path: Path) -> Callable[[ScriptNc], Any]:
    """The ``# prog.py`` program of a README, executed as a module of its own."""
    blocks = re.findall(r"```python\n(# prog\.py.*?)```", path.read_text(), re.S)
    assert len(blocks) == 1, f"{path}: one ```python block starting with '# prog.py' expected"
    ns: dict[str, Any] = {"__name__": f"readme_{path.parent.name}"}
    exec(compile(blocks[0], str(path), "exec"), ns)
    return ns["cycle"]


def _naive_program() -> Callable[[ScriptNc], Any]:
    """The old README pattern: Execute wired to MC_Power.Status."""
    X = AXIS_REF(nc="nc1", axis_id=1)
    power, move = MC_Power(), MC_MoveAbsolute()

    def cycle(plc: Any) -> None:
        power(Axis=X, Enable=True, Enable_Positive=True, Enable_Negative=True)
        move(Axis=X, Execute=power.Status, Position=100.0, Velocity=50.0)

    return cycle


PROGRAMS = {
    "README.md": lambda: _readme_program(ROOT / "README.md"),
    "plc_client/README.md": lambda: _readme_program(ROOT / "plc_client" / "README.md"),
}


def _stale_cycles(s: ServedNc) -> int:
    return s.nc.stale_cycles


def _ready_and_moved(s: ServedNc) -> None:
    """Power on, the one move runs and ends Done."""
    s.run(200, until=lambda: len(s.moves) == 1 and s._left == 0 and s.nc.ax.Status.InTargetPosition)
    assert len(s.moves) == 1
    s.run(5)


@pytest.mark.parametrize("name", PROGRAMS)
def test_readme_program_moves_once_across_a_stale_episode_after_done(name: str) -> None:
    prog = PROGRAMS[name]()
    s = ServedNc(prog)
    _ready_and_moved(s)
    assert prog.__globals__["step"] == 20
    s.stale(_stale_cycles(s) + 5)
    s.run(50)
    assert [p.cmd for p in s.moves] == ["MoveAbsolute"] and prog.__globals__["step"] == 20


@pytest.mark.parametrize("name", PROGRAMS)
def test_readme_program_does_not_restart_a_move_interrupted_by_a_stale_episode(name: str) -> None:
    prog = PROGRAMS[name]()
    s = ServedNc(prog, move_cycles=100)
    s.run(200, until=lambda: len(s.moves) == 1)
    s.run(3)
    s.stale(_stale_cycles(s) + 5)  # the move fails with 0x4B0F, the NC finishes it meanwhile
    assert prog.__globals__["step"] == 90
    s.run(150)
    assert len(s.moves) == 1 and prog.__globals__["step"] == 90


def test_the_old_pattern_did_move_twice() -> None:
    """The episode of the tests above is real: with Execute=power.Status it makes a second move."""
    s = ServedNc(_naive_program())
    _ready_and_moved(s)
    s.stale(_stale_cycles(s) + 5)
    s.run(50)
    assert len(s.moves) == 2


def test_example_01_goes_on_only_from_its_sequence() -> None:
    prog = load_program(str(ROOT / "examples" / "01_power_and_move.py"))
    s = ServedNc(prog)
    _ready_and_moved(s)  # first move Done; the example starts the next one (to 0) itself
    s.run(20)
    positions = [float(p.args["Position"]) for p in s.moves]
    assert positions[:2] == [100.0, 0.0]
    n = len(s.moves)
    s.stale(_stale_cycles(s) + 5)  # during a move: it fails with 0x4B0F, the sequence stops (step 90)
    s.run(100)
    assert len(s.moves) == n and prog.__globals__["step"] == 90


def test_demo_shuttle_finishes_an_interrupted_leg_once() -> None:
    """The demo resumes after a failure on purpose, to the same position, never a leg twice."""
    ax = AXIS_REF(nc="nc1", axis_id=1)
    shuttle = demo_program.Shuttle(ax, 0.0, 400.0, 300.0)
    s = ServedNc(lambda plc: shuttle.cycle(), move_cycles=60)
    s.run(200, until=lambda: len(s.moves) == 1)
    s.run(3)
    s.stale(_stale_cycles(s) + 5)
    s.run(200, until=lambda: len(s.moves) == 3)
    positions = [float(p.args["Position"]) for p in s.moves]
    assert positions == [400.0, 400.0, 0.0]


def test_power_status_during_and_after_a_stale_episode() -> None:
    """MC_Power: Status FALSE with Error 0x4B0F exactly while the data is stale, Busy and the
    enables kept, no new claim; Status TRUE and no error again with fresh data."""
    ax = AXIS_REF(nc="nc1", axis_id=1)
    pw = MC_Power()
    s = ServedNc(lambda plc: pw(Axis=ax, Enable=True, Enable_Positive=True, Enable_Negative=True))
    s.run(20, until=lambda: pw.Status)
    assert pw.Status and not pw.Error
    claims = [p for p in s.nc.port.sent if p.cmd == "Claim"]
    seen = []
    orig = s.nc.calls[0]
    s.nc.calls[0] = lambda: (orig(), seen.append((ax.Status.Valid, pw.Status, pw.Error, pw.ErrorID, pw.Busy,
                                                 int(ax.PlcToNc["ControlDWord"]) & 0x7)))
    s.stale(_stale_cycles(s) + 5)
    assert any(not v for v, *_ in seen) and seen[0][0]
    for valid, status, error, error_id, busy, enables in seen:
        assert status == valid and busy and enables == 0x7
        assert (error, error_id) == ((False, 0) if valid else (True, ErrorCodes.MC_NO_NC_CYCLE_UPDATE))
    s.run(3)
    assert pw.Status and not pw.Error and pw.ErrorID == 0
    assert [p for p in s.nc.port.sent if p.cmd == "Claim"] == claims
