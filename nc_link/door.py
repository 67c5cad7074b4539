"""NcDoor: a user-facing door's link to one NC (frames, claims map, the users it acts for, their PLCTONC supply).

The door logic shared by nc-opcua (an OPC UA session) and nc-web (a browser login): a door *session* is an
int the door numbers (never reused). Built on the client link (:class:`nc_link.NcLink`): one :class:`nc_link.NcLink` per NC as the door's own client id (it takes
the NC's frames once per sampling period, the NC's liveliness and instance, the claims map, and sends the door's
own reads: Info, ReadParameter). What the door does *for one of its users* it does as the client id
``<door>.<user>`` (:meth:`NcDoor.command`): the NC records that id as the commander, the claim holder, in its
claims map; per user the door declares that id's liveliness token and PLCTONC publisher on the same session
(:class:`UserAgent`, ``NcLink.declare_holder``) and supplies the PLCTONC of the axes the user powered with
:class:`nc_link.Supplies` (one per user id: the NC's claims map is checked against that id).

One thread per NC (``supply``): every ``supply_period`` it takes the newest frame, the NC's events (a new NC
instance ends every supply, as in nc-ads) and claims map (a supply the NC no longer names the user the holder of
ends), and publishes one PLC frame per user with supplied axes; an axis disabled by Power(FALSE) is released
after a few enables-off periods. Commands (:meth:`command`) block and run on the caller's thread (the doors run
them in a worker thread, never on their event loop).

A vanished door session (:meth:`session_gone`): on each axis it powered (Enable supplied) the error 0x8F01
(ZNC_CLIENT_LOST, SetExternalError: the NC stops the axis with its deceleration), then the claim is released; on
each axis whose last motion command the door sent for that session and that still moves, 0x8F01 too (the NC's
rule for the motions of a lost client); its jogs stop. This is nc-ads's per-connection rule, per door
session. When a user's last session is gone its id's liveliness token is undeclared as well (the NC then lists
it as not alive; anything it still commanded falls under the NC's own client-loss rule). If the door itself dies, its user ids' tokens vanish with its zenoh session and the NC's own
client-loss rules apply (ClientLossReaction, docs/arbitration.md).

A session that vanishes while its command waits for the NC's reply: :meth:`session_gone` first marks it gone
(under the lock); :meth:`command`, :meth:`power` and :meth:`jog` refuse a gone session (0x8F01) and, after
the NC's reply, look again under the lock: gone -> the loss reaction for that command (a Power's fresh claim
is released, never supplied; a motion gets 0x8F01; a jog Halt) and CommandError 0x8F01. PLCTONC of one user
id is published by one thread at a time (``UserAgent.publish_lock``: the supply thread and a command's).

May import: ``nc_schema``, this package and the standard library.
"""
from __future__ import annotations

import asyncio
import functools
import logging
import math
import struct
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, Callable, TypeVar

from .link import CommandError, NcLink
from .supply import Supplies
from .link import RESTART
from nc_schema import (
    NCTOPLC_DTYPE, PLCTONC_DTYPE, PLCTONC_SIZE, ErrorCodes, StateDWord, encode_plc_records, frame_records,
)

log = logging.getLogger(__name__)

__all__ = ["NcDoor", "AxisImage", "UserAgent", "OVERRIDE_100", "CommandPool", "REFRESH_INTERVAL"]

#: an axis's parameters are refreshed from the NC at most once per this many seconds (RefreshParameters, the
#: page's Refresh): each refresh is one ReadParameter per MC_AxisPara parameter, on the request budget every PLC
#: shares, and any logged-in observer may ask for it
REFRESH_INTERVAL = 5.0
_UNREACHABLE = (int(ErrorCodes.ADSERR_DEVICE_NOTREADY), int(ErrorCodes.ADSERR_DEVICE_TIMEOUT))

_T = TypeVar("_T")


