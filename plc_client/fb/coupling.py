"""Master-slave coupling: MC_GearIn, MC_GearInFloat, MC_GearInDyn, MC_GearOut, MC_GearOutExt
(TcMC manual 3.17-3.21; outputs Busy and the PLCopen output rules from Tc2_MC2 / PLCopen Part 1).

Call style: ``gi(Master=ax1, Slave=ax2, Execute=True, RatioNumerator=1, RatioDenominator=2)``;
MC_GearOut and MC_GearOutExt take only ``Slave``. Master and Slave are VAR_IN_OUT: passed once,
they are kept, like inputs. The requests go to the **slave's** axis key with ``Master`` = the
master's AxisId (wire contract, ``schema/protocol.json``).

**The coupling is a job of the slave.** The NC's reply carries its CmdNo; while the axes are
coupled it is the slave's ``NCJOBS.ActiveCmdNo`` in state ACTIVE, the slave shows CoupleState
SLAVE (MASTERSLAVE if it is itself a master) and AxisState 11 PRE-PHASE / 12 SYNCHRONIZING / 13
SYNCHRON. The gear-in blocks follow that job with the machinery of the motion blocks
(:class:`~plc_client.fb.motion.MotionBlock`: the job records, or NcToPlc CmdNo/CmdState on an NC
without them) and end as follows (zenoh-nc choices where the manual is silent):

* Busy from the Execute edge while the block follows the coupling; **InGear** once the job is
  ACTIVE and the slave's AxisState is 13 (SLAVE_SYNCHRON). InGear is latched: it stays TRUE,
  together with Busy (PLCopen: MC_GearIn stays Busy while it is responsible for the coupling),
  until the coupling ends. InGear, CommandAborted and Error are mutually exclusive.
* The coupling job ends **DONE** (MC_GearOut / MC_GearOutExt decoupled the slave normally): the
  block finishes with InGear as its result - Busy falls, InGear stays TRUE while Execute stays
  TRUE (one cycle if it already fell), like a Done (TcMC: "InGear becomes TRUE if the coupling
  was successful"; PLCopen names MC_GearOut as the regular end of MC_GearIn's command). Decoupled
  before it ever was InGear (while synchronizing): CommandAborted.
* It ends **ABORTED** (another command took the slave, MC_Stop, a disable, ...) or is pushed out
  of the job record by newer commands: CommandAborted.
* It ends **ERROR**, or the slave's axis Error bit shows while it runs: Error with the job's
  error id (the NCJOBS ``Ended`` entry, else NcToPlc.ErrorCode, else 0x4B62).
* On an NC whose frames carry no job records the block follows NcToPlc CmdNo/CmdState alone; a
  newer CmdNo then cannot be told from an abort, so MC_GearOut's follow-on velocity job also
  makes the block CommandAborted there (the zenoh-nc NC always sends job records).
* The result outputs follow the general rules (held while Execute stays TRUE, TRUE for one
  cycle if Execute already fell; a rising edge while Busy is ignored). Execute falling while
  coupled does not end the block (except MC_GearInDyn, see there).

Input checks, nothing sent on failure: a ratio that is not a number of the manual's type
(RatioNumerator an integer in the IEC INT range -32768..32767, RatioDenominator an integer
1..65535 - 0 would be a division by zero -, GearRatio a finite number; BOOLs and integral
floats such as 2.0 are not integers here), or a non-finite Acceleration/Deceleration/Jerk:
Error 0x4B06. Master or Slave not given, unbound outside a PLC cycle or with stale data: 0x4B0F;
an axis the frames do not contain: 0x4012. A Master on another NC than the slave (the task reads both
NCs): the request carries ``MasterNc`` and the slave's NC follows the master's samples over zenoh
(coupling across NCs, docs/coupling-across-ncs.md; that NC must list the master in ``[remote] masters``,
else 0x4012; MC_GearInDyn across NCs: 0x4B06). The master is checked when the command starts; afterwards only
the slave (the coupling is the slave's job; an NC restart - ``nc_epoch`` - makes it 0x4B0F).
Everything else (master == slave, a cycle of couplings, a slave already coupled, not at
standstill, |ratio| > 1e6) is the NC's answer.

MC_GearOut: Done once the NC accepted the decoupling and a frame of the reply's cycle (or a
later one) arrived, so a program that sees Done also sees the slave decoupled; the reply's CmdNo
(the velocity job of a slave decoupled in motion) is not followed. Errors: the NC's (0x4B05 when
the slave is not coupled).

MC_GearOutExt: the reply's CmdNo is the follow-on command's (``Mode``, E_DecoupleMode); the
block follows it as a motion block follows its own command: Done when that command reached its
end - STOP, ORIENTEDSTOP, INSTANTANEOUSSTOP: the logical standstill (as MC_Halt); NEWPOS,
NEWPOSANDVELO: the target rule of TcMC appendix 7.1 (as MC_MoveAbsolute); ENDLESS,
ENDLESS_NEWVELO: the command active at constant velocity (as MC_MoveVelocity's InVelocity; the
block is then finished). CmdNo 0 (the slave stood, no follow-on command): Done once the reply's
frame is shown. A Mode that is not an integer 0..6: Error 0x4B04, nothing sent.
"""
from __future__ import annotations

