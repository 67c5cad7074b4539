"""Common machinery of the TcMC function blocks.

Call style (IEC 61131-3 ST semantics): ``fb(Axis=ax, Execute=True, Position=10.0)``.
Inputs not passed keep their last value; outputs are attributes; the call returns the
block itself, so ``if mv(Axis=ax, Execute=True).Done:`` works. An unknown input name
raises ``TypeError`` (it is a program bug, like a compile error); bad input *values* never
raise: the block reports ``Error`` with a TwinCAT error code.

Output rules (Tc2_MC2 "General rules for MC function blocks", TcMC appendix 7.1), for the
Execute blocks:

* the command starts on the rising edge of Execute; inputs are latched then;
* Busy, Done, Error and CommandAborted are mutually exclusive; Active only while the
  block's command is the axis's active command;
* Done/Error/CommandAborted stay TRUE while Execute stays TRUE; if Execute fell before
  the end, the output is TRUE for exactly one cycle;
* a rising edge while Busy is ignored (no feedback, no second command);
* the outputs are reset on Execute falling when the block is not Busy;
* an axis bound while the PLC runs (an AXIS_REF made or first used in a cycle) has no data until its NC's
  view frames include it (``AXIS_REF.pending``, a few ms; at most the task's ``command_timeout``): a call
  of a block on it in between is not evaluated (outputs unchanged; its inputs, edges included, are taken
  by the first call with the data), as a PLC whose task waits for its I/O; past that time it is stale;
* an axis whose data is stale (``AXIS_REF.Status.Valid`` False) makes a block that acts
  on it report Error 0x4B0F (0x4012 if frames arrive without that axis); a Busy block ends so
  as soon as it sees the data stale or the NC restarted (:meth:`ExecuteBlock._lost_axis`, the
  one path every block family follows, waiting for a reply included), and hands the motion command
  it followed to the task (``_on_axis_lost``: the task stops it if the same NC still runs it
  when its data comes back, see :mod:`plc_client.task`).

Timeouts: ``timeout`` (constructor argument, seconds, default the task's
``command_timeout``, 1 s) bounds the wait for the NC's reply: no reply -> Error 0x745.

When a command shows (one rule for every block, AXACT included): the NC's reply carries ``cycle``, the NC
cycle whose frame first shows the command's effect; over a real network the reply arrives before that
frame. A block reads the axis's data for its command only from the first frame with
``Cycle >= reply cycle`` (:func:`plc_client.port.reply_cycle`, :meth:`plc_client.axis_ref.AXIS_REF.shows_cycle`),
so its outputs never contradict the axis's data (a Busy that fell while HasJob is still FALSE).

Names (Structured Text ignores case; zenoh-nc's rules, :class:`FunctionBlock`): every declared input and
output answers in any case: ``fb.ErrorId is fb.ErrorID``, ``fb(execute=True)``. The exact spelling costs
nothing extra (the ordinary attribute lookup finds it); another spelling is resolved on a miss
(``__getattr__``) and, for call keywords, when the name is not a declared input. An attribute *written* in
another case (``fb.execute = True``) takes effect at the block's next call (checking every write would
double a simple block's cost); until then reading that spelling returns what was written. ``Axis``,
``Master``, ``Slave`` and ``TriggerInput`` (VAR_IN_OUT, the calls' own keywords) stay case-sensitive. Two
declared names that differ only in case are refused when the class is defined (TypeError). The type
checker still sees only the declared spelling, so mypy flags a misspelling in typed code.
"""
from __future__ import annotations

import math
import numbers
from typing import TYPE_CHECKING, Any, ClassVar, Self

import numpy as np

from nc_schema import ErrorCodes, cmdno_newer

from ..axis_ref import AXIS_REF
from ..port import PendingCommand, reply_cycle
from ..task import PlcTask, current_task


def _fold_maps(cls: type[FunctionBlock]) -> tuple[dict[str, str], dict[str, str]]:
    """(lower-case name -> declared name) of ``cls``'s inputs and outputs, and of its inputs alone.

    Raises:
        TypeError: two declared names differ only in case (ST could not tell them apart).
    """
    every: dict[str, str] = {}
    inputs: dict[str, str] = {}
    for table, names in ((inputs, cls._INPUTS), (every, cls._INPUTS), (every, cls._OUTPUTS)):
        for name in names:
            seen = table.setdefault(name.lower(), name)
            if seen != name:
                raise TypeError(f"{cls.__qualname__}: {seen!r} and {name!r} differ only in case "
                                "(Structured Text names ignore case)")
    return every, inputs


