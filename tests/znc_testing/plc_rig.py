"""Helpers of the PLC-side unit tests (fixtures in conftest.py):

* :class:`Rig`: a real in-process NcCore driven by InProcessPlc tasks, and :func:`powered`, a
  client whose program powers an axis and runs a body the test sets;
* :class:`ScriptNc`: a PLC task whose NC is the test (the wire contract alone: requests answered
  and frames written by hand, cycle by cycle), with :func:`started` and :func:`run_move`.

Timing: NC cycle 1 ms, PLC cycle 10 ms -> 10 NC steps per PLC cycle; time is virtual
(``plc.now = plc.cycle * 0.01``), so nothing sleeps.
"""
from __future__ import annotations

from typing import Any, Callable

import numpy as np
from nc_schema import NCJOBS_DTYPE, NCTOPLC_DTYPE, CmdState, StateDWord, make_reply
from nc_server.core import AxisConfig, AxisParams, NcCore
from nc_server.drives.sim import SimDrive
from nc_sim import InProcessPlc
from plc_client import AXIS_REF, MC_Power, PlcTask
from plc_client.port import CommandPort
from plc_client.fb.base import FunctionBlock
from znc_testing.until import step_until

NC_CYCLE = 0.001
PLC_CYCLE = 0.010
STEPS = round(PLC_CYCLE / NC_CYCLE)


def check_exclusive(fb: Any) -> None:
    """PLCopen: Busy/Done/Error/CommandAborted mutually exclusive; Active only with Busy
    (MC_Stop: Busy+Active+Done while locked is the documented exception; MC_GearIn*: InGear
    comes with Busy, the block stays responsible for the coupling)."""
    names = [n for n in ("Busy", "Done", "InVelocity", "InGear", "Error", "CommandAborted") if hasattr(fb, n)]
    on = [n for n in names if getattr(fb, n)]
    if type(fb).__name__ == "MC_Stop" and set(on) == {"Busy", "Done"}:
        assert fb.Active
        return
    if set(on) == {"Busy", "InGear"}:
        on = ["InGear"]
    assert len(on) <= 1, f"{type(fb).__name__}: {on} TRUE together"
    if getattr(fb, "Active", False):
        assert fb.Busy, f"{type(fb).__name__}: Active without Busy"
    if not fb.Error:
        assert fb.ErrorID == 0


class Rig:
    """One NcCore and any number of in-process PLC clients stepped in lockstep.

    ``rig.run(n)`` runs n PLC cycles: each client's ``step()`` (snapshot, program, PLCTONC),
    then 10 NC steps. Every ExecuteBlock registered with :meth:`watch` is checked for output
    exclusivity after every cycle, and its outputs are recorded in ``rig.trace[fb]``.
    """

    def __init__(self, n_axes: int = 2, params: AxisParams | None = None, drive_cls: type | None = None) -> None:
        p = params or AxisParams()
        cfg = [AxisConfig(AxisId=i + 1, Name=f"A{i + 1}", params=AxisParams(**vars(p))) for i in range(n_axes)]
        drive = drive_cls([c.params for c in cfg], NC_CYCLE) if drive_cls else None
        self.core = NcCore(cfg, cycle_time=NC_CYCLE, drive=drive)
        self.plcs: dict[str, InProcessPlc] = {}
        self.watched: list[Any] = []
        self.trace: dict[int, list[dict[str, Any]]] = {}
        self.nc_running = True

    def plc(self, client_id: str = "plc1", program: Callable[[Any], None] | None = None, **kw: Any) -> InProcessPlc:
        kw.setdefault("cycle_time", PLC_CYCLE)
        t = InProcessPlc(self.core, program, client_id=client_id, **kw)
        self.plcs[client_id] = t
        return t

    def watch(self, *fbs: Any) -> Any:
        """Check and record these blocks after every cycle; returns them (one: itself)."""
        for fb in fbs:
            self.watched.append(fb)
            self.trace[id(fb)] = []
        return fbs[0] if len(fbs) == 1 else fbs

    def outputs(self, fb: Any) -> list[dict[str, Any]]:
        return self.trace[id(fb)]

    def run(self, n: int = 1, until: Callable[[], bool] | None = None) -> int:
        for k in range(1, n + 1):
            for t in self.plcs.values():
                t.step()
            for fb in self.watched:
                check_exclusive(fb)
                self.trace[id(fb)].append({o: getattr(fb, o) for o in fb._OUTPUTS})
            if self.nc_running:
                for _ in range(STEPS):
                    self.core.step()
            if until is not None and until():
                return k
        return n

    def run_until(self, cond: Callable[[], Any], limit: int = 1000) -> int:
        """PLC cycles until ``cond()`` (:func:`znc_testing.until.step_until`); returns their number."""
        return step_until(self.run, cond, limit)

    def rec(self, axis_id: int = 1) -> np.void:
        return self.core.nctoplc[self.core.index(axis_id)]