import logging
import numbers
from typing import TYPE_CHECKING, Any, Self

import numpy as np

from nc_schema import AxisState, E_DecoupleMode, ErrorCodes, StateDWord

from ..axis_ref import AXIS_REF
from ..port import reply_cycle
from ..task import current_task
from .base import ExecuteBlock
from .motion import MotionBlock

log = logging.getLogger(__name__)



_SYNCHRON = int(AxisState.SLAVE_SYNCHRON)
_HASJOB = int(StateDWord.HasJob)
_CONSTV = int(StateDWord.ConstantVelocity)

#: IEC INT / UINT ranges of RatioNumerator / RatioDenominator (TcMC 3.17)
_INT16 = (-(2**15), 2**15 - 1)
_UINT16_POSITIVE = (1, 2**16 - 1)
_DYN_REALS = ("Acceleration", "Deceleration", "Jerk")
_DYN = {"Acceleration": 0.0, "Deceleration": 0.0, "Jerk": 0.0}


def _integer_in(v: Any, lo: int, hi: int) -> int | None:
    """``v`` as int if it is an integer (not a BOOL, not a float) within lo..hi, else None."""
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, numbers.Integral):
        return None
    i = int(v)
    return i if lo <= i <= hi else None


def _check_axis_arg(block: str, name: str, v: Any) -> None:
    if v is not None and not isinstance(v, AXIS_REF):
        raise TypeError(f"{block}: {name} must be an AXIS_REF, got {type(v).__name__}")


if TYPE_CHECKING:
    # the checker sees the block the mixin is combined with (its super().__call__, its Axis)
    _SlaveCallBase = ExecuteBlock
else:
    _SlaveCallBase = object


class _SlaveCall(_SlaveCallBase):
    """Mixin of the blocks acting on a slave alone: the ``Slave`` keyword is the block's Axis."""

    # [override]: TcMC names the axis Slave, so Axis= is refused (not substitutable, on purpose)
    def __call__(self, Slave: AXIS_REF | None = None, **inputs: Any) -> Self:  # type: ignore[override]
        if "Axis" in inputs:
            raise TypeError(f"{type(self).__name__}: pass the slave axis as Slave=..., not Axis=...")
        _check_axis_arg(type(self).__name__, "Slave", Slave)
        return super().__call__(Axis=Slave, **inputs)

    @property
    def Slave(self) -> AXIS_REF | None:
        """The slave axis (VAR_IN_OUT; the block's Axis)."""
        return self.Axis


