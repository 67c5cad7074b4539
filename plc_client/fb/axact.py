"""AXACT: the older TcNC axis-action block (START/STOP edges, numeric start MODE, BUSY/ERR/ERRID).

Inputs: AXID (INT axis id), START, STOP (BOOL edges), MODE (DWORD start type, table below),
VELOCITY [u/s], TARGPOS [u], TMOUT [s] (TIME; a ``datetime.timedelta`` is accepted too).
Outputs: BUSY, ERR, ERRID.

Addressing (zenoh-nc choice): AXACT has no AXIS_REF; it names its axis by AXID, and the NC by
the constructor argument ``AXACT(nc="nc1")``. It talks to the axis through the running PLC task
(:func:`plc_client.task.current_task`) with an AXIS_REF it creates for (nc, AXID) on first use
(``task.axis``; one per axis id, kept). It never controls the axis: the enables come from an
MC_Power of whatever PLC holds the axis; AXACT only sends commands, as ADS does.

Edges and outputs (spec): a rising edge of START sends the start command of MODE, a rising edge
of STOP sends a stop; if both rise in the same cycle, STOP wins (the START edge is dropped).
BUSY is TRUE from the edge until the NC has accepted the command *and* the axis's cyclic data shows
it - it monitors the *acceptance*, not the motion (follow ``HasJob`` for that). The spec: "as soon
as BUSY goes FALSE, the bit 'axis has transport instruction' is set"; over a real network the NC's
reply arrives before the frame of the cycle in which the command took effect, so BUSY falls on the
first frame with Cycle >= the reply's cycle (the rule of every block: :func:`plc_client.port.reply_cycle`,
:meth:`plc_client.axis_ref.AXIS_REF.shows_cycle`); in the PLC cycle BUSY falls, ``HasJob`` of a
started motion is TRUE (unless the motion already ended). A STOP (Halt) follows the same rule.
BUSY lasts at most TMOUT, which bounds the wait for the reply *and* for that frame: no answer, or no
frame showing the accepted command, within TMOUT gives ERR with ERRID 0x745 (zenoh-nc choice: a command
the NC accepted keeps running; only its confirmation is missing). An NC restart seen between the edge
and that frame (``AXIS_REF.nc_epoch`` changed: the new instance's cycles cannot confirm the old one's
reply) gives ERR 0x4B0F at once; a request still unanswered is abandoned then, so if the new instance
accepts it anyway the task stops that motion (the task's late-reply rule). While BUSY no edge is
accepted - a STOP edge too (spec: "no new command will be accepted"; BUSY lasts one round trip and a
frame, a few ms). ERR/ERRID keep the result of the last command and are reset by the next accepted
edge. A refused command: ERR with the NC's code.

STOP sends ``Halt`` (a normal stop with the axis's deceleration; the axis can be started again
at once). Not ``Stop``: MC_Stop's command locks the axis until a release that AXACT, having no
release input, could never send.

MODE -> NC command (``schema/protocol.json``; zenoh-nc's interpretation where the table only
names the start type):

======================  ==========================================================================
1                       MoveAbsolute Position=TARGPOS, Velocity=VELOCITY
2                       MoveRelative Distance=TARGPOS, Velocity=VELOCITY
3 / 4                   MoveVelocity Velocity=VELOCITY, Direction positive / negative
5                       MoveModulo Velocity=VELOCITY: TARGPOS >= 0 -> Position=TARGPOS in positive
                        direction (TARGPOS beyond the modulo period = extra turns, as the table
                        says "can also be larger than the modulo factor"); TARGPOS < 0 ->
                        Position=\\|TARGPOS\\| in negative direction (the sign of the "± travel
                        region" chooses the direction)
261/517/773/1029        MoveModulo Position=TARGPOS, Velocity=VELOCITY, Direction shortest way /
                        positive / negative / current (TcNC start types MODULO_SHORT/PLUS/
                        MINUS/CURRENT)
272 / 273               Jog MC_JOGMODE_STANDARD_SLOW, positive / negative (endless at the slow
                        manual velocity AxisVeloManSlow; STOP ends it)
528 / 529               Jog MC_JOGMODE_STANDARD_FAST, positive / negative (AxisVeloManFast)
784 / 785               MoveVelocity at the axis's AxisRapidTraverseVelocity, positive /
                        negative; the parameter is read with ReadParameter on every START (no
                        cache: a WriteParameter in between is honoured), then the move is sent
288 / 289               MoveRelative +/- one encoder increment ("pulse width"):
                        Distance = AxisEncoderScalingFactor (units per increment), at
                        Velocity = AxisVeloManSlow (both read with ReadParameter)
544/545, 800/801,       MoveRelative +/- 0.001, 0.01, 0.1, 1 units ("1/1000 ... 1/1"), at
1056/1057, 1312/1313    Velocity = AxisVeloManSlow (read with ReadParameter)
anything else           ERR with 0x4B04 (MC_INVALID_MODE), nothing sent
======================  ==========================================================================

The dynamics are always the axis defaults (AXACT has no acceleration inputs). TMOUT bounds the
whole START (parameter reads and the command together). VELOCITY/TARGPOS are checked only in
the modes that use them: a non-finite value gives ERR 0x4B06, nothing sent; the values
themselves are the NC's to judge (e.g. 0x4221 for a velocity above AxisVeloMax). ERRID 0x4012 for
an AXID outside 1..65535, 0x4B06 for a TMOUT that is not a positive number, 0x4B0F when the block
is called outside a running PLC cycle.
"""
from __future__ import annotations