def powered(rig: Rig, client: str = "plc1", axis_id: int = 1) -> tuple[AXIS_REF, MC_Power, dict]:
    """A client whose program powers ``axis_id`` (both feed enables) and then runs
    ``calls['body'](plc)``; returns once the axis is enabled."""
    plc = rig.plc(client)
    ax = plc.axis("nc1", axis_id)
    pw = MC_Power()
    calls: dict = {"body": lambda p: None}

    def program(p: Any) -> None:
        pw(Axis=ax, Enable=True, Enable_Positive=True, Enable_Negative=True)
        calls["body"](p)

    plc.program = program
    rig.run_until(lambda: pw.Status, 10)
    return ax, pw, calls


class OffsetDrive(SimDrive):
    """A simulated drive that settles 0.5 u short of the set position (never in the 0.02 target window)."""

    def step(self, enabled: np.ndarray, set_pos: np.ndarray, set_velo: np.ndarray, set_acc: np.ndarray) -> None:
        super().step(enabled, set_pos - 0.5 * enabled, set_velo, set_acc)


# ---- the wire contract alone: a scripted NC ------------------------------------------------------
ACTIVE, DONE, ABORTED, ERROR = CmdState.ACTIVE, CmdState.DONE, CmdState.ABORTED, CmdState.ERROR
S = StateDWord
MOVING = int(S.Operational | S.ControlLoopClosed | S.HasJob | S.PositiveDirection)
IDLE = int(S.Operational | S.ControlLoopClosed | S.NotMoving | S.InTargetPosition | S.InPositionArea)


class ScriptPort(CommandPort):
    """Records requests; the test answers them with :meth:`answer` (delivered by the next poll)."""

    def __init__(self) -> None:
        super().__init__("plc1")
        self.sent: list[Any] = []

    def _transmit(self, pending: Any, payload: bytes) -> None:
        self.sent.append(pending)

    def answer(self, pending: Any, error: int = 0, cycle: int = 0, cmdno: int | None = None,
               value: Any = None) -> None:
        self._deliver(pending, make_reply(pending.id, pending.cmd, error, cycle=cycle, cmd_no=cmdno, value=value))