class _GearInBlock(MotionBlock):
    """Couple Slave to Master and follow the coupling job (see the module docstring)."""

    _OUTPUTS = {"InGear": False, "Busy": False, "CommandAborted": False, "Error": False, "ErrorID": 0}
    InGear: bool
    _DONE = "InGear"

    def __init__(self, timeout: float | None = None) -> None:
        super().__init__(timeout)
        self.Master: AXIS_REF | None = None

    # [override]: TcMC names the axes Master and Slave, so Axis= is refused (not substitutable, on purpose)
    def __call__(self, Master: AXIS_REF | None = None, Slave: AXIS_REF | None = None,  # type: ignore[override]
                 **inputs: Any) -> Self:
        name = type(self).__name__
        if "Axis" in inputs:
            raise TypeError(f"{name}: pass the axes as Master=... and Slave=..., not Axis=...")
        _check_axis_arg(name, "Master", Master)
        _check_axis_arg(name, "Slave", Slave)
        if Master is not None:
            self.Master = Master
        return super().__call__(Axis=Slave, **inputs)

    @property
    def Slave(self) -> AXIS_REF | None:
        """The slave axis (VAR_IN_OUT; the block's Axis)."""
        return self.Axis

    def _held(self) -> bool:
        """The slave's wait for its first data (FunctionBlock._held), or the master's."""
        if super()._held():
            return True
        m = self.Master
        if m is None:
            return False
        if m._task is None:
            t = current_task() or (self.Axis._task if self.Axis is not None else None)
            if t is None:
                return False
            t.register(m)
        return m.pending

    # -- start ---------------------------------------------------------------------------
    def _ratio_args(self) -> dict[str, Any] | None:
        """The ratio part of the request; None if an input is not valid (subclass)."""
        raise NotImplementedError  # pragma: no cover

    def _master_problem(self) -> int:
        """0 if the Master can be named to the NC, else the error code to report."""
        m, s = self.Master, self.Axis
        if m is None:
            return ErrorCodes.MC_NO_NC_CYCLE_UPDATE
        if m._task is None:
            t = current_task() or (s._task if s is not None else None)
            if t is None:
                return ErrorCodes.MC_NO_NC_CYCLE_UPDATE
            t.register(m)
        if m.missing:
            return ErrorCodes.NC_AXIS_ID_NOT_ALLOWED
        if not m.Status.Valid:
            return ErrorCodes.MC_NO_NC_CYCLE_UPDATE
        return 0

    def _start(self) -> None:
        self._cmdno, self._cmd_cycle, self._done_since = 0, 0, None
        ratio = self._ratio_args()
        if ratio is None:
            self._finish("Error", ErrorCodes.MC_PARAMETER_NOT_CORRECT)
            return
        if not self._check_inputs(_DYN_REALS, buffer_mode=False):
            return
        code = self._axis_problem() or self._master_problem()
        if code:
            self._finish("Error", code)
            return
        self._before_send()
        assert self.Master is not None and self.Axis is not None
        # a Master on another NC: a coupling across NCs (the slave's NC follows the master's samples; protocol 4)
        remote = {"MasterNc": self.Master.nc} if self.Master.nc != self.Axis.nc else {}
        self._send(self.CMD, Master=int(self.Master.axis_id), **remote, **ratio,
                   **{k: float(getattr(self, k)) for k in _DYN_REALS})

    def _before_send(self) -> None:
        """Hook: MC_GearInDyn writes PlcToNc.GearRatio1 first."""

    def _take_reply(self) -> bool:
        """True once the reply's CmdNo is known; finishes with Error on loss/refusal/timeout."""
        if self._cmdno:
            return True
        got = self._accepted()
        if got is None:
            return False
        self._cmdno, self._cmd_cycle, _ = got
        return True

    # -- following (MotionBlock calls these) ---------------------------------------------
    def _on_active(self, sdw: int) -> None:
        assert self.Axis is not None  # (_follow checked it)
        if int(self.Axis.NcToPlc["AxisState"]) == _SYNCHRON:
            self.InGear = True  # latched until the coupling ends

    def _on_done(self, rec: Any, sdw: int) -> None:
        self._decoupled()

    def _done_now(self) -> None:
        self._decoupled()

    def _decoupled(self) -> None:
        """The coupling job ended DONE: decoupled normally (MC_GearOut): InGear is the result (it was
        successful), CommandAborted if it never got synchronous."""
        self._finish("InGear" if self.InGear else "CommandAborted")

    def _end_quietly(self) -> None:
        if self._pending is not None and not self._pending.done:
            self._pending.abandon()
        self._pending = None
        self.Busy = self.InGear = False
        self.Active = False

    def _finish(self, result: str, error_id: int = 0) -> None:
        self.InGear = False  # exclusive with CommandAborted / Error
        super()._finish(result, error_id)


class MC_GearIn(_GearInBlock):
    """Linear coupling with the ratio RatioNumerator / RatioDenominator (TcMC 3.17).

    Inputs: Execute, RatioNumerator (INT, may be negative), RatioDenominator (UINT, > 0),
    Acceleration, Deceleration, Jerk (not used by the NC, sent anyway).
    Outputs: InGear, Busy, CommandAborted, Error, ErrorID. VAR_IN_OUT: Master, Slave.
    See the module docstring for the outputs and checks.
    """

    CMD = "GearIn"
    _INPUTS = {"Execute": False, "RatioNumerator": 1, "RatioDenominator": 1, **_DYN}
    RatioNumerator: int
    RatioDenominator: int
    Acceleration: float
    Deceleration: float
    Jerk: float

    def _ratio_args(self) -> dict[str, Any] | None:
        num = _integer_in(self.RatioNumerator, *_INT16)
        den = _integer_in(self.RatioDenominator, *_UINT16_POSITIVE)
        if num is None or den is None:
            return None
        return {"RatioNumerator": num, "RatioDenominator": den}


