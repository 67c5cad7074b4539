"""The cyclic PLC task, independent of the transport.

:class:`PlcTask` does, once per PLC cycle (:meth:`PlcTask.step`):

1. take the newest NC status frame of every NC and snapshot it into the bound
   :class:`~plc_client.axis_ref.AXIS_REF` objects (by AxisId), marking stale data;
2. drain the command port's replies (claims, late replies, detached commands);
3. run the user program (``program(plc)``, or ``program.cycle(plc)`` / ``program.cycle()``)
   with this task as the *current task*, so an AXIS_REF passed to a function block for the
   first time is bound to it (the program's declared axes are bound before the first cycle:
   the ``axes`` argument, which ``plc-run`` fills from :func:`plc_client.program.load`);
4. publish one batched PLCTONC frame per NC for the axes this task controls.

Transports subclass it (:class:`plc_client.runtime.PlcRuntime` over zenoh,
:class:`nc_sim.InProcessPlc` against an in-process ``NcCore``).

Claims: an axis becomes *controlled* the first time an ``MC_Power`` block is called on it;
the task then sends ``Claim`` (the NC refuses with 0x723 while another live client holds the
axis). A refused or timed-out claim is retried on MC_Power's Enable rising edge and every
``claim_retry`` seconds while Enable stays TRUE. An NC restart (a new NC instance: its instance token
carries another id, or its frames' cycle counter went back, :class:`nc_schema.NcInstance`; a liveliness
token that goes and comes back is none) forgets all claims on that NC; MC_Power claims again.

Late replies (zenoh-nc choice, the manual is silent): a block that times out (0x745)
abandons its request. If the NC accepted it anyway (late reply with error 0), the task
checks the frames once they reach the reply's cycle: if that command is still the axis's
active command (same CmdNo, CmdState ACTIVE) - i.e. the axis is moving for a command the
PLC program believes failed - the task sends ``Halt`` (a normal stop, no lock) and logs a
warning. A late ``Stop`` leaves the axis stopped and locked (safe; MC_Stop/MC_Reset unlock).
A late ``Claim`` makes the claim held.

Claim loss: when an axis this task holds shows the NC's claim faults (0x8F01 client lost,
0x8F02 PLCTONC timeout: the NC dropped the claim), the claim is requested again by MC_Power;
the axis stays in ErrorStop until MC_Reset (MC_Power's Error/ErrorID show 0x8F01/0x8F02 meanwhile).

Hand-over (:meth:`PlcTask.hand_over`, :meth:`PlcTask.expect_hand_over`; docs/arbitration.md): the
holder gives an axis to another live client without disabling it. The receiver first expects it:
its MC_Power publishes PLCTONC for the axis (Enable TRUE) while its claim waits without an error of its own,
polling ``Claim`` every :data:`HANDOVER_POLL` s; the NC applies the receiver's frames from the
hand-over on (until then the giver's last one), so the axis is never disabled. The giver's claim
becomes 'handed' (MC_Power: no error of its own, not Active; it claims again only on an Enable rising edge).

Losing the NC (killed, frozen, the link cut): the axes' data turns invalid at once when the NC's
liveliness token disappears (else after ``stale_cycles``), so blocks end with 0x4B0F instead of
waiting. A block that gives up following an accepted motion command that way hands it to the task
(:meth:`PlcTask.lost_command`): when frames of the same NC instance come back (its cycle counter
did not go back) and that command is still running, the task stops it (Halt; Stop + StopRelease for
homing, GearOut for a coupling, AbortSuperposition for a superposition) - the axis never goes on
moving for a block that reported an error.
"""
from __future__ import annotations

import collections
import inspect
import logging
import math
import struct
import threading
import time
from typing import Any, Callable, Iterable

import numpy as np

from nc_schema import (COMMAND_SPECS, JOB_RECORDS, MOTION_COMMANDS, NCJOBS_SIZE, NCTOPLC_DTYPE, NCTOPLC_SIZE, CmdState,
                       ControlDWord, ErrorCodes, NcInstance, StateDWord, error_text, frame_header_values, member_struct)

# The command sets come from the contract's command properties (protocol.json, nc_schema.COMMAND_SPECS).
#: motion commands whose CmdNo numbers a slot of their own (not NCTOPLC.CmdNo): ``slot``
_SLOT_COMMANDS = frozenset(n for n, s in COMMAND_SPECS.items() if s.motion and s.slot is not None)
#: commands that change a running job (their CmdNo is that job's: not theirs to undo): ``amends``
_AMENDS = frozenset(n for n, s in COMMAND_SPECS.items() if s.amends)
#: plain stops: a late one is left as it is (it only stops): ``stop``
_STOPS = frozenset(n for n, s in COMMAND_SPECS.items() if s.stop)

from .axis_ref import AXIS_REF
from .plcframe import PlcFrameBuffer
from .port import CommandPort, PendingCommand, reply_cycle

log = logging.getLogger(__name__)

_local = threading.local()

_ENABLE = int(ControlDWord.Enable)
_CLC = int(StateDWord.ControlLoopClosed)
_ERROR = int(StateDWord.Error)
#: Axis errors with which the NC drops a claim (zenoh-nc server watchdog).
_CLAIM_FAULTS = frozenset({int(ErrorCodes.ZNC_CLIENT_LOST), int(ErrorCodes.ZNC_PLCTONC_TIMEOUT)})