def _plain_io(cls: type[FunctionBlock]) -> bool:
    """Whether every declared input and output of ``cls`` is a plain instance attribute (see ``_PLAIN_IO``)."""
    if cls.__setattr__ is not object.__setattr__:
        return False
    for name in (*cls._INPUTS, *cls._OUTPUTS):
        for c in cls.__mro__:
            if hasattr(type(c.__dict__.get(name)), "__set__"):  # a property, a slot, another data descriptor
                return False
    return True


class FunctionBlock:
    """Base of all blocks: input handling, names in any case and the Axis binding.

    Subclasses declare ``_INPUTS`` (name -> default) and ``_OUTPUTS`` (name -> reset value), and
    annotate each of those names in the class body (``Execute: bool``) so that the type checker
    knows the attributes ``__init__`` creates from the two maps (tests/plc/test_declarations.py
    checks that none is missing). Every declared name also answers in any case (the module
    docstring, "Names"); ``__init_subclass__`` builds the class's case maps and refuses two declared
    names that differ only in case (TypeError).
    """

    _INPUTS: ClassVar[dict[str, Any]] = {}
    _OUTPUTS: ClassVar[dict[str, Any]] = {"Error": False, "ErrorID": 0}
    #: lower-case name -> declared name of every input and output (built per class)
    _FOLD: ClassVar[dict[str, str]] = {}
    #: the same for the inputs alone (call keywords)
    _FOLD_INPUTS: ClassVar[dict[str, str]] = {}

    #: the declared inputs and outputs are plain instance attributes (no property or other descriptor of
    #: that name on the class, no ``__setattr__`` of its own): the per-cycle paths may write them with one
    #: ``__dict__.update`` instead of a ``setattr`` each (built per class)
    _PLAIN_IO: ClassVar[bool] = True
    #: the class keeps FunctionBlock._held (its test is done inline in ``__call__``: a call per block and
    #: cycle less; built per class)
    _PLAIN_HELD: ClassVar[bool] = True
    #: the declared inputs' names (built per class): ``_INPUT_SET.issuperset(inputs)`` is the cheapest test
    _INPUT_SET: ClassVar[frozenset[str]] = frozenset()

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        cls._FOLD, cls._FOLD_INPUTS = _fold_maps(cls)
        cls._PLAIN_IO = _plain_io(cls)
        cls._PLAIN_HELD = cls._held is FunctionBlock._held
        cls._INPUT_SET = frozenset(cls._INPUTS)

    def __init__(self, timeout: float | None = None) -> None:
        if timeout is not None and not (isinstance(timeout, (int, float)) and timeout > 0):
            raise ValueError(f"timeout must be > 0 s, got {timeout!r}")
        self.timeout = timeout
        self.Axis: AXIS_REF | None = None
        for k, v in self._INPUTS.items():
            setattr(self, k, v)
        self._reset_outputs()
        self._n_attrs = -1  # attributes of the instance at the last call (-1: look at the next call)

    def _reset_outputs(self) -> None:
        if self._PLAIN_IO:
            self.__dict__.update(self._OUTPUTS)
            return
        for k, v in self._OUTPUTS.items():
            setattr(self, k, v)

    if not TYPE_CHECKING:  # (hidden from mypy: it keeps flagging misspellings in typed code)
        def __getattr__(self, name: str) -> Any:
            """A declared input/output read in another case (called only when the exact lookup fails)."""
            real = type(self)._FOLD.get(name.lower())
            if real is None or real == name:
                raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")
            return getattr(self, real)

    def __call__(self, Axis: AXIS_REF | None = None, **inputs: Any) -> Self:
        if Axis is not None and Axis is not self.Axis:
            if not isinstance(Axis, AXIS_REF):
                raise TypeError(f"{type(self).__name__}: Axis must be an AXIS_REF, got {type(Axis).__name__}")
            self.Axis = Axis
        # _set_inputs and _held inline where they would do their usual (every cycle: ~2 calls per block less)
        d = self.__dict__
        if len(d) == self._n_attrs and self._PLAIN_IO and self._INPUT_SET.issuperset(inputs):
            d.update(inputs)
        else:
            self._set_inputs(inputs)
        if self._PLAIN_HELD:
            ax = self.Axis
            if ax is not None:
                if ax._task is None:
                    self._task()
                if ax.pending:
                    return self
        elif self._held():
            return self
        self._cycle()
        return self

    def _held(self) -> bool:
        """True if the block waits for its axis's first data (``AXIS_REF.pending``: bound after the client
        asked for its view, the NC has not sent it yet): the call is not evaluated, its outputs stay and its
        inputs are taken, edges included, by the first call with the data. Binds an unbound Axis first."""
        ax = self.Axis
        if ax is None:
            return False
        if ax._task is None:
            self._task()
        return ax.pending

    def _set_inputs(self, inputs: dict[str, Any]) -> None:
        """Apply the call's inputs (any case) after the attributes written in another case since the last call.

        Raises:
            TypeError: an unknown input, or one given twice in different cases (a program bug).
        """
        if len(self.__dict__) != self._n_attrs:  # an attribute appeared: maybe ``fb.execute = ...``
            self._fold_writes()
        if self._PLAIN_IO and inputs.keys() <= self._INPUTS.keys():  # every name as declared: one update
            self.__dict__.update(inputs)
            return
        for k, v in inputs.items():
            if k not in self._INPUTS:
                k = self._input_name(k, inputs)
            setattr(self, k, v)

    def _input_name(self, k: str, inputs: dict[str, Any]) -> str:
        low = k.lower()
        real = self._FOLD_INPUTS.get(low)
        if real is None:
            raise TypeError(f"{type(self).__name__} has no input {k!r} (inputs: {', '.join(self._INPUTS)})")
        same = [j for j in inputs if j.lower() == low]
        if len(same) > 1:
            raise TypeError(f"{type(self).__name__}: input {real!r} given twice ({', '.join(same)})")
        return real

    def _fold_writes(self) -> None:
        """Move attributes written in another case than declared (``fb.execute = True``) onto the declared ones."""
        d = self.__dict__
        fold = self._FOLD
        for k in [k for k in d if k.lower() in fold and fold[k.lower()] != k]:
            setattr(self, fold[k.lower()], d.pop(k))
        self._n_attrs = len(d)

    def _cycle(self) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    # -- helpers ---------------------------------------------------------------------
    def _task(self) -> PlcTask | None:
        """The task of the Axis, binding it to the running task on first use."""
        ax = self.Axis
        if ax is None:
            return None
        if ax._task is None:
            t = current_task()
            if t is None:
                return None
            t.register(ax)
        return ax._task

    def _axis_problem(self) -> int:
        """0 if the Axis has valid data, else the error code to report."""
        ax = self.Axis
        if ax is None or (ax._task is None and self._task() is None):  # (bound: no call)
            return ErrorCodes.MC_NO_NC_CYCLE_UPDATE
        if ax.missing:
            return ErrorCodes.NC_AXIS_ID_NOT_ALLOWED
        if not ax.Status.Valid:
            return ErrorCodes.MC_NO_NC_CYCLE_UPDATE
        return 0

    def _timeout(self) -> float:
        if self.timeout is not None:
            return float(self.timeout)
        t = self.Axis._task if self.Axis is not None else None
        return t.command_timeout if t is not None else 1.0

    @staticmethod
    def _is_real(v: Any) -> bool:
        t = type(v)
        if t is float or t is int:  # the usual inputs, without the ABC check below (slow: every cycle)
            return math.isfinite(v)
        # numbers.Real also admits numpy scalars (np.float32 ...); BOOL is not a number here
        return isinstance(v, numbers.Real) and not isinstance(v, (bool, np.bool_)) and math.isfinite(v)

    def __repr__(self) -> str:
        outs = ", ".join(f"{k}={getattr(self, k)!r}" for k in self._OUTPUTS if getattr(self, k))
        return f"{type(self).__name__}({outs})"