import datetime
import math
import numbers
from typing import Any, Callable, ClassVar, Self

import numpy as np

from nc_schema import E_JogMode, ErrorCodes, MC_AxisPara, MC_Direction

from ..axis_ref import AXIS_REF
from ..port import PendingCommand, reply_cycle
from ..task import PlcTask, current_task
from .base import FunctionBlock

_POS = int(MC_Direction.MC_Positive_Direction)
_NEG = int(MC_Direction.MC_Negative_Direction)
_SHORT = int(MC_Direction.MC_Shortest_Way)
_CURRENT = int(MC_Direction.MC_Current_Direction)
_SLOW = int(E_JogMode.MC_JOGMODE_STANDARD_SLOW)
_FAST = int(E_JogMode.MC_JOGMODE_STANDARD_FAST)
_P_RAPID = int(MC_AxisPara.AxisRapidTraverseVelocity)
_P_MANSLOW = int(MC_AxisPara.AxisVeloManSlow)
_P_SCALING = int(MC_AxisPara.AxisEncoderScalingFactor)

#: MODE -> (what it needs from the inputs, the parameters to read, build(inputs, params) -> (cmd, args))
_Build = Callable[[float, float, dict[int, Any]], tuple[str, dict[str, Any]]]


def _modulo5(v: float, p: float, _: dict[int, Any]) -> tuple[str, dict[str, Any]]:
    if p < 0:
        return "MoveModulo", {"Position": -p, "Velocity": v, "Direction": _NEG}
    return "MoveModulo", {"Position": p, "Velocity": v, "Direction": _POS}


def _rel_step(sign: float, step: float | None) -> _Build:
    def build(v: float, p: float, par: dict[int, Any]) -> tuple[str, dict[str, Any]]:
        dist = par[_P_SCALING] if step is None else step
        return "MoveRelative", {"Distance": sign * float(dist), "Velocity": float(par[_P_MANSLOW])}
    return build


def _modulo_to(direction: int) -> _Build:
    def build(v: float, p: float, _: dict[int, Any]) -> tuple[str, dict[str, Any]]:
        return "MoveModulo", {"Position": p, "Velocity": v, "Direction": direction}
    return build