#: Data older than this is stale when the task is built without ``stale_cycles`` [s].
DEFAULT_STALE_TIME = 0.2
#: While expecting a hand-over, Claim is re-sent this often [s] (its success shows the hand-over).
HANDOVER_POLL = 0.05
#: A command lost with the NC is forgotten if no frame comes back within this time [s].
LOST_COMMAND_TTL = 600.0
#: what stops a motion command nobody follows any more, where it is not the default Halt: ``undo``
_UNDO = {n: s.undo for n, s in COMMAND_SPECS.items() if s.motion and not s.stop and s.undo != ("Halt",)}


#: a frame as the task keeps it: (cycle, NCTOPLC records, AxisId -> row, NCJOBS records or None); the arrays
#: are None for a frame taken as bytes (PlcTask._set_frame_bytes: its bytes are in PlcTask._frame_bytes)
_FrameEntry = tuple[int, "np.ndarray | None", dict[int, int], "np.ndarray | None"]
#: where an NCTOPLC record keeps its AxisId, and its struct code
_AXIS_ID_OFFSET, _AXIS_ID = member_struct(NCTOPLC_DTYPE, "AxisId")
_AXIS_IDS: dict[int, struct.Struct] = {}


def _axis_ids_struct(n: int) -> struct.Struct:
    """The struct that reads the AxisIds of ``n`` consecutive NCTOPLC records (from the first one's start)."""
    st = _AXIS_IDS.get(n)
    if st is None:
        if len(_AXIS_IDS) >= 64:
            _AXIS_IDS.clear()
        code, pad = _AXIS_ID.format[-1], NCTOPLC_SIZE - _AXIS_ID.size
        st = _AXIS_IDS[n] = struct.Struct("<" + (f"{_AXIS_ID_OFFSET}x{code}{pad - _AXIS_ID_OFFSET}x" * n))
    return st


def current_task() -> PlcTask | None:
    """The task whose program is running in this thread (None outside a PLC cycle)."""
    return getattr(_local, "task", None)


class ClaimState:
    """Claim of one axis by this task: ``state`` is 'none', 'pending', 'held', 'refused',
    'awaiting' (expecting a hand-over: Claim is polled, a refusal is no error) or 'handed'
    (given to another client with HandOver). ``error``: the refusal's code while 'refused', and while
    'pending' the retry of a refused claim (kept until the NC's answer replaces it: MC_Power's Error
    does not drop for every retry's round trip); 0 otherwise."""

    __slots__ = ("state", "error", "pending", "since", "fault_seen")

    def __init__(self) -> None:
        self.fault_seen = False
        self.state = "none"
        self.error = 0
        self.pending: PendingCommand | None = None
        self.since = 0.0

    def __repr__(self) -> str:
        return f"ClaimState({self.state}, error=0x{self.error:X})"


class _Orphan:
    """A motion command the NC may still run although no block follows it any more.

    ``lost``: its block gave up because the NC's data was lost (checked at the first valid frame: a
    frame with a cycle below ``cycle``, or another ``epoch``, is a restarted NC, which knows nothing of it); else a late
    acceptance after a block timeout (checked once a frame of the reply's ``cycle`` is there, only
    while ``epoch`` is the axis's).
    """

    __slots__ = ("ax", "cmdno", "cycle", "epoch", "cmd", "lost", "since")

    def __init__(self, ax: AXIS_REF, cmdno: int, cycle: int, epoch: int, cmd: str, lost: bool = False,
                 since: float = 0.0) -> None:
        self.ax, self.cmdno, self.cycle, self.epoch, self.cmd = ax, cmdno, cycle, epoch, cmd
        self.lost, self.since = lost, since


class HandOverRequest:
    """A hand-over asked for with :meth:`PlcTask.hand_over` (sent at the next cycle start).

    Attributes:
        nc, axis_id, to: what is handed to whom.
        pending: the HandOver command once sent (None before).
        done: True once the NC answered (or the request could not be sent).
        error: 0 on success, else the error code (0x723: not the holder, or ``to`` unknown).
    """

    __slots__ = ("nc", "axis_id", "to", "pending", "done", "error")

    def __init__(self, nc: str, axis_id: int, to: str) -> None:
        self.nc, self.axis_id, self.to = nc, int(axis_id), to
        self.pending: PendingCommand | None = None
        self.done = False
        self.error = 0

    def __repr__(self) -> str:
        state = "waiting" if not self.done else f"error=0x{self.error:X}"
        return f"HandOverRequest({self.nc}/{self.axis_id} -> {self.to} {state})"


def _program_caller(program: Any) -> Callable[[PlcTask], Any] | None:
    """Normalize a program: a callable(plc), an object with cycle(plc) or cycle(), or None."""
    if program is None:
        return None
    fn = getattr(program, "cycle", None)
    if fn is None:
        if not callable(program):
            raise TypeError(f"program must be callable or have a cycle() method, got {program!r}")
        fn = program
    try:
        n = len([p for p in inspect.signature(fn).parameters.values()
                 if p.default is p.empty and p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD)])
    except (TypeError, ValueError):
        n = 1
    return (lambda plc: fn()) if n == 0 else fn