FunctionBlock._FOLD, FunctionBlock._FOLD_INPUTS = _fold_maps(FunctionBlock)


class ExecuteBlock(FunctionBlock):
    """An Execute-triggered block (see the module docstring for the output rules).

    Subclasses implement ``_start()`` (rising edge, not Busy: latch and send; may finish at
    once) and ``_progress()`` (each cycle while Busy). They end with :meth:`_finish`.
    """

    _INPUTS: ClassVar[dict[str, Any]] = {"Execute": False}
    _OUTPUTS: ClassVar[dict[str, Any]] = {"Done": False, "Busy": False, "Active": False, "CommandAborted": False,
                                          "Error": False, "ErrorID": 0}
    #: the output that means success (InVelocity for MC_MoveVelocity)
    _DONE: ClassVar[str] = "Done"
    Execute: bool
    Done: bool
    Busy: bool
    Active: bool
    CommandAborted: bool
    Error: bool
    ErrorID: int

    def __init__(self, timeout: float | None = None) -> None:
        super().__init__(timeout)
        self._prev_execute = False
        self._pending: PendingCommand | None = None
        self._epoch = 0
        self._cycle_no = 0  # the reply's NC cycle (blocks that wait for their effect to show)

    @property
    def request(self) -> PendingCommand | None:
        """The NC request of the block's current command (None: none out; a refusal by the block itself sends
        none). Diagnostics and benches: its ``reply`` once ``done``."""
        return self._pending

    def _cycle(self) -> None:
        ex = bool(self.Execute)
        rising = ex and not self._prev_execute
        falling = self._prev_execute and not ex
        self._prev_execute = ex
        if not self.Busy and (not ex or rising):
            # falling edge (or a result shown for its one cycle) resets the outputs
            self._reset_outputs()
        if rising and not self.Busy:
            self._reset_outputs()
            self.Busy = True
            self._start()
        elif self.Busy:
            if falling:
                self._on_execute_fell()
            self._progress()

    def _start(self) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def _progress(self) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def _on_execute_fell(self) -> None:
        """Execute fell while Busy: the command goes on (MC_Stop overrides)."""

    def _finish(self, result: str, error_id: int = 0) -> None:
        """End the command: result is the done output name, 'Error' or 'CommandAborted'."""
        if self._pending is not None and not self._pending.done:
            self._pending.abandon()
        self._pending = None
        self.Busy = False
        self.Active = False
        setattr(self, result, True)
        if result == "Error":
            self.ErrorID = int(error_id) or ErrorCodes.NC_INTERNAL

    def _check_inputs(self, reals: tuple[str, ...] = (), buffer_mode: bool = True) -> bool:
        """Validate latched inputs; finish with Error and return False if one is bad."""
        for name in reals:
            if not self._is_real(getattr(self, name)):
                self._finish("Error", ErrorCodes.MC_PARAMETER_NOT_CORRECT)
                return False
        if buffer_mode:
            bm = getattr(self, "BufferMode", 0)
            if isinstance(bm, (bool, np.bool_)) or not isinstance(bm, numbers.Integral) or int(bm) != 0:
                self._finish("Error", ErrorCodes.MC_BUFFERMODE_NOT_SUPPORTED)
                return False
        return True

    def _usable_axis(self) -> AXIS_REF | None:
        """The bound Axis if a command can use it now; else the block finishes with its error
        (unbound, stale data, not in the frames) and None is returned."""
        code = self._axis_problem()
        if code:
            self._finish("Error", code)
            return None
        return self.Axis

    def _send(self, cmd: str, **args: Any) -> bool:
        """Send ``cmd`` for the Axis; finish with Error and return False if that is impossible."""
        ax = self._usable_axis()
        if ax is None:
            return False
        assert ax._task is not None  # (_usable_axis: bound)
        self._epoch = ax.nc_epoch
        self._pending = ax._task.send(ax, cmd, **args)
        return True

    def _lost_axis(self) -> bool:
        """Finish with Error if the axis data is stale/missing or the NC restarted since the send
        (then :meth:`_on_axis_lost`)."""
        ax = self.Axis
        if ax is not None and ax._task is not None and not ax.missing and ax.Status.Valid \
                and ax.nc_epoch == self._epoch:
            return False  # (the usual answer, every cycle of a busy block: without the _axis_problem call; the same
            # test is inlined in MotionBlock._follow: change both)
        code = self._axis_problem()
        if not code and ax is not None and ax.nc_epoch != self._epoch:
            code = ErrorCodes.MC_NO_NC_CYCLE_UPDATE
        if code:
            self._finish("Error", code)
            if ax is not None and ax._task is not None:
                self._on_axis_lost(ax, ax._task)
            return True
        return False

    def _on_axis_lost(self, ax: AXIS_REF, task: PlcTask) -> None:
        """The block just ended with Error because the axis's data was lost: hand what it followed
        to the task (``task.lost_command``) if the NC may still run it. Default: nothing."""

    def _reply_shown(self) -> bool:
        """True once the NC accepted the command and a frame of the reply's cycle (or later) is
        here, so the effect is visible; finishes with Error on loss, rejection or timeout.
        ``self._cycle_no`` (reset it in ``_start``) keeps the reply's cycle."""
        if self._lost_axis():
            return False
        if not self._cycle_no:
            reply = self._await_reply()
            if reply is None:
                return False
            self._cycle_no = reply_cycle(reply)
            self._pending = None
        return self.Axis is not None and self.Axis.shows_cycle(self._cycle_no)

    def _own_slot(self, no_field: str, state_field: str, no: int, cycle: int) -> tuple[int, Any] | None:
        """(state, job record) of this block's command ``no`` in a slot of the axis's job record
        (NCJOBS ``no_field``/``state_field``: the superposition, the touch probe) once a frame of
        ``cycle`` is here; None while waiting, or after the block finished: the axis lost (its
        error), no job records or an older number there (0x4B60), a newer one (CommandAborted:
        replaced)."""
        if self._lost_axis():
            return None
        ax = self.Axis
        assert ax is not None
        if not ax.shows_cycle(cycle):
            return None  # the frame does not show the command yet
        jobs = ax._jobs  # (plain values; subclasses read more members of it by name)
        if not jobs.AxisId:
            self._finish("Error", ErrorCodes.MC_CMD_NOT_ACTIVE)  # no job records: cannot be followed
            return None
        shown = int(jobs[no_field])
        if shown != no:
            if cmdno_newer(shown, no):
                self._finish("CommandAborted")  # a newer one replaced ours
            else:
                self._finish("Error", ErrorCodes.MC_CMD_NOT_ACTIVE)
            return None
        return int(jobs[state_field]), jobs

    def _accepted(self) -> tuple[int, int, dict[str, Any]] | None:
        """(CmdNo, cycle, reply) once the NC accepted the command with a number; None while waiting
        (or after the block finished: a lost axis, a refusal, a timeout, CmdNo 0 -> 0x4B65)."""
        if self._lost_axis():
            return None
        reply = self._await_reply()
        if reply is None:
            return None
        no = int(reply.get("CmdNo", 0))
        if not no:
            self._finish("Error", ErrorCodes.MC_CMD_NUMBER_ZERO)
            return None
        self._pending = None
        return no, reply_cycle(reply), reply

    def _await_reply(self) -> dict[str, Any] | None:
        """The reply once it arrived (error 0); finishes with Error on rejection/timeout, or at
        once (0x4B0F) when the axis's data is lost meanwhile."""
        p = self._pending
        if p is None:
            return None
        if not p.done and self._lost_axis():
            return None
        if p.done:
            if p.reply is None:
                self._finish("Error", p.failed)
                return None
            err = int(p.reply.get("error", 0))
            if err:
                self._finish("Error", err)
                return None
            return p.reply
        if self.Axis is not None and self.Axis._task is not None and self.Axis._task.now - p.sent_at >= self._timeout():
            self._finish("Error", ErrorCodes.ADSERR_CLIENT_SYNCTIMEOUT)
        return None