_MODES: dict[int, tuple[tuple[str, ...], tuple[int, ...], _Build]] = {
    1: (("VELOCITY", "TARGPOS"), (), lambda v, p, _: ("MoveAbsolute", {"Position": p, "Velocity": v})),
    2: (("VELOCITY", "TARGPOS"), (), lambda v, p, _: ("MoveRelative", {"Distance": p, "Velocity": v})),
    3: (("VELOCITY",), (), lambda v, p, _: ("MoveVelocity", {"Velocity": v, "Direction": _POS})),
    4: (("VELOCITY",), (), lambda v, p, _: ("MoveVelocity", {"Velocity": v, "Direction": _NEG})),
    5: (("VELOCITY", "TARGPOS"), (), _modulo5),
    272: ((), (), lambda v, p, _: ("Jog", {"Mode": _SLOW, "Direction": _POS})),
    273: ((), (), lambda v, p, _: ("Jog", {"Mode": _SLOW, "Direction": _NEG})),
    528: ((), (), lambda v, p, _: ("Jog", {"Mode": _FAST, "Direction": _POS})),
    529: ((), (), lambda v, p, _: ("Jog", {"Mode": _FAST, "Direction": _NEG})),
    784: ((), (_P_RAPID,), lambda v, p, par: ("MoveVelocity", {"Velocity": float(par[_P_RAPID]), "Direction": _POS})),
    785: ((), (_P_RAPID,), lambda v, p, par: ("MoveVelocity", {"Velocity": float(par[_P_RAPID]), "Direction": _NEG})),
    288: ((), (_P_SCALING, _P_MANSLOW), _rel_step(1.0, None)),
    289: ((), (_P_SCALING, _P_MANSLOW), _rel_step(-1.0, None)),
}
for _mode, _dir in ((261, _SHORT), (517, _POS), (773, _NEG), (1029, _CURRENT)):
    _MODES[_mode] = (("VELOCITY", "TARGPOS"), (), _modulo_to(_dir))
for _base, _step in ((544, 0.001), (800, 0.01), (1056, 0.1), (1312, 1.0)):
    _MODES[_base] = ((), (_P_MANSLOW,), _rel_step(1.0, _step))
    _MODES[_base + 1] = ((), (_P_MANSLOW,), _rel_step(-1.0, _step))

#: the MODE values AXACT understands (spec table)
AXACT_MODES = frozenset(_MODES)


def _seconds(v: Any) -> float | None:
    if isinstance(v, datetime.timedelta):
        v = v.total_seconds()
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, numbers.Real) or not math.isfinite(v) or v <= 0:
        return None
    return float(v)