class ScriptNc(PlcTask):
    """A PLC task whose NC is the test: axis 1 (``ax``; ``n_axes`` > 1 adds axes 2.. to the frames,
    e.g. a master); frames with job records unless ``jobs=False``."""

    def __init__(self, jobs: bool = True, n_axes: int = 1) -> None:
        super().__init__(self._run_calls, cycle_time=0.01, client_id="plc1")
        #: the program: these callables, every cycle
        self.calls: list[Any] = []
        self.port: ScriptPort = ScriptPort()
        self.port.clock = lambda: self.now
        self.nc_cycle = 0
        self.frame_epoch = 0  # the frames' Epoch (protocol 5: a hot-standby pair's; 0 without redundancy)
        ids = np.arange(1, n_axes + 1)
        self.recs = np.zeros(n_axes, dtype=NCTOPLC_DTYPE)
        self.recs["AxisId"] = ids
        self.recs["StateDWord"] = IDLE
        self.jobs = np.zeros(n_axes, dtype=NCJOBS_DTYPE) if jobs else None
        if self.jobs is not None:
            self.jobs["AxisId"] = ids
        self.ax = self.axis("nc1", 1)
        self.watched: list[Any] = []
        self.trace: list[dict[int, dict[str, Any]]] = []

    def _run_calls(self, plc: Any) -> None:
        for c in list(self.calls):
            c()

    def clock(self) -> float:
        return self.cycle * self.cycle_time

    def _take_frames(self) -> None:
        self._set_frame("nc1", self.nc_cycle, self.recs, self.jobs, epoch=self.frame_epoch)

    # -- the scripted NC ------------------------------------------------------------------
    @property
    def rec(self) -> np.void:
        return self.recs[0]

    def set_jobs(self, active: tuple[int, int] = (0, 0), buffered: int = 0, newest: int | None = None,
                 ended: tuple[tuple[int, int, int], ...] = (), flags: int = 0) -> None:
        """Job record (and NCTOPLC.CmdNo/CmdState = the active job, as the contract says)."""
        assert self.jobs is not None
        j = self.jobs[0]
        j["ActiveCmdNo"], j["ActiveState"] = active
        j["BufferedCmdNo"] = buffered
        j["BufferedMode"] = 1 if buffered else 0
        j["NewestCmdNo"] = newest if newest is not None else max([active[0], buffered] + [e[0] for e in ended])
        j["Flags"] = flags
        j["Ended"] = np.zeros(4, dtype=j["Ended"].dtype)
        for k, e in enumerate(ended):
            j["Ended"][k] = e
        self.rec["CmdNo"], self.rec["CmdState"] = active
        sdw = int(self.rec["StateDWord"]) & ~int(S.CmdBuffered)
        self.rec["StateDWord"] = sdw | (int(S.CmdBuffered) if buffered else 0)

    def state(self, sdw: int, **fields: Any) -> None:
        waiting = self.jobs is not None and int(self.jobs[0]["BufferedCmdNo"])
        keep = int(S.CmdBuffered) if waiting else 0
        self.rec["StateDWord"] = sdw | keep
        for k, v in fields.items():
            self.rec[k] = v

    def job_done(self, cmdno: int, sdw: int = IDLE, **fields: Any) -> None:
        """Job ``cmdno`` ended DONE and is the newest fate; the axis shows ``sdw`` and ``fields``."""
        self.state(sdw, **fields)
        self.set_jobs(active=(cmdno, DONE), ended=((cmdno, DONE, 0),))

    def cycle_once(self, n: int = 1) -> None:
        """n PLC cycles; the NC advances 10 cycles per PLC cycle; outputs checked every cycle."""
        for _ in range(n):
            self.step()
            for fb in self.watched:
                check_exclusive(fb)
            self.trace.append({id(fb): {o: getattr(fb, o) for o in fb._OUTPUTS} for fb in self.watched})
            self.nc_cycle += 10

    def history(self, fb: Any, output: str) -> list[Any]:
        """``output`` of ``fb`` after each cycle it was watched."""
        return [t[id(fb)][output] for t in self.trace if id(fb) in t]

    def last_sent(self, cmd: str) -> Any:
        ps = [p for p in self.port.sent if p.cmd == cmd]
        assert ps, f"no {cmd} sent"
        return ps[-1]


def started(nc: ScriptNc, fb: Any, cmdno: int, **inputs: Any) -> Any:
    """Call fb with Execute=TRUE every cycle; answer its request with ``cmdno``; return its request."""
    nc.calls.append(lambda: fb(Axis=nc.ax, Execute=True, **inputs))
    nc.cycle_once()
    p = nc.port.sent[-1]
    nc.port.answer(p, cycle=nc.nc_cycle, cmdno=cmdno)  # its effect is in the next frame
    return p


def run_move(nc: ScriptNc, fb: Any, cmdno: int, **inputs: Any) -> None:
    """fb started with ``cmdno``, shown active on the next frame."""
    nc.watched.append(fb)
    started(nc, fb, cmdno, **inputs)
    nc.state(MOVING)
    nc.set_jobs(active=(cmdno, ACTIVE))
    nc.cycle_once()
    assert fb.Busy and fb.Active


def all_blocks() -> list[type[FunctionBlock]]:
    """Every function block class of plc_client (each subclass of FunctionBlock, by qualified name)."""
    import plc_client.fb  # noqa: F401  (imports every block module: their classes exist)
    out: list[type[FunctionBlock]] = []
    todo = list(FunctionBlock.__subclasses__())
    while todo:
        c = todo.pop()
        if c not in out:
            out.append(c)
            todo.extend(c.__subclasses__())
    return sorted(out, key=lambda c: c.__qualname__)