class CommandPool:
    """The threads a door's event loop runs its NC commands on (Stop, Halt, jogs and their renewals,
    session_gone, ...): its own, not asyncio's default executor, so they never queue behind password checks
    (:class:`nc_link.users.PasswordGate`) or parameter reads."""

    def __init__(self, workers: int = 8) -> None:
        self._pool = ThreadPoolExecutor(workers, thread_name_prefix="nc-command")

    async def run(self, fn: Callable[..., _T], *args: Any) -> _T:
        return await asyncio.get_running_loop().run_in_executor(self._pool, functools.partial(fn, *args))

    def close(self) -> None:
        self._pool.shutdown(wait=False, cancel_futures=True)

OVERRIDE_100 = 1_000_000
CONTROL_ENABLE_ALL = 0x7
assert PLCTONC_DTYPE.fields is not None and NCTOPLC_DTYPE.fields is not None
_CW_OFF = int(PLCTONC_DTYPE.fields["ControlDWord"][1])
_OVR_OFF = int(PLCTONC_DTYPE.fields["Override"][1])
_MOVING = int(StateDWord.HasJob)
_NOT_MOVING = int(StateDWord.NotMoving)


@dataclass(frozen=True)
class AxisImage:
    """The newest frame of the NC: its cycle, when it arrived (monotonic), NCTOPLC record bytes per AxisId."""

    cycle: int
    received: float
    records: dict[int, bytes]


@dataclass
class UserAgent:
    """What the door holds for one user id ``<door>.<user>`` on one NC: token, publisher, supplies, sessions."""

    client_id: str
    token: Any
    pub: Any
    supplies: Supplies
    sessions: set[int] = field(default_factory=set)
    plc_cycle: int = 0
    #: one publisher of this id's PLCTONC at a time (the supply thread and a command's worker thread publish)
    publish_lock: threading.Lock = field(default_factory=threading.Lock)


@dataclass
class Jog:
    """A running jog: who started it (session, user id) and when it stops unless renewed (monotonic)."""

    session: int
    client_id: str
    deadline: float
    direction: int


def default_plctonc(enable: bool, override: int) -> bytearray:
    rec = bytearray(PLCTONC_SIZE)
    struct.pack_into("<I", rec, _CW_OFF, CONTROL_ENABLE_ALL if enable else 0)
    struct.pack_into("<I", rec, _OVR_OFF, override)
    return rec