class EnableBlock(FunctionBlock):
    """An Enable-level block (MC_Read*): Valid/Done while Enable and the data is valid."""

    _INPUTS: ClassVar[dict[str, Any]] = {"Enable": False}
    _OUTPUTS: ClassVar[dict[str, Any]] = {"Valid": False, "Done": False, "Busy": False, "Error": False, "ErrorID": 0}
    Enable: bool
    Valid: bool
    Done: bool
    Busy: bool
    Error: bool
    ErrorID: int

    def _cycle(self) -> None:
        if not self.Enable:
            self.Valid = self.Done = self.Busy = self.Error = False
            self.ErrorID = 0
            return
        self.Busy = True
        ax = self.Axis
        # (_axis_problem's answer for a bound axis with valid data, without the call)
        code = 0 if ax is not None and ax._task is not None and not ax.missing and ax.Status.Valid \
            else self._axis_problem()
        if code:
            self.Valid = self.Done = False
            self.Error, self.ErrorID = True, code
            return
        self.Error, self.ErrorID = False, 0
        assert self.Axis is not None  # (_axis_problem checked it)
        self._read(self.Axis)
        self.Valid = self.Done = True

    def _read(self, ax: AXIS_REF) -> None:  # pragma: no cover - abstract
        raise NotImplementedError