class MC_GearInFloat(_GearInBlock):
    """Linear coupling with an LREAL GearRatio (TcMC 3.18).

    Inputs: Execute, GearRatio (finite; the NC refuses |ratio| > 1e6), Acceleration,
    Deceleration, Jerk (not used). Outputs: InGear, Busy, CommandAborted, Error, ErrorID.
    VAR_IN_OUT: Master, Slave.
    """

    CMD = "GearInFloat"
    _INPUTS = {"Execute": False, "GearRatio": 1.0, **_DYN}
    GearRatio: float
    Acceleration: float
    Deceleration: float
    Jerk: float

    def _ratio_args(self) -> dict[str, Any] | None:
        r = self.GearRatio
        return {"GearRatio": float(r)} if self._is_real(r) else None


class MC_GearInDyn(_GearInBlock):
    """Coupling whose ratio may change every PLC cycle (TcMC 3.19).

    Inputs: Execute, GearRatio (LREAL, taken every cycle while Execute is TRUE), Acceleration
    (limits the slave's acceleration from ratio changes; 0 = the slave's AxisAcc), Deceleration,
    Jerk (not used). Outputs: InGear, Busy, CommandAborted, Error, ErrorID. VAR_IN_OUT: Master,
    Slave.

    Mechanism (wire contract): the block writes ``Slave.PlcToNc.GearRatio1 := GearRatio`` in
    every cycle in which it is Busy and Execute is TRUE, from the cycle the NC accepted the
    ``GearInDyn`` request on (a refused request changes nothing; the NC starts with the request's
    GearRatio and takes GearRatio1 once it is the block's), and the NC reads PLCTONC.GearRatio1 of
    the slave in every NC cycle. A new rising edge on a slave this block (or another GearInDyn)
    still couples to the same master is accepted (TcMC 3.19: "a rising edge at Execute will then
    be accepted"): the NC takes the coupling over at its current ratio, without a jump.
    Hence **the client running this block must be the one supplying the slave's PLCTONC, i.e.
    it runs the slave's MC_Power** (the NC applies only the claim holder's PLCTONC; a warning is
    logged if the slave is not controlled by this task, and the coupling then keeps its initial
    ratio). A GearRatio that is not a finite number is not written (GearRatio1 keeps the last
    value); at the rising edge it is Error 0x4B06 and nothing is sent.

    Busy is TRUE from the rising edge until the falling edge of Execute: the falling edge ends
    the block (Busy and InGear fall, no result output); the coupling stays at the last ratio,
    because GearRatio1 keeps its last value. If Execute falls before the NC's reply arrived,
    the block waits for it (an Error is then shown for one cycle). While Execute is TRUE, a
    decoupling of the slave - its coupling job ending DONE (MC_GearOut) or ABORTED - is
    CommandAborted, an ERROR end is Error. Afterwards the block no longer writes GearRatio1.
    """

    CMD = "GearInDyn"
    _INPUTS = {"Execute": False, "GearRatio": 1.0, **_DYN}
    GearRatio: float
    Acceleration: float
    Deceleration: float
    Jerk: float

    def _ratio_args(self) -> dict[str, Any] | None:
        r = self.GearRatio
        return {"GearRatio": float(r)} if self._is_real(r) else None

    def _write_ratio(self) -> None:
        ax = self.Axis
        if ax is not None and self._is_real(self.GearRatio):
            ax.PlcToNc["GearRatio1"] = float(self.GearRatio)

    def _before_send(self) -> None:
        ax = self.Axis
        assert ax is not None
        if not ax.controlled:
            log.warning("%s on %r: this task does not control the slave (no MC_Power): the NC will not see "
                        "GearRatio1 changes", type(self).__name__, ax)

    def _progress(self) -> None:
        if not self._take_reply():
            return
        if self.Execute:
            self._write_ratio()
        if not self.Execute:
            self._end_quietly()  # the falling edge finishes the command; the coupling stays
            return
        self._follow()

    def _decoupled(self) -> None:
        self._finish("CommandAborted")  # decoupled while Execute is TRUE