class NcDoor:
    """A door's link to NC ``nc`` (see the module docstring).

    Args:
        nc: the NC name. endpoint: its zenoh endpoint (or the router's). door_id: the door's client id.
        frame_period_ms: the frames taken (``nc/<nc>/frame/<P>ms``, one of ``nc_schema.FRAME_PERIODS_MS``).
        tls_dir: certificate directory (mutual TLS as ``door_id``), or None.
        supply_period: the PLCTONC supply period [s] (well inside the NC's watchdog_timeout).
        query_timeout: how long a command waits for its reply [s].
    """

    def __init__(self, nc: str, endpoint: str, door_id: str, frame_period_ms: int = 100, tls_dir: str | None = None,
                 supply_period: float = 0.02, query_timeout: float = 2.0, lease_ms: int = 1000) -> None:
        self.nc = nc
        self.door_id = door_id
        self.link = NcLink(nc, endpoint, door_id, lease_ms, tls_dir, None, holder=False, claims=True,
                           query_timeout=query_timeout)
        self.link.frame_key = self.link.keys.frame_every(frame_period_ms)
        self.supply_period = supply_period
        self.image: AxisImage | None = None
        self.names: dict[int, str] = {}
        self.claims: dict[int, str] = {}
        self.agents: dict[str, UserAgent] = {}
        self.jogs: dict[int, Jog] = {}
        self.commanded: dict[int, int] = {}  # AxisId -> the session whose motion command the door sent last
        self.params: dict[tuple[int, int], Any] = {}  # (AxisId, ParameterNumber) -> value (read on demand)
        self._param_lock = threading.Lock()  # one parameter read at a time: concurrent readers share the cache
        self._refreshed: dict[int, float] = {}  # AxisId -> when its parameters were last refreshed (monotonic)
        self._lock = threading.RLock()
        self._gone: set[int] = set()  # sessions that vanished (numbers are never reused): refused from then on
        self._closed = threading.Event()
        self._thread: threading.Thread | None = None
        self.on_restart: list[Callable[[], None]] = []

    # ---- lifecycle --------------------------------------------------------------------------------------------
    def start(self, timeout: float = 10.0) -> None:
        """Open the link (retrying until ``timeout``) and start the supply thread.

        Raises:
            ConnectionError: the NC's endpoint could not be reached within ``timeout``.
        """
        deadline = time.monotonic() + timeout
        while not self.link.open():
            if time.monotonic() > deadline:
                raise ConnectionError(f"NC {self.nc}: cannot connect ({self.link.last_error})")
            time.sleep(0.3)
        self._thread = threading.Thread(target=self._loop, name=f"door-{self.door_id}-{self.nc}", daemon=True)
        self._thread.start()

    def close(self) -> None:
        """Stop supplying (enables off, release), close the link. Idempotent."""
        if self._closed.is_set():
            return
        with self._lock:
            agents = list(self.agents.values())
        for ag in agents:
            for a in ag.supplies.disable_all():
                self._publish(ag)
                try:
                    self.link.request("Release", a, sender=ag.client_id)
                except CommandError:
                    pass
        self._closed.set()
        if self._thread is not None:
            self._thread.join(3)
        for ag in agents:
            for d in (ag.token, ag.pub):
                try:
                    d.undeclare()
                except Exception:
                    pass
        self.link.close()

    # ---- the supply thread --------------------------------------------------------------------------------------
    def _loop(self) -> None:
        nxt = time.monotonic()
        while not self._closed.is_set():
            try:
                self._step()
            except Exception:
                if self._closed.is_set():
                    return
                log.exception("NC %s: supply cycle failed", self.nc)
            nxt += self.supply_period
            delay = nxt - time.monotonic()
            if delay < -self.supply_period:
                nxt, delay = time.monotonic(), 0.0  # late: skip, never replay
            self._closed.wait(max(0.0, delay))

    def _step(self) -> None:
        data = self.link.take_frame()
        if data is not None:
            try:
                h, recs = frame_records(data)
            except ValueError:
                pass
            else:
                taken, why = self.link.follow_frame(h.Cycle, h.Epoch)
                if taken:  # (not: a frame of a lower epoch, an old active NC's of a hot-standby pair)
                    self.image = AxisImage(h.Cycle, time.monotonic(), dict(recs))
                if why is not None:
                    self._restarted(why)
        for ev in self.link.take_events():
            if ev.kind == RESTART:
                self._restarted(ev.why)
        m = self.link.take_claims()
        if m is not None:
            cycle, claims = m
            self.claims = claims
            with self._lock:
                agents = list(self.agents.values())
            for ag in agents:
                for a in ag.supplies.end_lost(cycle, claims, ag.client_id):
                    log.warning("NC %s axis %d: the NC no longer counts %s as its holder; supply ended", self.nc, a,
                                ag.client_id)
        self._check_jogs()
        with self._lock:
            agents = list(self.agents.values())
        for ag in agents:
            self._publish(ag)

    def _restarted(self, why: str) -> None:
        with self._lock:
            for ag in self.agents.values():
                ag.supplies.end_all()
            self.jogs.clear()
            self.params.clear()
            self.names.clear()
        log.warning("NC %s restarted (%s): supplies ended, parameter cache cleared", self.nc, why)
        for cb in self.on_restart:
            cb()

    def _publish(self, ag: UserAgent) -> None:
        with ag.publish_lock:  # due(), the PlcCycle and the put as one: two threads publish
            items, release = ag.supplies.due()
            if items:
                ag.plc_cycle += 1
                try:
                    ag.pub.put(encode_plc_records(ag.plc_cycle, items))
                except Exception:
                    pass
        for a in release:
            threading.Thread(target=self._release, args=(ag, a, None), daemon=True).start()

    def _release(self, ag: UserAgent, axis: int, owner: int | None) -> None:
        if ag.supplies.take(axis, owner) is None:
            return
        try:
            self.link.request("Release", axis, sender=ag.client_id)
        except CommandError as exc:
            log.warning("NC %s axis %d: Release for %s failed: %s", self.nc, axis, ag.client_id, exc)

    def _check_jogs(self) -> None:
        now = time.monotonic()
        with self._lock:
            due = [(a, j) for a, j in self.jogs.items() if now >= j.deadline]
            for a, _ in due:
                del self.jogs[a]
        for a, j in due:
            log.info("NC %s axis %d: jog of %s timed out: Halt", self.nc, a, j.client_id)
            threading.Thread(target=self._quiet, args=("Halt", a, j.client_id), daemon=True).start()

    def _quiet(self, cmd: str, axis: int, sender: str, **args: Any) -> None:
        try:
            self.link.request(cmd, axis, sender=sender, **args)
        except CommandError as exc:
            log.warning("NC %s axis %d: %s for %s failed: %s", self.nc, axis, cmd, sender, exc)

    # ---- users --------------------------------------------------------------------------------------------------
    def agent(self, client_id: str, session: int) -> UserAgent:
        """The :class:`UserAgent` of ``client_id`` (declared on first use), with ``session`` among its sessions.

        Raises:
            CommandError: 0x707 no session to the NC; 0x8F01 ``session`` already vanished.
        """
        with self._lock:
            self._refuse_gone(session)
            ag = self.agents.get(client_id)
            if ag is None:
                token, pub = self.link.declare_holder(client_id)
                ag = self.agents[client_id] = UserAgent(client_id, token, pub, Supplies(threading.Lock()))
            ag.sessions.add(session)
            return ag

    def command(self, cmd: str, axis: int | None, sender: str, session: int, **args: Any) -> dict[str, Any]:
        """Send ``cmd`` as ``sender`` for door session ``session``; a motion command records the session as the
        axis's commander (:meth:`session_gone`).

        Raises:
            CommandError: the NC's refusal (its ErrorID and text) or the transport's.
        """
        self.agent(sender, session)  # its liveliness token first: a Claim needs it (refuses a vanished session)
        reply = self.link.request(cmd, axis, sender=sender, **args)
        if axis is not None and cmd not in ("Reset", "Halt", "Stop", "StopRelease", "Claim", "Release",
                                            "WriteParameter", "ReadParameter", "SetExternalError"):
            with self._lock:
                gone = session in self._gone
                if not gone:
                    self.commanded[axis] = session
            if gone:  # it vanished while the NC took the motion: the rule for a lost client's motions
                self._quiet("SetExternalError", axis, sender, ErrorCode=ErrorCodes.ZNC_CLIENT_LOST)
                self._refuse_gone(session)
        return reply

    def _refuse_gone(self, session: int) -> None:
        """Raises CommandError 0x8F01 if ``session`` vanished."""
        if session in self._gone:
            raise CommandError(ErrorCodes.ZNC_CLIENT_LOST, f"door session {session} is gone")

    def power(self, axis: int, sender: str, session: int, enable: bool, override: int) -> None:
        """Power (MC_Power): claim ``axis`` for ``sender`` if needed and supply Enable + feed enables and
        ``override`` [1/1000000]; disable: enables off for a few supply periods, then Release.

        Raises:
            CommandError: the NC's refusal (0x723 naming another holder) or the transport's.
        """
        ag = self.agent(sender, session)
        if not enable:
            ag.supplies.disable(axis, session, periods=3)
            return

        def change(rec: bytearray) -> None:
            rec[:] = default_plctonc(True, override)

        if ag.supplies.change(axis, change, session) is None:
            rec = default_plctonc(True, override)
            reply = self.link.request("Claim", axis, sender=sender)
            with self._lock:  # session_gone marks the session gone under this lock before it ends its supplies
                gone = session in self._gone
                if not gone:
                    ag.supplies.start(axis, rec, session, int(reply.get("cycle", 0)))
            if gone:  # it vanished while the NC took the claim: never supplied, only released
                self._quiet("Release", axis, sender)
                self._refuse_gone(session)
        self._publish(ag)

    def jog(self, axis: int, sender: str, session: int, direction: int, velocity: float, timeout: float) -> None:
        """JogStart: a continuous jog (the NC's Jog, mode 2 with ``velocity``, mode 0 with 0: AxisVeloManSlow)
        that stops (Halt) after ``timeout`` s unless renewed: a new JogStart of the same session and direction
        only moves the deadline (the session's heartbeat).

        Raises:
            CommandError: the NC's refusal or the transport's.
        """
        with self._lock:
            j = self.jogs.get(axis)
            if j is not None and j.session == session and j.direction == direction and self._has_job(axis):
                j.deadline = time.monotonic() + timeout
                return
        args: dict[str, Any] = {"Mode": 2, "Velocity": velocity} if velocity > 0 else {"Mode": 0}
        self.command("Jog", axis, sender, session, Direction=direction, **args)
        with self._lock:
            gone = session in self._gone
            if not gone:
                self.jogs[axis] = Jog(session, sender, time.monotonic() + timeout, direction)
        if gone:  # vanished after command() recorded the jog: session_gone's 0x8F01 may have missed the start
            self._quiet("Halt", axis, sender)
            self._refuse_gone(session)

    def _has_job(self, axis: int) -> bool:
        """The newest frame shows a job on ``axis`` (a renewed jog the NC ended, e.g. by an error or another
        client's command, is started again instead of only extended)."""
        img = self.image
        rec = img.records.get(axis) if img is not None else None
        return rec is not None and bool(struct.unpack_from("<I", rec, 0)[0] & _MOVING)

    def jog_stop(self, axis: int, sender: str, session: int) -> None:
        """JogStop: Halt (whoever's jog it was). Raises: CommandError."""
        with self._lock:
            self.jogs.pop(axis, None)
        self.command("Halt", axis, sender, session)

    def end_jogs(self, session: int, axes: set[int] | None = None) -> list[int]:
        """Halt the running jogs of ``session`` (on ``axes`` only, if given) now, not at their timeout: its
        heartbeats' channel closed (nc-web: the page's WebSocket). Blocks (a worker thread). The axes halted."""
        with self._lock:
            due = [(a, j) for a, j in self.jogs.items() if j.session == session and (axes is None or a in axes)]
            for a, _ in due:
                del self.jogs[a]
        for a, j in due:
            log.info("NC %s axis %d: jog of %s ended with its heartbeats' channel: Halt", self.nc, a, j.client_id)
            self._quiet("Halt", a, j.client_id)
        return [a for a, _ in due]

    def session_gone(self, session: int) -> None:
        """Door session ``session`` vanished, closed or logged out: see the module docstring (blocks: a worker thread)."""
        with self._lock:
            self._gone.add(session)  # first: a command whose reply lands later sees it (command, power, jog)
            agents = [ag for ag in self.agents.values() if session in ag.sessions]
            jogs = [(a, j) for a, j in self.jogs.items() if j.session == session]
            for a, _ in jogs:
                del self.jogs[a]
            commanded = [a for a, s in self.commanded.items() if s == session]
            for a in commanded:
                del self.commanded[a]
        img = self.image
        last = self._last_commands() if commanded else {}
        stopped: set[int] = set()
        for ag in agents:
            for axis, enabled in ag.supplies.owned_by(session):
                if enabled:
                    self._quiet("SetExternalError", axis, ag.client_id, ErrorCode=ErrorCodes.ZNC_CLIENT_LOST)
                    stopped.add(axis)
                self._release(ag, axis, session)
        for a, j in jogs:
            if a not in stopped:
                self._quiet("Halt", a, j.client_id)
                stopped.add(a)
        for a in commanded:
            rec = img.records.get(a) if img else None
            if a in stopped or rec is None:
                continue
            sdw = struct.unpack_from("<I", rec, 0)[0]
            moving = bool(sdw & _MOVING) or not sdw & _NOT_MOVING
            by = last.get(a)  # the NC's newest accepted command on the axis: still one of the door's users?
            if moving and (by is None or by.startswith(self.door_id + ".")):
                sender = by or next((ag.client_id for ag in agents), self.door_id)
                self._quiet("SetExternalError", a, sender, ErrorCode=ErrorCodes.ZNC_CLIENT_LOST)
        gone = []
        with self._lock:
            for ag in agents:
                ag.sessions.discard(session)
                if not ag.sessions and not ag.supplies:  # the user's last session: its id leaves the NC too
                    del self.agents[ag.client_id]
                    gone.append(ag)
        for ag in gone:
            for d in (ag.token, ag.pub):
                try:
                    d.undeclare()
                except Exception:
                    pass

    def _last_commands(self) -> dict[int, str]:
        """AxisId -> the client of the NC's newest accepted op/eng command (Info's arbitration map); {} if unknown."""
        try:
            arb = (self.link.request("Info", None).get("Value") or {}).get("arbitration") or {}
            return {int(a): str(v.get("client", "")) for a, v in (arb.get("last_command") or {}).items()}
        except (CommandError, AttributeError, TypeError, ValueError):
            return {}

    # ---- reads --------------------------------------------------------------------------------------------------
    def axis_names(self) -> dict[int, str]:
        """AxisId -> Name from the NC's Info (cached until a restart)."""
        if not self.names:
            try:
                value = self.link.request("Info", None).get("Value") or {}
            except CommandError:
                return {}
            self.names = {int(a["AxisId"]): str(a.get("Name", "")) for a in value.get("axes", [])}
        return dict(self.names)

    def read_parameter(self, axis: int, number: int, refresh: bool = False) -> Any:
        """Parameter ``number`` of ``axis``, read from the NC on first use (or ``refresh``) and cached.

        Raises:
            CommandError: the NC's refusal or the transport's.
        """
        key = (axis, number)
        with self._param_lock:  # a concurrent reader of the same key waits and takes the cached value
            if not refresh and key in self.params:
                return self.params[key]
            value = self.link.request("ReadParameter", axis, ParameterNumber=number).get("Value")
            self.params[key] = value
            return value

    def read_parameters(self, axis: int, numbers: list[int], refresh: bool = False) -> dict[int, Any]:
        """Parameters ``numbers`` of ``axis`` (:meth:`read_parameter`): number -> value, or the CommandError of
        its read. ``refresh`` reads them from the NC again, at most once per :data:`REFRESH_INTERVAL` per axis
        (a refresh asked sooner, or while one runs, answers from the cache). The first 0x707/0x719 (NC
        unreachable / silent) ends the reads: the numbers after it are missing from the result."""
        if refresh:
            with self._lock:
                now = time.monotonic()
                if now - self._refreshed.get(axis, -math.inf) < REFRESH_INTERVAL:
                    refresh = False
                else:
                    self._refreshed[axis] = now
        out: dict[int, Any] = {}
        for n in numbers:
            try:
                out[n] = self.read_parameter(axis, n, refresh)
            except CommandError as exc:
                out[n] = exc
                if exc.code in _UNREACHABLE:
                    break  # do not wait once per parameter
        return out