class PlcTask:
    """Transport-independent PLC task (see the module docstring).

    Args:
        program: called once per cycle (see :func:`_program_caller`); may be None.
        cycle_time: nominal PLC cycle [s] (> 0).
        client_id: this PLC's client id.
        stale_cycles: PLC cycles without a newer NC frame after which axis data is invalid;
            default: ``ceil(0.2 s / cycle_time)``, at least 3.
        command_timeout: default Timeout of the function blocks [s].
        claim_retry: seconds between claim retries while MC_Power.Enable stays TRUE.
        axes: AXIS_REFs to bind now (the program's declared axes: ``plc-run`` passes what
            :func:`plc_client.program.load` found), so their data is refreshed from the first cycle
            without a block being called with them; ones bound to another task are left alone.

    Attributes:
        cycle: PLC cycle counter (1 in the first cycle).
        now: task time [s] at the start of the current cycle (what block timeouts use).

    Raises:
        ValueError: invalid cycle_time, stale_cycles or timeout.
    """

    def __init__(self, program: Any = None, *, cycle_time: float = 0.010, client_id: str = "plc",
                 stale_cycles: int | None = None, command_timeout: float = 1.0, claim_retry: float = 1.0,
                 axes: Iterable[AXIS_REF] = ()) -> None:
        if not (isinstance(cycle_time, (int, float)) and math.isfinite(cycle_time) and cycle_time > 0):
            raise ValueError(f"cycle_time must be > 0 s, got {cycle_time!r}")
        if stale_cycles is None:
            stale_cycles = max(3, math.ceil(DEFAULT_STALE_TIME / cycle_time))
        if isinstance(stale_cycles, bool) or not isinstance(stale_cycles, int) or stale_cycles < 1:
            raise ValueError(f"stale_cycles must be an integer >= 1, got {stale_cycles!r}")
        if not (isinstance(command_timeout, (int, float)) and command_timeout > 0):
            raise ValueError(f"command_timeout must be > 0 s, got {command_timeout!r}")
        self._program: Any = None
        self._call: Callable[[PlcTask], Any] | None = None
        self.program = program
        self.cycle_time = float(cycle_time)
        self.client_id = client_id
        self.stale_cycles = stale_cycles
        self.command_timeout = float(command_timeout)
        self.claim_retry = float(claim_retry)
        self.cycle = 0
        self.now = 0.0
        self.port: CommandPort  # set by the subclass
        self._refs: dict[tuple[str, int], list[AXIS_REF]] = {}
        self._controlled: dict[tuple[str, int], AXIS_REF] = {}
        self._claims: dict[tuple[str, int], ClaimState] = {}
        self._orphans: list[_Orphan] = []
        self._nc_down: set[str] = set()  # NCs whose liveliness token is gone: their data is invalid
        self._requests: collections.deque[Callable[[], None]] = collections.deque()  # from other threads
        self._handovers: list[HandOverRequest] = []
        self._detached: list[tuple[PendingCommand, str]] = []
        self._epochs: dict[str, int] = {}
        #: NC -> (cycle, NCTOPLC records, AxisId -> row, NCJOBS records or None) of its newest frame
        self._frames: dict[str, _FrameEntry] = {}
        #: NC -> the AxisIds its newest frame was cut for (None: all, a whole frame): :meth:`_set_frame`
        self._covers: dict[str, frozenset[int] | None] = {}
        #: NC -> (its ``_frames`` entry, the bytes of its records and where they start): :meth:`_bytes_of`
        self._frame_bytes: dict[str, tuple[_FrameEntry, bytes, int, bytes | None, int]] = {}
        #: each NC's instance as its instance token and frames show it: the restart rule (nc_schema.instance)
        self._instances: dict[str, NcInstance] = {}
        #: NC -> (its frames' AxisIds as last seen: bytes or a tuple, AxisId -> row)
        self._index_cache: dict[str, tuple[bytes | tuple[int, ...], dict[int, int]]] = {}
        #: the controlled axes by NC, as :meth:`_publish_all` sends them (None: rebuild, they changed)
        self._plan: list[tuple[str, list[AXIS_REF]]] | None = None
        #: NC -> its PLC frame's buffer (:meth:`plc_frame`)
        self._frame_bufs: dict[str, PlcFrameBuffer] = {}
        self._initial_axes = list(axes)  # bound by bind_axes() once the subclass has its transport

    def bind_axes(self, axes: Iterable[AXIS_REF] | None = None) -> list[AXIS_REF]:
        """Bind ``axes`` (default: the constructor's ``axes``) that no task holds yet; returns those bound."""
        todo = self._initial_axes if axes is None else list(axes)
        if axes is None:
            self._initial_axes = []
        bound = []
        for ax in todo:
            if isinstance(ax, AXIS_REF) and ax._task is None:
                bound.append(self.register(ax))
        return bound

    @property
    def program(self) -> Any:
        """The user program (assignable between cycles)."""
        return self._program

    @program.setter
    def program(self, program: Any) -> None:
        self._call = _program_caller(program)
        self._program = program

    # -- clock -------------------------------------------------------------------------
    def clock(self) -> float:
        """Task time source [s]; the zenoh runtime uses time.monotonic()."""
        return time.monotonic()

    # -- axes --------------------------------------------------------------------------
    def axis(self, nc: str, axis_id: int, name: str = "") -> AXIS_REF:
        """A new AXIS_REF bound to this task."""
        return self.register(AXIS_REF(nc=nc, axis_id=axis_id, name=name))

    def register(self, ax: AXIS_REF) -> AXIS_REF:
        """Bind ``ax`` to this task (idempotent) and give it the newest snapshot at once.

        Raises:
            TypeError: ``ax`` is not an AXIS_REF.
            ValueError: ``ax`` is bound to another task.
        """
        if not isinstance(ax, AXIS_REF):
            raise TypeError(f"expected an AXIS_REF, got {type(ax).__name__}")
        if ax._task is self:
            return ax
        if ax._task is not None:
            raise ValueError(f"{ax!r} is bound to another PLC task")
        ax._task = self
        ax._pending_until = time.monotonic() + self.command_timeout
        self._refs.setdefault((ax.nc, ax.axis_id), []).append(ax)
        self._on_new_axis(ax)
        self._snapshot_one(ax)
        return ax

    def _on_new_axis(self, ax: AXIS_REF) -> None:
        """Hook: a transport may subscribe to something for a new NC."""

    @property
    def axes(self) -> list[AXIS_REF]:
        return [a for refs in self._refs.values() for a in refs]

    def is_controlled(self, ax: AXIS_REF) -> bool:
        return self._controlled.get((ax.nc, ax.axis_id)) is ax

    # -- claims ------------------------------------------------------------------------
    def control(self, ax: AXIS_REF, retry: bool = False) -> ClaimState:
        """Mark ``ax`` controlled (its PLCTONC is published) and make sure it is claimed.

        ``retry`` re-sends a refused claim (MC_Power: Enable rising edge, or claim_retry
        elapsed while Enable is TRUE).
        """
        key = (ax.nc, ax.axis_id)
        c = self._claims.get(key)
        if c is not None and c.state == "held" and not retry and self._controlled.get(key) is ax:
            # the usual call (MC_Power every cycle of an axis held): what the rest below does for it, the
            # cheap tests first (a closed loop or an axis error shows the claim is not lost)
            if (not ax.NcToPlc._sdw & (_CLC | _ERROR) and ax.Status.Valid
                    and self.now - c.since >= self.claim_retry and self.reachable(ax.nc)
                    and self._claim_looks_lost(ax, c)):
                self._send_claim(ax, c)
            return c
        prev = self._controlled.get(key)
        if prev is not ax:
            if prev is not None:
                log.warning("%r: a second AXIS_REF object controls the same axis; the newest one is published", ax)
            self._controlled[key] = ax
            self._plan = None
        if c is None:
            c = self._claims[key] = ClaimState()
        if not self.reachable(ax.nc):
            return c  # claimed as soon as the NC can be reached
        if c.state == "handed":
            if not retry:
                return c  # given away: claimed again only on a new Enable edge
            c.state = "none"
        if c.state == "awaiting":
            if c.pending is None and self.now - c.since >= HANDOVER_POLL:
                c.since = self.now
                c.pending = self.port.send(ax.nc, ax.axis_id, "Claim")
                c.pending.owner = ax
            return c
        if c.state == "none" or (c.state == "refused" and (retry or self.now - c.since >= self.claim_retry)):
            self._send_claim(ax, c)
        elif c.state == "held" and (retry or self._claim_looks_lost(ax, c)):
            # Claim is idempotent for the holder; re-sending it recovers a claim the NC dropped
            # without our noticing (e.g. a watchdog release on an axis already in error).
            self._send_claim(ax, c)
        return c

    def _claim_looks_lost(self, ax: AXIS_REF, c: ClaimState) -> bool:
        """We enable the axis, the NC shows it neither enabled nor in error, for claim_retry."""
        if not ax.Status.Valid or self.now - c.since < self.claim_retry:
            return False
        sd = ax.NcToPlc.StateDWord
        enabling = ax.PlcToNc.ControlDWord & _ENABLE
        return bool(enabling) and not sd & (_CLC | _ERROR)

    def reachable(self, nc: str) -> bool:
        """Whether requests to ``nc`` can be sent now (the zenoh runtime: session open)."""
        return True

    def claim_state(self, ax: AXIS_REF) -> ClaimState | None:
        return self._claims.get((ax.nc, ax.axis_id))

    def _send_claim(self, ax: AXIS_REF, c: ClaimState) -> None:
        # (a retried refusal keeps its code until the answer: see ClaimState.error)
        c.state, c.error, c.since = "pending", c.error if c.state == "refused" else 0, self.now
        c.pending = self.port.send(ax.nc, ax.axis_id, "Claim")
        c.pending.owner = ax

    def _update_claims(self, late: list[PendingCommand]) -> None:
        c: ClaimState | None  # (the loops below also look claims up)
        for key, c in self._claims.items():
            p = c.pending
            if p is None:  # (a held claim, the usual case: nothing on its way)
                continue
            if c.state == "awaiting":
                if p.done:  # held once the hand-over happened; a refusal is no error here
                    c.pending, c.since = None, self.now
                    if (p.error or 0) == 0:
                        c.state, c.error = "held", 0
                        log.info("%s/%d: handed over to us", key[0], key[1])
                elif self.now - p.sent_at > self.command_timeout:
                    p.abandon()
                    c.pending, c.since = None, self.now
                continue
            if c.state != "pending":
                continue
            if p.done:
                err = p.error or 0
                c.state, c.error, c.since, c.pending = ("held" if err == 0 else "refused"), err, self.now, None
                if err:
                    log.warning("claim of %s/%d refused: 0x%X %s", key[0], key[1], err, p.text)
            elif self.now - p.sent_at > self.command_timeout:
                p.abandon()
                c.state, c.error, c.since = "refused", ErrorCodes.ADSERR_CLIENT_SYNCTIMEOUT, self.now
        # the NC drops a claim when it faults the axis for a lost client / PLCTONC timeout
        claims = self._claims
        for key, ax in self._controlled.items():
            c = claims.get(key)
            if c is None:
                continue
            st = ax.Status
            if not (st.Valid and st.Error):  # (the usual case: no axis error, no fault)
                c.fault_seen = False
                continue
            code = ax.NcToPlc.ErrorCode
            lost = code in _CLAIM_FAULTS
            if lost and not c.fault_seen and c.state == "held":
                log.warning("%r: the NC dropped our claim (0x%X %s); claiming again", ax, code, error_text(code))
                c.state, c.error, c.pending = "none", 0, None
            c.fault_seen = lost
        for p in late:
            if p.cmd == "Claim" and (p.error or 0) == 0:
                c = self._claims.get((p.nc, p.axis_id or 0))
                if c is not None and c.state in ("refused", "none", "awaiting"):
                    c.state, c.error, c.pending = "held", 0, None
        self._update_handovers()

    # -- hand-over -----------------------------------------------------------------------
    def hand_over(self, nc: str, axis_id: int, to: str) -> HandOverRequest:
        """Hand the claim of ``nc``/``axis_id`` to the live client ``to`` without disabling the axis.

        Thread-safe: sent at the start of the next cycle. The receiver should call
        :meth:`expect_hand_over` first and keep its MC_Power enabled. On success this task's claim
        becomes 'handed' and it stops publishing PLCTONC for the axis; the NC keeps applying the
        last frame until the receiver's first one.

        Returns:
            The request; its ``done``/``error`` show the NC's answer (0x723: not the holder, or
            ``to`` has no liveliness token).
        """
        req = HandOverRequest(nc, axis_id, to)
        self._requests.append(lambda: self._send_hand_over(req))
        return req

    def expect_hand_over(self, nc: str, axis_id: int) -> None:
        """Accept a hand-over of ``nc``/``axis_id`` (thread-safe; applied at the next cycle start).

        MC_Power on the axis then publishes PLCTONC while its claim waits ('awaiting': no error of
        its own, not Active), polling Claim until the holder hands it over; then the claim is 'held'.
        """
        def apply() -> None:
            c = self._claims.setdefault((nc, int(axis_id)), ClaimState())
            if c.state != "held":
                c.state, c.error, c.pending, c.since = "awaiting", 0, None, -math.inf
        self._requests.append(apply)

    def _send_hand_over(self, req: HandOverRequest) -> None:
        key = (req.nc, req.axis_id)
        ax = self._controlled.get(key) or next(iter(self._refs.get(key, [])), None)
        if ax is None:
            ax = self.axis(req.nc, req.axis_id)
        req.pending = self.send(ax, "HandOver", To=req.to)
        self._handovers.append(req)

    def _update_handovers(self) -> None:
        if not self._handovers:
            return
        keep = []
        for req in self._handovers:
            p = req.pending
            assert p is not None
            if not p.done:
                if self.now - p.sent_at <= self.command_timeout:
                    keep.append(req)
                    continue
                p.abandon()
                req.done, req.error = True, int(ErrorCodes.ADSERR_CLIENT_SYNCTIMEOUT)
            else:
                req.done, req.error = True, int(p.error or 0)
            key = (req.nc, req.axis_id)
            if req.error:
                log.warning("hand-over of %s/%d to %s refused: 0x%X %s", req.nc, req.axis_id, req.to, req.error,
                            p.text or error_text(req.error))
                continue
            c = self._claims.setdefault(key, ClaimState())
            if req.to != self.client_id:
                c.state, c.error, c.pending, c.since = "handed", 0, None, self.now
                self._controlled.pop(key, None)  # its frames no longer count: stop sending them
                self._plan = None
                log.info("%s/%d handed over to %s", req.nc, req.axis_id, req.to)
        self._handovers = keep

    def _forget_claims(self, nc: str) -> None:
        for (n, _), c in self._claims.items():
            if n == nc and c.state != "awaiting":
                c.state, c.error, c.pending = "none", 0, None
            elif n == nc:
                c.pending = None

    # -- commands ----------------------------------------------------------------------
    def send(self, ax: AXIS_REF, cmd: str, **args: Any) -> PendingCommand:
        """Send ``cmd`` for ``ax`` through this task's port (non-blocking)."""
        p = self.port.send(ax.nc, ax.axis_id, cmd, **args)
        p.owner = ax
        return p

    def detach(self, p: PendingCommand, what: str = "") -> None:
        """Fire and forget: log ``p``'s error if it fails (e.g. StopRelease)."""
        self._detached.append((p, what or p.cmd))

    def _handle_late(self, late: list[PendingCommand]) -> None:
        for p in late:
            err = p.error or 0
            ax = p.owner if isinstance(p.owner, AXIS_REF) else None
            if err or ax is None or p.cmd not in MOTION_COMMANDS or p.reply is None:
                if p.cmd != "Claim":
                    log.info("late reply to abandoned %s (axis %s): 0x%X", p.cmd, p.axis_id, err)
                continue
            cmdno = int(p.reply.get("CmdNo", 0))
            if p.cmd in _STOPS or not cmdno or p.cmd in _SLOT_COMMANDS or p.cmd in _AMENDS:
                log.warning("late acceptance of %s on %r (CmdNo %d): left as is", p.cmd, ax, cmdno)
                continue
            self._orphans.append(_Orphan(ax, cmdno, reply_cycle(p.reply), ax.nc_epoch, p.cmd))

    def lost_command(self, ax: AXIS_REF, cmdno: int, cmd: str, nc_cycle: int) -> None:
        """A block stopped following motion command ``cmdno`` (``cmd``) on ``ax`` because the NC's data
        was lost (stale, NC gone or restarted) after a frame of NC cycle ``nc_cycle`` had shown it.

        When valid frames come back from the same NC instance (cycle >= ``nc_cycle``) and the
        command still runs, the task stops it (see the module docstring); a restarted NC (a new
        instance, :meth:`nc_restarted`) knows nothing of it.
        """
        if cmdno:
            self._orphans.append(_Orphan(ax, int(cmdno), int(nc_cycle), ax.nc_epoch, cmd, lost=True, since=self.now))

    def _still_running(self, o: _Orphan) -> bool:
        """Whether the NC (as the axis's newest frame shows it) still runs orphan ``o``'s command."""
        ax = o.ax
        if o.cmd in _SLOT_COMMANDS:
            jobs = ax.NcJobs
            return int(jobs["SuperCmdNo"]) == o.cmdno and int(jobs["SuperState"]) == CmdState.ACTIVE
        rec, jobs = ax.NcToPlc, ax.NcJobs
        if int(jobs["AxisId"]):  # job records: running or still buffered
            if int(jobs["ActiveCmdNo"]) == o.cmdno and int(jobs["ActiveState"]) == CmdState.ACTIVE:
                return True
            if int(jobs["BufferedCmdNo"]) == o.cmdno:
                return True
        return int(rec["CmdNo"]) == o.cmdno and int(rec["CmdState"]) == CmdState.ACTIVE

    def _check_orphans(self) -> None:
        if not self._orphans:
            return
        keep = []
        for o in self._orphans:
            ax = o.ax
            if o.lost:
                if not ax.Status.Valid:
                    if self.now - o.since < LOST_COMMAND_TTL:
                        keep.append(o)
                    continue
                if ax.Status.NcCycleCounter < o.cycle or ax.nc_epoch != o.epoch:
                    continue  # a restarted NC: the command is gone with the old instance
            else:
                if ax.nc_epoch != o.epoch:
                    continue
                if not ax.Status.Valid or not ax.shows_cycle(o.cycle):
                    keep.append(o)
                    continue
            if self._still_running(o):
                undo = _UNDO.get(o.cmd, ("Halt",))
                why = ("its block gave up when the NC's data was lost" if o.lost
                       else "it was accepted after its block timed out")
                log.warning("%r: command %d (%s) still runs but %s; %s", ax, o.cmdno, o.cmd, why, " + ".join(undo))
                for cmd in undo:
                    self.detach(self.send(ax, cmd), f"{cmd} of an orphaned {o.cmd}")
        self._orphans = keep

    def _check_detached(self) -> None:
        if not self._detached:
            return
        keep = []
        for p, what in self._detached:
            if not p.done:
                if self.now - p.sent_at <= max(self.command_timeout, 5.0):
                    keep.append((p, what))
                else:
                    p.abandon()
                    log.warning("%s: no reply", what)
            elif p.error:
                log.warning("%s failed: 0x%X %s", what, p.error, p.text)
        self._detached = keep

    # -- the cycle ---------------------------------------------------------------------
    def step(self) -> None:
        """Run one PLC cycle (see the module docstring). Exceptions of the program propagate."""
        self.cycle += 1
        self.now = self.clock()
        if self._initial_axes:
            self.bind_axes()
        self._take_frames()
        self._snapshot_all()
        while self._requests:
            self._requests.popleft()()
        late = self.port.poll()
        self._update_claims(late)
        self._handle_late(late)
        self._check_orphans()
        self._check_detached()
        if self._call is not None:
            prev = current_task()
            _local.task = self
            try:
                self._call(self)
            finally:
                _local.task = prev
        self._publish_all()

    def _take_frames(self) -> None:
        """Fetch the newest frame of each NC into ``self._frames`` (subclass)."""

    def _set_frame(self, nc: str, cycle: int, records: np.ndarray, jobs: np.ndarray | None = None,
                   covers: frozenset[int] | None = None, epoch: int = 0) -> None:
        """Take a status frame: NCTOPLC records and (same order) the NCJOBS records, if sent. A frame of a
        new NC instance (:class:`nc_schema.NcInstance`: its cycle counter went back) is a restart
        (:meth:`nc_restarted`); one of a lower ``epoch`` (the header's) than the NC's followed is dropped (a
        hot-standby pair's old active NC, ``NcInstance.take``). ``covers``: the AxisIds a view frame was cut for
        (its attachment, ``nc_schema.parse_view_axes``; None: every axis of the NC, a whole frame). An axis outside
        them is not yet in the view (bound after the view was asked for): no data yet, not 0x4012."""
        if not self._frame_arrived(nc, cycle, covers, epoch):
            return
        ids = records["AxisId"]
        key = ids.tobytes()
        index = self._index_cache.get(nc)
        if index is None or index[0] != key:  # the NC's axes rarely change: keep the AxisId -> row map
            index = self._index_cache[nc] = (key, {int(a): i for i, a in enumerate(ids.tolist())})
        self._frames[nc] = (int(cycle), records, index[1], jobs)

    def _frame_arrived(self, nc: str, cycle: int, covers: frozenset[int] | None, epoch: int = 0) -> bool:
        """What every frame does first: the epoch and restart rule (``NcInstance.take``, the task's clock), then, if
        it is taken, keep the axes it was cut for. False: a frame of a lower epoch, dropped (not taken: the axes
        keep the frame held, and go stale if no other comes). (The clock, not ``self.now``: a runtime takes frames
        before its first step too.)"""
        inst = self._instances.get(nc)
        if inst is None:  # (not setdefault: that built an NcInstance for every frame)
            inst = self._instances[nc] = NcInstance()
        taken, why = inst.take(cycle, epoch, self.clock())
        if not taken:
            return False
        self._covers[nc] = covers
        if why is not None:
            self.nc_restarted(nc, why)
        return True

    def _set_frame_bytes(self, nc: str, data: bytes, covers: frozenset[int] | None = None) -> None:
        """Take a status frame as received: its bytes (``sample.payload.to_bytes()``), what
        :meth:`_set_frame` takes after ``nc_schema.decode_frame``, without numpy: the header is checked and
        unpacked with one ``struct`` call (``nc_schema.frame_header``), the AxisIds with another, and the axes'
        records are slices of ``data`` (immutable: kept as they are). For a transport's ``_take_frames``.

        Raises:
            ValueError: not a status frame (wrong magic, version or sizes), as ``decode_frame``.
        """
        # (frame_header's checks and values, as the plain tuple: no FrameHeader per frame)
        _, _, hs, cycle, _, n, _, flags, epoch = frame_header_values(data)
        if not self._frame_arrived(nc, cycle, covers, epoch):
            return
        ids = _axis_ids_struct(n).unpack_from(data, hs)
        index = self._index_cache.get(nc)
        if index is None or index[0] != ids:  # the NC's axes rarely change: keep the AxisId -> row map
            index = self._index_cache[nc] = (ids, {a: i for i, a in enumerate(ids)})
        frame: _FrameEntry = (cycle, None, index[1], None)
        self._frames[nc] = frame
        self._frame_bytes[nc] = (frame, data, hs, data if flags & JOB_RECORDS else None, hs + n * NCTOPLC_SIZE)

    def _bytes_of(self, nc: str, frame: _FrameEntry) -> tuple[_FrameEntry, bytes, int, bytes | None, int]:
        """(frame, the bytes its NCTOPLC records start in, where they start, the same of its NCJOBS records or
        None): the frame's own bytes (:meth:`_set_frame_bytes`), or one copy of each array per frame entry of
        ``_frames``, made when the first axis takes its snapshot of it (a task without axes copies nothing).
        The axes' snapshots are slices of them: immutable, so nothing the NC or the transport does to its
        arrays afterwards reaches them."""
        got = self._frame_bytes.get(nc)
        if got is None or got[0] is not frame:
            recs, jobs = frame[1], frame[3]
            assert recs is not None  # (a frame entry without arrays comes with its bytes: _set_frame_bytes)
            got = self._frame_bytes[nc] = (frame, recs.tobytes(), 0, None if jobs is None else jobs.tobytes(), 0)
        return got

    def _snapshot_all(self) -> None:
        """:meth:`_snapshot_refs` of every bound axis, the frame of each NC looked up once."""
        frames = self._frames
        last: str | None = None
        frame: _FrameEntry | None = None
        recs = b""
        jobs: bytes | None = None
        covers: frozenset[int] | None = None
        stale = rbase = jbase = 0
        if not self._refs:
            return  # (a task without axes: nothing to set up)
        index: dict[int, int] = {}
        fcycle = 0
        cycle, cycle_time = self.cycle, self.cycle_time
        for (nc, axis_id), refs in self._refs.items():
            if nc != last:
                last = nc
                frame = frames.get(nc)
                stale = 0 if nc in self._nc_down else self.stale_cycles  # 0: invalid at once
                if frame is not None:
                    _, recs, rbase, jobs, jbase = self._bytes_of(nc, frame)
                    covers = self._covers.get(nc)
                    fcycle, index = frame[0], frame[2]
            i = index.get(axis_id) if frame is not None else None
            if i is None:  # no frame yet, or the axis is not in it: _snapshot_refs tells which
                self._snapshot_refs(refs, axis_id, frame, recs, rbase, jobs, jbase, covers, stale)
                continue
            # (the usual case, as _snapshot_refs does it, without its call)
            rec = None
            for ax in refs:
                if ax._src is frame and ax._unchanged + 1 < stale:
                    # no newer frame since this axis's last snapshot, which was valid and of this very frame: its
                    # NcToPlc, NcJobs and Status hold what a new snapshot would (the bytes are the same), only the
                    # counters move on (AXIS_REF._snapshot's path for an unchanged NC cycle, without the decoding)
                    ax._unchanged += 1
                    ax.pending = False
                    ax.Status.CycleCounter = cycle
                    continue
                if rec is None:
                    o = rbase + i * NCTOPLC_SIZE
                    rec = recs[o:o + NCTOPLC_SIZE]
                    if jobs is None:
                        job = None
                    else:
                        j = jbase + i * NCJOBS_SIZE
                        job = jobs[j:j + NCJOBS_SIZE]
                ax._snapshot(rec, fcycle, cycle, cycle_time, stale, job)
                if ax.Status.Valid:
                    ax._src = frame  # (valid: _snapshot took this frame's record; any other call of it clears this)

    def _snapshot_refs(self, refs: list[AXIS_REF], axis_id: int, frame: _FrameEntry | None, recs: bytes, rbase: int,
                       jobs: bytes | None, jbase: int, covers: frozenset[int] | None, stale: int) -> None:
        """The snapshot of ``refs`` (the AXIS_REFs of ``axis_id``) from their NC's newest ``frame`` (None: none
        yet) and its bytes (:meth:`_bytes_of`): its record; or no record, as an axis the NC lacks (0x4012) where
        the frame covers it, as one not yet in the view (``pending`` for at most ``command_timeout`` after its
        binding, then stale: 0x4B0F) where it does not."""
        cycle, cycle_time = self.cycle, self.cycle_time
        if frame is None:
            for ax in refs:
                ax._snapshot(None, None, cycle, cycle_time, stale)
            return
        i = frame[2].get(axis_id)
        if i is None:
            if covers is None or axis_id in covers:  # the NC has no such axis (0x4012)
                for ax in refs:
                    ax._snapshot(None, frame[0], cycle, cycle_time, stale)
                return
            now = time.monotonic()  # not yet in the view: no data yet
            for ax in refs:
                ax._snapshot(None, None, cycle, cycle_time, stale)
                ax.pending = now < ax._pending_until
            return
        o = rbase + i * NCTOPLC_SIZE
        j = jbase + i * NCJOBS_SIZE
        rec = recs[o:o + NCTOPLC_SIZE]
        job = None if jobs is None else jobs[j:j + NCJOBS_SIZE]
        for ax in refs:
            ax._snapshot(rec, frame[0], cycle, cycle_time, stale, job)

    def _snapshot_one(self, ax: AXIS_REF) -> None:
        nc = ax.nc
        frame = self._frames.get(nc)
        stale = 0 if nc in self._nc_down else self.stale_cycles  # 0: invalid at once
        recs, rbase, jobs, jbase = b"", 0, None, 0
        if frame is not None and ax.axis_id in frame[2]:
            _, recs, rbase, jobs, jbase = self._bytes_of(nc, frame)
        self._snapshot_refs([ax], ax.axis_id, frame, recs, rbase, jobs, jbase, self._covers.get(nc), stale)

    def nc_token_gone(self, nc: str) -> None:
        """The liveliness token of NC ``nc`` disappeared (transports that watch it call this).

        The NC is unreachable: its data is invalid at once (:meth:`nc_down`). That is not a restart:
        the token also goes and comes back when the zenoh link is dropped for a lease (a starved
        client, NC or router) while the same NC runs on. A new instance shows by its instance token
        and its frames (:meth:`nc_instance_token`, :meth:`_set_frame`); if this client's link was dropped, the NC
        dropped its claims too and shows it (0x8F01 on the held axes: claimed again by MC_Power).
        """
        self.nc_down(nc)

    def nc_token_back(self, nc: str) -> None:
        """The liveliness token of NC ``nc`` is back after :meth:`nc_token_gone`: its frames count
        again (whether it is a new instance, its instance token and frames tell)."""
        self.nc_up(nc)

    def nc_instance_token(self, nc: str, instance: str) -> None:
        """NC ``nc``'s instance token ``nc/<nc>/alive/<instance>`` appeared (transports that watch it call
        this): another id than the one followed is a restart (:meth:`nc_restarted`), the same one coming
        back (a dropped link) is none (:class:`nc_schema.NcInstance`).

        Raises:
            ValueError: ``instance`` is not an instance id (the transport drops such tokens before).
        """
        why = self._instances.setdefault(nc, NcInstance()).token(instance)
        if why is not None:
            self.nc_restarted(nc, why)

    def nc_down(self, nc: str) -> None:
        """The NC's liveliness token disappeared: its axes' data is invalid from this cycle on
        (blocks end with 0x4B0F at once, without waiting ``stale_cycles``)."""
        self._nc_down.add(nc)

    def nc_up(self, nc: str) -> None:
        """The NC's liveliness token is back: its frames count again."""
        self._nc_down.discard(nc)

    def nc_restarted(self, nc: str, why: str = "its cycle counter went back") -> None:
        """The NC ``nc`` restarted (``why``, for the log): bump the epoch of its axes and forget its claims.

        The frame held is the old instance's (a restart told by the instance token comes before the new
        instance's frames): dropped, so no old data is valid under the new epoch (invalid until the new
        instance's first frame)."""
        for (n, _), refs in self._refs.items():
            if n == nc:
                for ax in refs:
                    ax.nc_epoch += 1
                    ax._has_data = False  # (its snapshot is the old instance's)
        self._forget_claims(nc)
        self._frames.pop(nc, None)
        self._frame_bytes.pop(nc, None)
        log.warning("NC %s restarted (%s): commands of the old instance are no longer followed", nc, why)

    def _publish_all(self) -> None:
        plan = self._plan
        if plan is None:  # the controlled axes changed (rarely): group them by NC again
            by_nc: dict[str, list[AXIS_REF]] = {}
            for (nc, _), ax in self._controlled.items():
                by_nc.setdefault(nc, []).append(ax)
            plan = self._plan = list(by_nc.items())
        for nc, axes in plan:
            self._publish(nc, axes)

    def _publish(self, nc: str, axes: list[AXIS_REF]) -> None:
        """Send one PLCTONC frame for ``axes`` of ``nc`` (subclass; :meth:`plc_frame` makes it)."""

    def plc_frame(self, nc: str, axes: list[AXIS_REF]) -> bytearray:
        """This cycle's PLC frame of ``axes`` of NC ``nc`` (the list :meth:`_publish` is given), the bytes of
        ``nc_schema.encode_plc_records(self.cycle, ...)``: packed into that NC's buffer, kept while the
        controlled axes stay the same (:class:`plc_client.plcframe.PlcFrameBuffer`). Valid until the next
        call for ``nc``; the transport copies it when it sends it."""
        w = self._frame_bufs.get(nc)
        if w is None or w.axes is not axes:
            w = self._frame_bufs[nc] = PlcFrameBuffer(axes)
        return w.frame(self.cycle)

    def disable_all(self) -> None:
        """Clear Enable/feed enables of every controlled axis (shutdown)."""
        for ax in self._controlled.values():
            ax.PlcToNc["ControlDWord"] = 0

    def held_claims(self) -> Iterable[tuple[str, int]]:
        """The claims to release at shutdown (held, or a Claim on its way)."""
        return [k for k, c in self._claims.items() if c.state in ("held", "pending")]