class MC_GearOut(_SlaveCall, ExecuteBlock):
    """Decouple the slave (TcMC 3.20): Done once the NC accepted it and the frame shows it.

    Inputs: Execute. Outputs: Done, Busy, Error, ErrorID (0x4B05: the slave is not coupled).
    VAR_IN_OUT: Slave. A slave decoupled in motion goes on at constant velocity (stop it with
    MC_Stop / MC_Halt); that velocity job is not followed by this block.
    """

    _OUTPUTS = {"Done": False, "Busy": False, "Error": False, "ErrorID": 0}

    def _start(self) -> None:
        self._cycle_no = 0
        self._send("GearOut")

    def _progress(self) -> None:
        if self._reply_shown():
            self._finish("Done")


#: E_DecoupleMode -> how the follow-on command ends (see the module docstring)
_GEAROUT_END = {int(E_DecoupleMode[name]): end for name, end in (
    ("MC_DECOUPLEMODE_STOP", "standstill"), ("MC_DECOUPLEMODE_ORIENTEDSTOP", "standstill"),
    ("MC_DECOUPLEMODE_ENDLESS", "velocity"), ("MC_DECOUPLEMODE_ENDLESS_NEWVELO", "velocity"),
    ("MC_DECOUPLEMODE_NEWPOS", "window"), ("MC_DECOUPLEMODE_NEWPOSANDVELO", "window"),
    ("MC_DECOUPLEMODE_INSTANTANEOUSSTOP", "standstill"))}


class MC_GearOutExt(_SlaveCall, MotionBlock):
    """Decouple and continue with the command of Mode (TcMC 3.21).

    Inputs: Execute, Mode (E_DecoupleMode 0..6), Position [u] (NEWPOS/NEWPOSANDVELO: absolute
    target; ORIENTEDSTOP: modulo position), Velocity [u/s] (ENDLESS_NEWVELO/NEWPOSANDVELO),
    Acceleration, Deceleration, Jerk (0 = axis default). Outputs: Done, Busy, CommandAborted,
    Error, ErrorID. VAR_IN_OUT: Slave. See the module docstring for when it is Done. ORIENTEDSTOP
    with the oriented position beyond an enabled software limit: the slave is decoupled and makes
    the standard stop, then Error 0x4222 (as MC_OrientedStop, TcMC 3.16).
    """

    CMD = "GearOutExt"
    _UNDO_ON_LOSS = False  # it ends a coupling with a stop: nothing to undo
    _INPUTS = {"Execute": False, "Mode": 0, "Position": 0.0, "Velocity": 0.0, **_DYN}
    _OUTPUTS = {"Done": False, "Busy": False, "CommandAborted": False, "Error": False, "ErrorID": 0}
    Mode: int
    Position: float
    Velocity: float
    Acceleration: float
    Deceleration: float
    Jerk: float
    _REALS = ("Position", "Velocity", "Acceleration", "Deceleration", "Jerk")

    def __init__(self, timeout: float | None = None) -> None:
        super().__init__(timeout)
        self._end_rule = "standstill"
        self._standing = False  # reply CmdNo 0: decoupled at standstill, nothing to follow

    def _start(self) -> None:
        self._standing = False
        mode = _integer_in(self.Mode, min(_GEAROUT_END), max(_GEAROUT_END))
        if mode is None or mode not in _GEAROUT_END:
            self._finish("Error", ErrorCodes.MC_INVALID_MODE)
            return
        self._end_rule = _GEAROUT_END[mode]
        super()._start()

    def _args(self) -> dict[str, Any] | None:
        a = super()._args()
        if a is not None:
            a["Mode"] = int(self.Mode)
        return a

    def _progress(self) -> None:
        if not self._cmdno and not self._standing:
            if self._lost_axis():
                return
            reply = self._await_reply()
            if reply is None:
                return
            self._pending = None
            cmdno = int(reply.get("CmdNo", 0))
            if not cmdno:
                self._standing = True
                self._cycle_no = reply_cycle(reply)
            else:
                self._cmdno, self._cmd_cycle = cmdno, reply_cycle(reply)
        if self._standing:
            if not self._lost_axis() and self.Axis is not None and self.Axis.shows_cycle(self._cycle_no):
                self._finish("Done")
            return
        self._follow()

    def _on_active(self, sdw: int) -> None:
        if self._end_rule == "velocity" and sdw & _CONSTV and sdw & _HASJOB:
            self._finish("Done")

    def _on_done(self, rec: Any, sdw: int) -> None:
        if self._end_rule == "velocity":
            # an endless motion only ends by being taken over (Ended DONE -> _done_now) or aborted
            self._finish("CommandAborted")
        elif self._end_rule == "standstill":
            if not sdw & _HASJOB:
                self._finish("Done")
        else:
            super()._on_done(rec, sdw)  # target rule (class _END "window")