class AXACT(FunctionBlock):
    """Axis actions by start type (TcNC AXACT); see the module docstring.

    Args:
        nc: the name of the NC whose axis AXID is meant (AXIS_REF's ``nc``).

    Inputs: AXID, START, STOP, MODE, VELOCITY, TARGPOS, TMOUT [s] (default 1 s).
    Outputs: BUSY, ERR, ERRID.
    """

    _INPUTS: ClassVar[dict[str, Any]] = {"AXID": 1, "START": False, "STOP": False, "MODE": 1, "VELOCITY": 0.0,
                                         "TARGPOS": 0.0, "TMOUT": 1.0}
    _OUTPUTS: ClassVar[dict[str, Any]] = {"BUSY": False, "ERR": False, "ERRID": 0}
    AXID: int
    START: bool
    STOP: bool
    MODE: int
    VELOCITY: float
    TARGPOS: float
    TMOUT: float | datetime.timedelta
    BUSY: bool
    ERR: bool
    ERRID: int

    def __init__(self, nc: str = "nc1") -> None:
        AXIS_REF(nc=nc, axis_id=1)  # validates the NC name (ValueError)
        super().__init__()
        self.nc = nc
        self._prev_start = False
        self._prev_stop = False
        self._axes: dict[tuple[int, int], AXIS_REF] = {}
        self._task_ref: PlcTask | None = None
        self._ax: AXIS_REF | None = None
        self._t0 = 0.0
        self._tmout = 1.0
        self._reads: dict[int, PendingCommand] = {}
        self._build: _Build | None = None
        self._inputs: tuple[float, float] = (0.0, 0.0)
        self._pending: PendingCommand | None = None
        self._epoch = 0       # the axis's nc_epoch at the edge
        self._shows = 0       # the accepted command's reply cycle: BUSY until a frame of it (0: no reply yet)

    def __call__(self, Axis: AXIS_REF | None = None, **inputs: Any) -> Self:
        if Axis is not None:
            raise TypeError("AXACT addresses its axis by AXID (and the nc given to its constructor), not by Axis")
        super().__call__(None, **inputs)
        return self

    @property
    def axis(self) -> AXIS_REF | None:
        """The AXIS_REF of the last command's axis (None before the first command)."""
        return self._ax

    def _cycle(self) -> None:
        start, stop = bool(self.START), bool(self.STOP)
        rise_start, rise_stop = start and not self._prev_start, stop and not self._prev_stop
        self._prev_start, self._prev_stop = start, stop
        if self.BUSY:
            self._progress()
            return
        if rise_stop or rise_start:
            self.ERR, self.ERRID = False, 0
            self.BUSY = True
            self._begin(stop=rise_stop)

    # -- a new command -------------------------------------------------------------------
    def _fail(self, code: int) -> None:
        for p in (*self._reads.values(), self._pending):
            if p is not None and not p.done:
                p.abandon()
        self._reads, self._pending, self._build = {}, None, None
        self.BUSY, self.ERR, self.ERRID = False, True, int(code) or ErrorCodes.NC_INTERNAL

    def _begin(self, stop: bool) -> None:
        task = current_task()
        if task is None:
            self._fail(ErrorCodes.MC_NO_NC_CYCLE_UPDATE)
            return
        axid = self.AXID
        if isinstance(axid, (bool, np.bool_)) or not isinstance(axid, numbers.Integral) or not 1 <= int(axid) <= 65535:
            self._fail(ErrorCodes.NC_AXIS_ID_NOT_ALLOWED)
            return
        tmout = _seconds(self.TMOUT)
        if tmout is None:
            self._fail(ErrorCodes.MC_PARAMETER_NOT_CORRECT)
            return
        key = (id(task), int(axid))
        ax = self._axes.get(key)
        if ax is None or ax.task is not task:
            ax = self._axes[key] = task.axis(self.nc, int(axid))
        self._task_ref, self._ax, self._t0, self._tmout = task, ax, task.now, tmout
        self._reads, self._pending, self._build = {}, None, None
        self._epoch, self._shows = ax.nc_epoch, 0
        if stop:
            self._pending = task.send(ax, "Halt")
            return
        mode = self.MODE
        entry = None
        if not isinstance(mode, (bool, np.bool_)) and isinstance(mode, numbers.Integral):
            entry = _MODES.get(int(mode))
        if entry is None:
            self._fail(ErrorCodes.MC_INVALID_MODE)
            return
        needs, params, build = entry
        for name in needs:
            if not self._is_real(getattr(self, name)):
                self._fail(ErrorCodes.MC_PARAMETER_NOT_CORRECT)
                return
        v = float(self.VELOCITY) if "VELOCITY" in needs else 0.0
        p = float(self.TARGPOS) if "TARGPOS" in needs else 0.0
        self._inputs, self._build = (v, p), build
        if params:
            self._reads = {n: task.send(ax, "ReadParameter", ParameterNumber=n) for n in params}
        else:
            self._send_final({})

    def _send_final(self, values: dict[int, Any]) -> None:
        assert self._build is not None and self._task_ref is not None and self._ax is not None
        cmd, args = self._build(*self._inputs, values)
        self._build = None
        self._pending = self._task_ref.send(self._ax, cmd, **args)

    # -- waiting for the NC ----------------------------------------------------------------
    def _progress(self) -> None:
        ax = self._ax
        if ax is not None and ax.nc_epoch != self._epoch:
            self._fail(ErrorCodes.MC_NO_NC_CYCLE_UPDATE)  # the NC restarted: nothing can confirm the command
            return
        if self._shows:
            if ax is not None and ax.shows_cycle(self._shows):
                self.BUSY = False  # accepted and shown: HasJob is in this cycle's data
                return
        elif self._reads:
            if all(p.done for p in self._reads.values()):
                values: dict[int, Any] = {}
                for n, p in self._reads.items():
                    err = p.error
                    if err:
                        self._fail(err)
                        return
                    values[n] = p.reply.get("Value") if p.reply is not None else None
                self._reads = {}
                if any(not FunctionBlock._is_real(v) for v in values.values()):
                    self._fail(ErrorCodes.MC_PARAMETER_NOT_CORRECT)
                    return
                self._send_final(values)
        elif self._pending is not None and self._pending.done:
            p, self._pending = self._pending, None
            err = p.error
            if err:
                self._fail(err)
                return
            self._shows = reply_cycle(p.reply)
            if ax is not None and ax.shows_cycle(self._shows):
                self.BUSY = False  # (the frame of the reply's cycle came with it)
                return
        task = self._task_ref
        if task is not None and task.now - self._t0 >= self._tmout - 1e-9:  # (float noise of now)
            self._fail(ErrorCodes.ADSERR_CLIENT_SYNCTIMEOUT)
del _mode, _dir, _base, _step
