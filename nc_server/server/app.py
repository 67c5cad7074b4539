"""The NC server: one NcCore, driven by the cycle thread, connected through zenoh.

Per cycle (:meth:`NcServer.cycle`): liveliness events -> claims; apply the newest PLCTONC frame of each
claim holder and the watchdog (:class:`~nc_server.server.handler.CycleInputs`, shared with the in-process
port); ``core.step()``; the frame and the applied PLCTONC into the frame ring (:mod:`.frame_ring`), which
the frame publisher (:mod:`.publisher`, a child process by default) puts on zenoh. Between cycles
(:meth:`NcServer.idle`): the requests, as many as fit before the next cycle; their replies go to the
I/O thread. A motion command that starts now is only prepared there (TwinCAT's SVB: checks and plan,
nothing changed) and activated (SAF) in the same gap when that fits too, its reply with the gap's others, else
at the start of the next cycle (``NcServer._activate_pending``), its reply sent after that cycle's work; either
way with ``cycle`` = the step in which it takes effect.
With a retain file (:mod:`.retain`): locked and read before the cycle starts; the first cycle only
steps the core once (the drive is read) and applies the file through the commands, before any
command or PLCTONC is taken and without publishing a frame; then a snapshot every 100 ms (and on
every change of standstill) for the retain thread; the final state written after the last cycle. The
replies of durable commands (WriteParameter; SetActualPosition, SetReferenceFlag of persistent axes) wait in
the I/O thread until the retain thread has written their snapshot (``RetainKeeper.commit``), at most
``transport.HOLD_MAX`` (then 0x4002).
"""
from __future__ import annotations

import collections
import functools
import gc
import logging
import os
import threading
import time
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from nc_schema import CLASSES, ErrorCodes, FrameFlags, Keys


from nc_server.security.acl import access_control, with_local_publisher
from nc_server.security.exposure import exposure

from .claims import ClaimTable
from .config import ServerConfig
from .cycle import IO_NICE, IO_THREAD_NICE, CycleLoop, configure_interpreter, raise_io_priority
from .handler import MAX_REQUEST_BYTES, NO_NC_CYCLE, CycleInputs, PendingReply, RequestHandler
from .replication import CoreRecorder
from .standby import HotStandby
from .retain import RetainKeeper, RetainLockError
from .frame_ring import RingCounters
from .publisher import READY_TIMEOUT, FrameOutput, PublisherProcess, PublisherThread, internal_endpoint, remove_internal_socket
from .transport import IoThread, Transport

if TYPE_CHECKING:
    from nc_server.core import NcCore

log = logging.getLogger("nc_server.server")

#: Queries executed per cycle at most (the rest wait for the next cycle).
MAX_QUERIES_PER_CYCLE = 32
#: Queries taken from the channel per call at most (those that wait for a prepared command on their axis
#: included).
QUERY_CHANNEL_TAKE = 128
#: ... and no new one once this much of the cycle went into requests [ns] (a flood cannot stall the NC).
QUERY_BUDGET_NS = 250_000
#: At shutdown, moving axes get a stop ramp; the NC waits at most this long for standstill [s].
SHUTDOWN_STOP_TIMEOUT = 5.0
#: last_command changes alone rebuild the claims map at most this often [s] (claims and clients: at once).
CLAIMS_MIN_PERIOD = 0.05
#: A gap this long between two runs of the cycle thread (cycle starts and idle slices) means the NC
#: itself stalled [s]: nobody is blamed for PLCTONC that could not be processed meanwhile, nor for a
#: liveliness token that vanished meanwhile and comes back (ClaimTable.grace).
STALL_GRACE = 0.05
#: After a stall longer than the watchdog timeout, the motion commands queued across it are refused
#: (0x4B0F), not executed late: their blocks have given up on stale data, or their session was dropped
#: with the reply path (a move executed then would be followed by nobody); stops and the rest run
#: (RequestHandler.handle_after_stall). Covers STALE_QUERY_WINDOW [s] after the stall, while zenoh still
#: delivers what it read from the sockets. (Shorter stalls, common on a loaded machine, change nothing:
#: a late reply to a block that gave up is undone by its PLC task.)
STALE_QUERY_WINDOW = 0.05


#: A request starts between cycles only if the recent cost of one of its class (the key's command class:
#: read, op, eng; the QUERY_COST_QUANTILE of the last QUERY_COST_WINDOW of that class, recomputed every
#: QUERY_COST_EVERY of them; between QUERY_RESERVE_MIN_NS and QUERY_RESERVE_MAX_NS) still fits before the
#: next cycle: planning a move costs 0.1-0.2 ms on a quiet machine and 0.2-0.45 ms on a loaded one
#: (p50-p99); run in the cycle or past the next deadline, they were what made the NC's cycles overrun
#: (bench/many_clients.py). A cost is the cycle thread's CPU time for the request (thread_time), not its
#: wall time: a preemption meanwhile (another process's real-time thread on a shared machine, the I/O
#: thread holding the GIL) delays the cycle as much whether a request runs or not, and with wall times in
#: the window of 64 such outliers made the reserve exceed the cycle's slack (commands waited for
#: QUERY_MAX_WAIT_NS). The cycle itself runs none (see cycle()); when none fitted for QUERY_MAX_WAIT_NS,
#: one runs right after the cycle's work anyway (requests always progress; the next cycle may start late:
#: with 4 ms instead of 20 on the loaded VM a fifth of the moves of bench/cmd_latency.py --clients 16 were
#: forced, and the NC overran more).
QUERY_COST_WINDOW = 64
QUERY_COST_QUANTILE = 0.98
QUERY_COST_EVERY = 16
QUERY_RESERVE_MIN_NS = 50_000
QUERY_RESERVE_MAX_NS = 600_000
QUERY_MAX_WAIT_NS = 20_000_000
#: ... and one that waited QUERY_SPIN_WAIT_NS may also use the spin before the deadline but for
#: QUERY_SPIN_MARGIN_NS (the cycle thread is awake in an idle call: the spin is there for a sleep's late
#: wake-up, which does not come then).
QUERY_SPIN_WAIT_NS = 3_000_000
QUERY_SPIN_MARGIN_NS = 50_000
#: The quantile of a class's recent CPU costs it reserves (a preparation that takes longer than its reserve
#: eats into the spin before the deadline, 100-200 us, before it makes the cycle late).
CLASS_COST_QUANTILE = 0.9
#: A prepared command whose prediction failed at its activation (the axis changed between its preparation
#: and the cycle: a watchdog fault, a PLCTONC enable or override change) is prepared again this many times,
#: then refused (0x4220); it is never activated stale.
MAX_REPREPARE = 2
#: request waits kept for the stats' request_wait_us_p50/p99 (from when the cycle thread took the query to
#: when its reply was handed over)
WAIT_WINDOW = 512


def query_reserve(costs: "collections.deque[int] | list[int]", quantile: float = QUERY_COST_QUANTILE) -> int:
    """The time [ns] to keep free for one more request, from the recent request costs [ns]."""
    if not costs:
        return QUERY_RESERVE_MAX_NS
    s = sorted(costs)
    q = s[min(len(s) - 1, int(len(s) * quantile))]
    return int(min(QUERY_RESERVE_MAX_NS, max(QUERY_RESERVE_MIN_NS, q)))


def key_class(key: str) -> str:
    """The cost class of a request from its key alone (no parsing): ``read``, ``op`` or ``eng`` (the key's
    command class); anything else ``?`` (keys are checked later: a flood of odd ones shares one class)."""
    head, _, _ = key.rpartition("/")
    cls = head.rpartition("/")[2]
    return cls if cls in CLASSES else "?"


def key_axis(key: str) -> int | None:
    """The AxisId of an axis command key ``nc/<nc>/axis/<id>/cmd/...``; None for any other key."""
    parts = key.split("/", 4)
    if len(parts) > 3 and parts[2] == "axis":
        try:
            return int(parts[3])
        except ValueError:
            return None
    return None


class NcServer:
    """The NC process's parts, wired together.

    Args:
        config: the checked configuration.
        core: an NcCore built from ``config.axes`` (the cycle thread owns it once started).
    The roles file (``config.roles``) makes the handler refuse what a client's role does not allow
    (0x723); with ``config.zenoh.tls_dir`` too, the NC's own session (router or peer mode) also
    enforces the zenoh access control generated from it (:func:`nc_server.security.acl.access_control`),
    so clients that connect to the NC directly get only their own keys.
    """

    def __init__(self, config: ServerConfig, core: NcCore) -> None:
        self.config = config
        if config.redundancy.enabled:  # a hot-standby pair: every input of the core is noted (docs/standby.md)
            core = cast("NcCore", CoreRecorder(core))
        self.core = core
        self.keys = Keys(config.name)
        self.axis_ids = [int(a) for a in np.asarray(core.axis_ids).tolist()]
        # the NC's lease: a stall of half of it may have dropped every link (ClaimTable.grace)
        self.claims = ClaimTable(self.axis_ids, config.watchdog_timeout, lease=config.zenoh.lease_ms / 1000.0)
        roles = config.roles.client_roles() if config.roles is not None else None  # (door users included)
        acl = None
        if config.roles is not None and config.zenoh.tls_dir and config.zenoh.mode != "client":
            acl = access_control(config.roles)
            if config.publisher == "process":  # its publisher child connects over the internal unix socket
                acl = with_local_publisher(acl, config.name)
        elif config.roles is None and config.zenoh.tls_dir and config.zenoh.mode != "client":
            log.warning("TLS without a roles file: clients are authenticated but not authorized (any certificate "
                        "of the CA may use any client id's keys); add --roles")
        elif config.roles is not None and not config.zenoh.tls_dir:
            log.warning("roles file without TLS: the client ids in the command keys are not authenticated "
                        "(use --tls-dir, or a router with TLS and access control)")
        said = exposure(config.zenoh.listen, config.zenoh.tls_dir, config.roles is not None)
        if said is not None:
            log.log(*said)
        self.transport = Transport(config.zenoh, self.keys, self.axis_ids, access_control=acl)
        # (no wake event: queries arrive through a channel that the idle slices poll, and nothing would set one; a
        # slice's Event.wait cost ~15 us more CPU than a plain sleep and woke ~15 us later: a larger adapted spin)
        self.loop = CycleLoop(config.cycle_time, self.cycle, config.realtime, config.rt_priority, idle=self.idle,
                              cpus=frozenset(config.cpu_affinity) or None)
        # [nc] retain_file: built now, while the core's parameters are still the configured ones
        self.retain = RetainKeeper(config.retain_file, config.name, core) if config.retain_file else None
        retain = self.retain
        self.handler = RequestHandler(core, self.claims, self.keys, info_extra=self._info_extra,
                                      refresh_liveliness=self._take_liveliness, roles=roles,
                                      keeps=None if retain is None else functools.partial(retain.keeps, core))
        self.inputs = CycleInputs(core, self.claims, config.loss_reactions or None)
        self.ha: HotStandby | None = None  # made after the I/O thread (it sends the snapshots)
        #: (version, claims map) made by the cycle thread; the I/O thread publishes it
        self.claims_msg: tuple[int, dict[str, Any]] | None = None
        self._arb_seen: tuple[int, int, int] = (-1, -1, -1)
        self._arb_built = 0.0
        self.io = IoThread(self.transport, self.stats, claims_source=lambda: self.claims_msg,
                           cycle_source=lambda: int(self.core.cycle), rt_threads=self._rt_threads,
                           nice=None if config.realtime == "off" else IO_THREAD_NICE,
                           watch=lambda: self.publisher.watch() if self.publisher is not None else None,
                           rt_priority=None if config.realtime == "off" or config.rt_priority < 2 else config.rt_priority - 1,
                           durability=None if retain is None else lambda: (retain.settled, retain.durable),
                           not_kept=self.handler.not_kept,
                           others_nice=None if config.realtime == "off" else IO_NICE)
        if retain is not None:
            retain.on_settled = self.io.wake  # held replies go out once their commit is in the file
        if config.redundancy.enabled:
            self.ha = HotStandby(self, config.redundancy)
            if retain is not None:  # only the active NC of the pair keeps its file (docs/standby.md)
                retain.follow()
        #: the cycle's frames (shared memory), and what puts them on zenoh (made by start(): a child
        #: process or a thread, ``[nc] publisher``)
        self.frames = FrameOutput(config.name, len(self.axis_ids))
        if config.redundancy.enabled:  # the fence: no frame older than a takeover goes out (docs/standby.md)
            self.frames.ring.set_max_age(int(config.redundancy.takeover_cycles * config.cycle_time * 1e9))
        self._internal_socket: str | None = None  # the path of the publisher child's internal socket
        self.publisher: PublisherProcess | PublisherThread | None = None
        self._prev_tick = 0.0       # the cycle thread's last run (cycle start or idle slice) [s, monotonic]
        self._refuse_until = 0.0    # queries popped before this are refused (after a long stall) [s]
        self._idle_ran = False      # an idle call ran since the last cycle (it ran the requests)
        self._query_costs: collections.deque[int] = collections.deque(maxlen=QUERY_COST_WINDOW)  # [ns]
        self._reserve_ns = QUERY_RESERVE_MIN_NS * 4  # until costs are known
        #: per cost class (key_class): the recent costs [ns] and the reserve made of them (none yet: _reserve_ns)
        # the cost classes (key_class's, "plan": the core's part of a command in steps, "activate": its activation)
        self._class_costs: dict[str, collections.deque[int]] = {
            c: collections.deque(maxlen=QUERY_COST_WINDOW) for c in (*CLASSES, "plan", "activate", "?")}
        self._class_reserve: dict[str, int] = {}
        #: prepared requests (SVB), activated at the next cycle's start (SAF): (query, pending, first seen [ns])
        self._pending: list[tuple[Any, PendingReply, int]] = []
        self._pending_axes: set[int] = set()  # their axes: a later request on one waits for the activation
        self._activated: list[tuple[Any, bytes, int]] = []  # replies of this cycle's activations (sent after it)
        self._prepared_again: dict[int, int] = {}  # id(query) -> preparations whose prediction failed
        self._first_seen: dict[int, int] = {}  # id(query) -> when the cycle thread first took it [ns]
        self._waits: collections.deque[int] = collections.deque(maxlen=WAIT_WINDOW)  # [ns]
        self.prepared = 0  # motion commands prepared (SVB) for activation at a cycle start
        self.prepared_again = 0  # preparations repeated because the axis changed before the activation
        self.activated_at_once = 0  # prepared commands activated (or refused by their activation) in the gap of their plan
        self.not_activated = 0  # refused after MAX_REPREPARE failed predictions (0x4220) or a long NC stall
        self.forced = 0  # requests run right after a cycle's work although their reserve did not fit (waited too long)
        self._waiting_since: int | None = None  # since when a request waits for time to run [ns]
        self._plan_waiting_since: int | None = None  # ... and a command in steps for time to be planned [ns]
        self._forcing = False  # (idle: one runs whatever it costs: stats requests_forced)
        self.stalls = 0             # NC stalls of more than STALL_GRACE seen
        self.step_errors = 0  # core.step() raised (a bug): the axes were faulted, the cycle went on
        self._rt_offset = time.time_ns() - time.monotonic_ns()
        self._claims_snapshot: dict[int, str] = {}
        self._clients_snapshot: list[str] = []
        self._claims_version = -1
        self._clients_dirty = False
        self._matched: tuple[int, np.ndarray | None, np.ndarray | None] = (-1, None, None)
        self.started = False
        self._drive_closed = False
        self._shutdown = threading.Event()  # set by stop(): the cycle stops every moving axis
        self._retain_pending = False  # the first cycle has not applied the retain file yet
        self._retain_cold_tried = False  # (a pair) a cold start's load of the retain file was tried: never again

    # ---- lifecycle --------------------------------------------------------------------------
    def start(self, cancel: threading.Event | None = None) -> None:
        """Open zenoh, start the I/O thread, then the cycle thread (SCHED_FIFO set inside it).

        Args:
            cancel: set to stop waiting for a router that is not up yet (client mode; :meth:`Transport.open`).

        Raises:
            OpenCancelled: ``cancel`` was set while the NC waited for its router (nothing left running).
            zenoh.ZError: the session could not be opened (e.g. endpoint in use).
            RealtimeError: ``realtime="fifo"`` and SCHED_FIFO was refused.
            RetainLockError: another process uses the retain file (nothing was opened).
        """
        configure_interpreter()
        try:
            # (a pair's standby: not before it becomes active, and then only after a cold start: became_active)
            if self.ha is None or self.config.redundancy.start == "active":
                self.load_retain()
        except BaseException:
            self._close_drive()  # (the drive is open since NcCore: CANopen nodes operational, remote threads)
            raise
        io_priority = raise_io_priority(self.config.realtime)  # zenoh's threads inherit it
        if self.config.publisher == "process" and self.config.zenoh.mode != "client":
            self.transport.internal, self._internal_socket = internal_endpoint()
        try:
            self.transport.open(cancel, serve=self.ha is None)
            if self.config.remote_masters:  # coupling across NCs: their samples from the start
                self.transport.declare_remote_masters(list(self.config.remote_masters))
            if self.ha is not None and self.transport.session is not None:
                self.ha.open(self.transport.session)  # (an active start: serve() from there)
        except BaseException:
            self._abort_start()
            raise
        try:
            if self.config.publisher == "thread":
                self.publisher = PublisherThread(self.frames, self.config.name, self.axis_ids, self.transport.session)
            else:
                self.publisher = PublisherProcess(self.frames, self.config.name, self.axis_ids, self.config.zenoh,
                                                  internal=self.transport.internal,
                                                  nice=0 if self.config.realtime == "off" else IO_NICE,
                                                  log_level=logging.getLevelName(log.getEffectiveLevel()))
            self.publisher.start()
        except BaseException:
            self._abort_start()
            raise
        self.io.start()
        # Objects made so far live as long as the server: keep the collector off them.
        gc.collect()
        gc.freeze()
        if self.retain is not None:
            self.retain.start()
        try:
            self.loop.start()
        except BaseException:
            self._abort_start()
            raise
        self.started = True
        # the ready line (cli) follows: the frames must be on zenoh by then, not a second later
        deadline = time.monotonic() + READY_TIMEOUT
        if self.ha is not None and self.ha.role != "active":
            deadline = 0.0  # (a standby puts no frames)
        while not self._publisher_counters().ready and time.monotonic() < deadline and self.loop.alive:
            time.sleep(0.01)
        if deadline and not self._publisher_counters().ready:
            log.warning("the frame publisher is not ready after %g s: starting without it", READY_TIMEOUT)
        log.info("cycle thread: %s; zenoh's threads: %s; I/O thread: %s; frames: %s publisher", self.loop.stats.timing_detail,
                 io_priority, self.io.priority, self.config.publisher)

    def _abort_start(self) -> None:
        """start() failed: undo what it did so far (each step may not have happened)."""
        if self.retain is not None:
            self.retain.stop()  # (releases the lock; nothing is written)
        if self.io.native_id is not None:  # (started)
            self.io.stop()
        if self.publisher is not None:
            self.publisher.stop()
        self.transport.close()  # (idempotent)
        self._cleanup_start()
        self._close_drive()

    def _close_drive(self) -> None:
        """Release the drive (once; a failing close is logged: it must not hide why the server stops)."""
        if self._drive_closed:
            return
        self._drive_closed = True
        try:
            (self.ha.real_drive if self.ha is not None else self.core.drive).close()
        except Exception as exc:
            log.warning("drive close: %s", exc)

    def _cleanup_start(self) -> None:
        """Close the frame ring, remove the internal socket."""
        self.frames.close()
        if self._internal_socket is not None:
            remove_internal_socket(self._internal_socket)
            self._internal_socket = None

    def load_retain(self) -> None:
        """Lock and read the retain file (if configured); the first cycle applies it (start() calls this).

        Raises:
            RetainLockError: another process uses the retain file.
        """
        if self.retain is not None and self.retain.status == "new":
            self.retain.load()
            self._retain_pending = True

    def stop(self) -> None:
        """Stop the cycle, publish a last frame flagged ShuttingDown, close zenoh (idempotent)."""
        if not self.started:
            return
        self.started = False
        # Never leave a drive moving: stop every moving axis with its stop ramp, wait (bounded)
        # for standstill, then end the cycle and release the drive.
        self._shutdown.set()
        # (a standby drives nothing and is not the NC its clients see: no stop ramp, no last frame)
        serving = self.ha is None or self.ha.role == "active"
        deadline = time.monotonic() + SHUTDOWN_STOP_TIMEOUT
        while serving and self.loop.alive and bool(np.asarray(self.core.moving).any()) and time.monotonic() < deadline:
            time.sleep(0.01)
        self.loop.stop()
        if self.retain is not None:  # the cycle has ended: its final state goes into the file
            self.retain.stop(self.core)
        self._close_drive()
        if self.ha is not None:
            self.ha.close()
        core = self.core
        try:  # the last frame, flagged ShuttingDown: the publisher puts it before it ends
            if serving:
                self.frames.put(core.cycle, core.nc_time_ns, core.nctoplc, int(FrameFlags.ShuttingDown),
                                core.ncjobs, core.plctonc, epoch=self.ha.epoch if self.ha is not None else 0)
        except Exception as exc:
            log.warning("final frame: %s", exc)
        # Queries still queued (or prepared, not activated) get no execution; finalize them so queriers do not wait.
        for q, _, _ in self._pending:
            try:
                q.drop()
            except Exception:
                pass
        self._pending.clear()
        while True:
            q = self.transport.try_recv_query()
            if q is None:
                break
            try:
                q.drop()
            except Exception:
                pass
        if self.publisher is not None:
            self.publisher.stop()
        self.io.stop()
        self.transport.close()
        self._cleanup_start()
        gc.unfreeze()  # let the collector free the server's cycles at exit (frozen objects never are)

    def _rt_threads(self) -> set[int]:
        """Native ids of the threads that run SCHED_FIFO on purpose: the cycle thread and the I/O thread, those
        that do (else empty).

        The cycle thread polls the PLCTONC channel, and zenoh creates some threads lazily (its SHM watchdog
        threads): one created from the cycle thread would inherit SCHED_FIFO and is set back to normal."""
        out: set[int] = set()
        t = self.loop._thread
        if self.loop.stats.timing == "SCHED_FIFO" and t is not None and t.native_id is not None:
            out.add(t.native_id)
        if self.io.realtime and self.io.native_id is not None:
            out.add(self.io.native_id)
        return out

    @property
    def timing(self) -> str:
        return self.loop.stats.timing

    # ---- per cycle (cycle thread) -----------------------------------------------------------
    def cycle(self, deadline_ns: int) -> None:
        """One NC cycle scheduled at ``deadline_ns`` (CLOCK_MONOTONIC)."""
        t = self.transport
        core = self.core
        ha = self.ha
        if self._retain_pending and ha is None:
            self._retain_cycle(deadline_ns)
            return
        claims = self.claims
        now = time.monotonic()
        if ha is not None:
            if self._prev_tick and ha.after_stall(now - self._prev_tick):
                pass  # (replaced while it stalled: a standby now, nothing of the stall is its to handle)
            if ha.before_cycle(now):  # a standby: it follows the active NC, drives and serves nothing
                self.loop.relaxed = True  # (no spin before its cycles: it drives nothing; CycleLoop)
                self._prev_tick = now
                self._take_liveliness(now)  # (its channel drained: the events of the clients are kept current)
                return
            self.loop.relaxed = False
            if self._retain_pending:  # a cold start of the pair: its file is applied in its first active cycle
                self._retain_cycle(deadline_ns)
                ha.after_step()  # (the log of that cycle, the file's commands in it, to the standby)
                return
        self._tick(now)

        self._take_liveliness(now)

        # Commands run between cycles (idle), in the time the cycle leaves; only when no idle call ran
        # since the last cycle (the work fills the period) does the cycle take one itself.
        if not self._idle_ran:
            self._drain_queries(now, limit=1)
        self._idle_ran = False

        # the commands prepared between cycles start now (SAF), if their prediction still holds; before the
        # PLCTONC and the watchdog, as a command executed between cycles: a move of a client lost meanwhile
        # is a job of the queue when the watchdog reacts to the loss, and is stopped
        if self._pending:
            self._activate_pending(now)

        # PLCTONC (the newest frame of each client, applied to the axes it holds), then the
        # watchdog (lost clients, stale PLCTONC): the same code the in-process port runs.
        self.inputs.apply(t.pop_plc_frames(), now)
        if t.remote_subs:  # the remote masters' samples (coupling across NCs): the core's one input from other NCs
            core.set_remote_samples(t.pop_master_samples())

        if self._shutdown.is_set():
            self._stop_moving_axes()
        try:
            core.step(self._nc_time_ns(deadline_ns))
        except Exception:  # a bug in the core: every axis stops on its ramp, the cycle goes on
            self.step_errors += 1
            log.exception("NC step failed: every axis is faulted with 0x4000")
            for i in range(len(core.axis_ids)):
                core.fault(i, ErrorCodes.NC_INTERNAL)

        if ha is not None:
            ha.after_step()  # the log of this cycle to the standby
        # (the job records and PLCTONC change on events: a ring slot that holds them at these counts keeps them)
        # (the epoch in the header: the clients drop frames of a lower one, the old active NC's after a link cut)
        self.frames.put(core.cycle, core.nc_time_ns, core.nctoplc, 0, core.ncjobs, core.plctonc,
                        (core.records.version, core.plctonc_version), ha.epoch if ha is not None else 0)
        if self._activated:  # their replies after the cycle's work (the I/O thread takes the GIL to send them)
            self.io.submit_replies(self._activated)
            self._activated = []
        if self.retain is not None:
            self.retain.tick(core)  # a snapshot every 100 ms for the retain thread (no I/O here)
        self._claims_changed()
        if self._clients_dirty:
            self._clients_dirty = False
            self._clients_snapshot = claims.clients()
        self._update_claims_msg(now)

    # ---- hot standby (docs/standby.md; the cycle thread) ------------------------------------------------------
    def became_active(self, now: float, serve: bool = True) -> None:
        """This NC drives from now on (HotStandby: a start as active, a takeover): serve its clients (``serve``
        False: the caller declares the NC's keys later, transport.serve())."""
        self._prev_tick = now
        self._claims_version = -1
        self._claims_changed()  # (the holders whose PLCTONC frames count)
        self._retain_active()
        if serve:
            self.transport.serve()

    def _retain_active(self) -> None:
        """(a pair: this NC became active) Keep the retain file from now on (docs/standby.md): after a cold start
        (no NC followed: its own state is the configuration's) the file is loaded and applied in the next cycle,
        as a single NC does; else (a takeover in step, a retake from its own core: its state is newer than its
        file) the retain thread takes the lock and writes that state."""
        retain, ha = self.retain, self.ha
        if retain is None or self._retain_pending:  # (a start as active: start() loaded it, the first cycle applies it)
            return
        if retain.status == "new" and ha is not None and not ha.followed and not self._retain_cold_tried:
            # (once per process: a node that found its lock taken and drove without its file, then was demoted and
            # retakes from its own core, must not apply the file in the middle of a run)
            self._retain_cold_tried = True
            try:
                retain.load()  # (the lock, then one read: what start() does for a single NC)
            except RetainLockError as exc:
                log.warning("%s: this NC drives without applying it", exc)
                retain.resume()
                return
            self._retain_pending = True
            return
        retain.resume()

    def became_standby(self) -> None:
        """This NC was replaced (HotStandby): it serves nothing; its prepared commands are dropped unanswered (a
        client's retry reaches the active NC, whose reply cache has them if they ran)."""
        self.transport.unserve()
        if self.retain is not None:  # only the active NC keeps the file: released after the write in progress
            self.retain.suspend()
            self._retain_pending = False
        for _, pending, _ in self._pending:
            self.core.set_preparing(pending.axis_id, False)
        self._pending.clear()
        self._pending_axes.clear()
        self._prepared_again.clear()  # (keyed by id(query): the dropped queries' ids are free again)
        self._first_seen.clear()
        self._activated = []

    def _claims_changed(self) -> None:
        """After anything that may change the claims (the watchdog in the cycle, requests between cycles):
        the holders the PLCTONC subscriber accepts, and the snapshot for the stats (cycle thread)."""
        claims = self.claims
        if claims.version != self._claims_version:
            self._claims_version = claims.version
            self._claims_snapshot = claims.claims()
            self.transport.holders = claims.holders()  # the subscriber drops frames of anybody else early

    def _update_claims_msg(self, now: float) -> None:
        """Rebuild the claims map when something changed (claims, clients: at once; last commands:
        at most every CLAIMS_MIN_PERIOD), for the I/O thread to publish (cycle thread)."""
        h = self.handler
        seen = (self.claims.version, h.clients_version, h.commands_version)
        if seen == self._arb_seen:
            return
        if seen[:2] == self._arb_seen[:2] and now - self._arb_built < CLAIMS_MIN_PERIOD:
            return
        self._arb_seen, self._arb_built = seen, now
        version = self.claims_msg[0] + 1 if self.claims_msg is not None else 0
        self.claims_msg = (version, h.arbitration())

    def _retain_cycle(self, deadline_ns: int) -> None:
        """The first cycle with a retain file: one ``core.step()`` (the drive is read, the axes are still
        disabled, no command or PLCTONC taken yet), then the file is applied through the commands. No
        frame: the next cycle's shows the restored state."""
        retain = self.retain
        assert retain is not None
        core = self.core
        self._prev_tick = time.monotonic()
        self._retain_pending = False
        try:
            core.step(self._nc_time_ns(deadline_ns))
        except Exception:  # as in cycle(): a bug in the core faults the axes, the NC goes on
            self.step_errors += 1
            log.exception("NC step failed: every axis is faulted with 0x4000")
            for i in range(len(core.axis_ids)):
                core.fault(i, ErrorCodes.NC_INTERNAL)
        try:
            retain.apply(core)
        except Exception:  # a bug: run on with what was applied, but never write that over the file
            retain.writing_disabled = True
            log.exception("retain file %s: 0x4002 NC retain data error: applying it failed; the NC does not "
                          "write the retain file during this run", retain.path)

    def _stop_moving_axes(self) -> None:
        """Shutdown: MC_Stop every moving axis that is not already stopping (cycle thread)."""
        core = self.core
        for i in np.flatnonzero(core.moving & ~core.stopping).tolist():
            core.execute({"id": None, "client": "", "cmd": "Stop", "Deceleration": 0.0, "Jerk": 0.0},
                         int(self.axis_ids[i]))

    def _tick(self, now: float) -> None:
        """Every run of the cycle thread starts here (cycle and idle): notice the NC's own stalls.

        A gap over STALL_GRACE: nobody is blamed (ClaimTable.grace); over the watchdog timeout also:
        the moving axes stop with 0x8F03 (their motion ran unsupervised) and the motion commands queued
        across it are refused. Must run before liveliness events and PLCTONC are taken.
        """
        prev, self._prev_tick = self._prev_tick, now
        gap = now - prev
        if not prev or gap <= STALL_GRACE:
            return
        self.stalls += 1
        self.claims.grace(now, since=prev)
        long_stall = gap > self.config.watchdog_timeout
        log.log(logging.WARNING if long_stall else logging.DEBUG,
                "the NC cycle thread stalled for %.3f s (the NC's own stall: no client is blamed)", gap)
        if long_stall:
            self._refuse_until = now + STALE_QUERY_WINDOW
            self.inputs.nc_stalled(gap)

    def _drain_queries(self, now: float, until_ns: int | None = None, at_least: int = 0,
                       limit: int = MAX_QUERIES_PER_CYCLE) -> int:
        """Run queued requests, hand their replies to the I/O thread; how many ran.

        At most ``limit``, none after QUERY_BUDGET_NS of this call, and (from the ``at_least``-th on) none
        that would, at the recent cost of a request of its class (:meth:`_reserve`), end after ``until_ns``
        [ns, monotonic]: a request costs 0.1-0.6 ms (planning a move), and the next cycle must start on
        time. A request that does not fit goes back to the front of the queue (``transport.queries``).

        A motion command that starts a job runs in steps (TwinCAT's SVB, then SAF): the handler's part
        (parse, key, dedup) when it is taken; the core's part (checks, record, plan from the state the next
        cycle starts from: :meth:`RequestHandler.plan`) in the gap before the cycle that activates it, as
        soon as its class ``plan`` fits (first of all in each call, in order); the activation right after the plan
        when the class ``activate`` fits too (its reply with this call's), else at that cycle's start
        (:meth:`_activate_pending`), its reply after that cycle's work. A request on an axis with a
        command in steps waits for its activation (each axis's commands run in order), and so does, for the
        rest of this call, every later one on an axis with a request waiting (``later``) in this call: a
        command activated in a gap of this call must not let a later request overtake the waiting one.
        """
        t = self.transport
        h = self.handler
        clock = time.monotonic_ns
        cpu = time.thread_time_ns  # a request's cost: the CPU it took, not the preemptions it suffered
        budget_end = clock() + QUERY_BUDGET_NS
        first_seen = self._first_seen
        replies: list[tuple[Any, bytes, bool]] = []  # (query, reply, held until kept: handler.durable)
        n = 0
        if self._pending:  # the core's part of the commands in steps first (they came first)
            n = self._plan_pending(replies, until_ns if at_least == 0 else None, budget_end, limit)
        later: list[Any] = []  # requests on axes with a command in steps: after its activation, in order
        deferred: set[int] = set()  # the axes of the requests in ``later``
        taken = 0
        while n < limit and taken < QUERY_CHANNEL_TAKE and (n == 0 or clock() <= budget_end):
            q = t.try_recv_query()
            if q is None:
                self._waiting_since = None
                break
            if not taken:  # the liveliness events that arrived before the request, applied before it (idle)
                self._take_liveliness(now)
            taken += 1
            t0 = clock()
            c0 = cpu()
            first_seen.setdefault(id(q), t0)
            key = str(q.key_expr)
            axis = key_axis(key) if self._pending_axes or deferred else None
            if axis is not None and (axis in self._pending_axes or axis in deferred):
                # (an axis with a request deferred in this call stays blocked for this call even once its command
                # in steps is answered, e.g. activated in the gap: its later requests never overtake that one)
                later.append(q)
                deferred.add(axis)
                continue
            cls = key_class(key)
            if until_ns is not None and t0 + self._reserve(cls) > until_ns:
                if n >= at_least:
                    t.queries.appendleft(q)  # first in line next time
                    if self._waiting_since is None:
                        self._waiting_since = t0
                    break
                self.forced += 1  # (it waited QUERY_MAX_WAIT_NS: runs although it may make the next cycle late)
            p = q.payload
            if p is not None and len(p) > MAX_REQUEST_BYTES:  # refuse before copying it onto this thread
                reply: bytes | PendingReply = h.too_large(len(p))
            elif now < self._refuse_until:
                reply = h.handle_after_stall(key, p.to_bytes() if p is not None else b"", now)
            else:
                reply = h.prepare(key, p.to_bytes() if p is not None else b"", now)
            n += 1
            self._waiting_since = None
            self._cost(cls, cpu() - c0)
            if isinstance(reply, PendingReply):
                self._pending.append((q, reply, first_seen.pop(id(q), t0)))
                self._pending_axes.add(reply.axis_id)
                self.core.set_preparing(reply.axis_id, True)
                self.prepared += 1
                self._plan_pending(replies, None if n <= at_least else until_ns, budget_end, limit - n + 1)
            else:
                replies.append((q, reply, h.durable))
        if later:  # (before a request put back above: they were taken before it)
            t.queries.extendleft(reversed(later))
        if replies:
            # a Claim's holder must count before its reply goes out: the client's next PLCTONC frame,
            # decoded between cycles, would otherwise be dropped as a non-holder's
            self._claims_changed()
            # acknowledged means kept: the replies of durable commands wait for the retain file (one snapshot
            # for all of them, written by the retain thread; the I/O thread sends them once it is fsync'ed)
            commit = self.retain.commit(self.core) if self.retain is not None and any(r[2] for r in replies) else 0
            end = clock()
            for q, _, _ in replies:
                self._waits.append(end - first_seen.pop(id(q), end))
            self.io.submit_replies([(q, r, commit if d else 0) for q, r, d in replies])  # (never on this thread)
        return n

    def _plan_pending(self, replies: list[tuple[Any, bytes, bool]], until_ns: int | None, budget_end: int,
                      most: int = MAX_QUERIES_PER_CYCLE) -> int:
        """The core's part of the commands in steps not planned yet, in order, at most ``most``, each only if the
        class ``plan`` fits before ``until_ns`` (None: whatever it costs; none after ``budget_end`` but the
        first); a refused one (or one that ran at once: a buffered move) goes to ``replies``, and so does one
        activated at once: with ``until_ns`` given, when the class ``activate`` fits too and no earlier command
        waits for the cycle's start (activations keep the arrival order, also across axes: a GearIn planned
        against its master's state must not see a later move of the master activated before it), not for a
        hot-standby pair, whose replies follow the cycle's log. One whose prediction failed already there is counted as at
        a cycle start (:meth:`_activate_pending`: planned again, at most MAX_REPREPARE times in all, then refused
        0x4220). Returns how many were planned or answered."""
        h = self.handler
        clock = time.monotonic_ns
        cpu = time.thread_time_ns
        done = 0
        keep: list[tuple[Any, PendingReply, int]] = []
        for k, (q, pending, seen) in enumerate(self._pending):
            if pending.prepared is not None:
                keep.append((q, pending, seen))
                continue
            t0 = clock()
            if (until_ns is not None and t0 + self._reserve("plan") > until_ns) or (done and t0 > budget_end) \
                    or done >= most:
                keep += self._pending[k:]
                if self._plan_waiting_since is None:
                    self._plan_waiting_since = t0
                break
            if until_ns is None and self._forcing:
                self.forced += 1  # (it waited QUERY_MAX_WAIT_NS: planned although it may make the next cycle late)
            self._plan_waiting_since = None
            c0 = cpu()
            got = h.plan(pending)
            self._cost("plan", cpu() - c0)
            done += 1
            if isinstance(got, PendingReply) and until_ns is not None and self.ha is None and not keep \
                    and clock() + self._reserve("activate") <= until_ns and time.monotonic() >= self._refuse_until:
                # its activation fits in this gap too: at once, not at the next cycle's start (SAF), and its reply
                # with the others of this gap: the same effect (the next step is the one it was planned for, whose
                # PLCTONC and watchdog then apply to it as to any command run between cycles), the reply a cycle
                # sooner (bench/fb_latency.py: the wait for the cycle start and that cycle's step were ~1 ms of
                # the ~2 ms the NC held a command on the loaded VM). (A pair's active NC: at the cycle's start, its
                # reply after the cycle's log to the standby.)
                reply = self._activate(got)
                if reply is None:  # its prediction failed already: counted as at the cycle's start
                    reply = self._plan_again_or_refuse(q, got)
                    if reply is None:  # (h.activate cleared its plan: planned again in a later gap)
                        keep.append((q, got, seen))
                        continue
                else:
                    self.activated_at_once += 1
                self._answered(q, got.axis_id)
                self._first_seen[id(q)] = seen
                replies.append((q, reply, False))
                continue
            if isinstance(got, PendingReply):
                keep.append((q, got, seen))
            else:  # refused, or ran at once (a buffered move): answered now
                self._answered(q, pending.axis_id)
                self._first_seen[id(q)] = seen
                replies.append((q, got, False))
        self._pending = keep
        return done

    def _activate(self, pending: PendingReply) -> bytes | None:
        """Activate a planned command (SAF: :meth:`Handler.activate`), its cost recorded in the class ``activate``;
        None: its prediction no longer holds (its plan is cleared)."""
        c0 = time.thread_time_ns()
        reply = self.handler.activate(pending)
        self._cost("activate", time.thread_time_ns() - c0)
        return reply

    def _plan_again_or_refuse(self, q: Any, pending: PendingReply) -> bytes | None:
        """A command whose prediction failed at its activation (in a gap or at a cycle start, counted alike):
        None while it may be planned again (at most MAX_REPREPARE times in all), else its refusal (0x4220: never
        planned again without limit, never unanswered)."""
        tries = self._prepared_again.get(id(q), 0) + 1
        if tries <= MAX_REPREPARE:
            self.prepared_again += 1
            self._prepared_again[id(q)] = tries
            return None
        self.not_activated += 1
        return self.handler.refuse_stale(pending)

    def _answered(self, q: Any, axis_id: int) -> None:
        """A command in steps got its answer (activated or refused): its axis takes the next one, its re-plan count
        goes (keyed by id(q): a later query with the same id must not inherit it)."""
        self._prepared_again.pop(id(q), None)
        self._pending_axes.discard(axis_id)
        self.core.set_preparing(axis_id, False)

    def _reserve(self, cls: str) -> int:
        """The time [ns] to keep free for one more request of cost class ``cls`` (:func:`key_class`)."""
        return self._class_reserve.get(cls, self._reserve_ns)

    def _cost(self, cls: str, ns: int) -> None:
        """Record what a request of class ``cls`` took [ns]; its class's reserve follows (:func:`query_reserve`)."""
        self._query_costs.append(ns)
        costs = self._class_costs[cls]
        costs.append(ns)
        if len(costs) % QUERY_COST_EVERY == 0:
            self._class_reserve[cls] = query_reserve(costs, CLASS_COST_QUANTILE)
        if len(self._query_costs) % QUERY_COST_EVERY == 0:
            self._reserve_ns = query_reserve(self._query_costs)

    def _activate_pending(self, now: float) -> None:
        """At the start of a cycle, before its PLCTONC, watchdog and step: activate the commands planned since
        the last one and not activated in the gap of their plan, in order (TwinCAT's SAF: a swap of plan rows, the records synced). One whose prediction no longer
        holds is planned again (at most MAX_REPREPARE times, failures in the gap included, then refused 0x4220);
        after a long NC stall every command in steps still here (not activated) is refused (0x4B0F), as the
        queued ones are. The replies go out after the
        cycle's work, with ``cycle`` = this cycle. Those not planned yet wait (their axis stays busy)."""
        h = self.handler
        clock = time.monotonic_ns
        stalled = now < self._refuse_until
        keep: list[tuple[Any, PendingReply, int]] = []
        for q, pending, seen in self._pending:
            reply: bytes | None = None
            if stalled:
                reply = h.refuse_stale(pending, NO_NC_CYCLE, "the NC stalled: a motion command prepared before the "
                                                             "stall is refused, not executed late")
                self.not_activated += 1
            elif pending.prepared is None:
                keep.append((q, pending, seen))
                continue
            else:
                reply = self._activate(pending)
                if reply is None:
                    reply = self._plan_again_or_refuse(q, pending)
                    if reply is None:
                        keep.append((q, pending, seen))
                        continue
            self._answered(q, pending.axis_id)
            self._waits.append(clock() - seen)
            self._activated.append((q, reply, 0))
        self._pending = keep

    def _take_liveliness(self, now: float | None = None) -> None:
        """Liveliness: PUT = client present, DELETE = gone (the watchdog reacts: CycleInputs)."""
        t = self.transport
        if t.take_liveliness():
            self._clients_dirty = True
            now = time.monotonic() if now is None else now
            for client, present in t.pop_liveliness():
                if present:
                    self.handler.client_alive(client, now)
                    log.info("client %s present", client)
                else:
                    self.handler.client_gone(client, now)
                    log.info("client %s gone", client)

    def idle(self, deadline_ns: int | None = None, after_work: bool = True) -> None:
        """Between cycles (cycle thread): run the requests that arrived, in the time left before
        ``deadline_ns`` [ns, monotonic; None: no limit]: each one only if the recent cost of a request
        still fits (:func:`query_reserve`); right after the cycle's work (``after_work``) one anyway when
        none could run for QUERY_MAX_WAIT_NS, so requests always progress.

        They take effect at the next ``core.step()``, as their reply's ``cycle`` says. Liveliness
        first: a client declares its token before it claims, and the NC must see them in that order
        (:meth:`_drain_queries` takes the liveliness events once it has a request, before it runs it; a
        slice without requests leaves them to the next cycle's start or request: no poll per slice).
        Nothing before the retain file was applied (the first cycle).
        """
        if self._retain_pending:
            return
        self._idle_ran = True
        now = time.monotonic()
        self._tick(now)
        # (liveliness: taken by _drain_queries before the first request it takes, not on every slice)
        waiting = min((w for w in (self._waiting_since, self._plan_waiting_since) if w is not None), default=None)
        waited = 0 if waiting is None else time.monotonic_ns() - waiting
        force = after_work and waited > QUERY_MAX_WAIT_NS
        if deadline_ns is not None and waited > QUERY_SPIN_WAIT_NS:
            # the cycle thread is awake: the spin kept for a sleep's late wake-up is free but for a margin
            deadline_ns = max(deadline_ns, deadline_ns + self.loop.stats.spin_ns - QUERY_SPIN_MARGIN_NS)
        self._forcing = force
        self._drain_queries(now, until_ns=deadline_ns, at_least=1 if force else 0)
        self._forcing = False
        self.transport.take_plctonc()  # decoded now, applied at the next cycle start

    def _nc_time_ns(self, deadline_ns: int) -> int:
        """CLOCK_REALTIME at the scheduled start of the cycle [ns]."""
        return deadline_ns + self._rt_offset

    # ---- stats / info (read from other threads) ----------------------------------------------
    def _publisher_counters(self) -> RingCounters:
        try:
            return self.publisher.counters() if self.publisher is not None else self.frames.ring.counters()
        except ValueError:  # closed (stopped)
            return RingCounters(0, 0, 0, False)

    def _info_extra(self) -> dict[str, Any]:
        return {"timing": self.loop.stats.timing, "watchdog_timeout": self.config.watchdog_timeout}

    def _wait_percentiles(self) -> dict[str, float]:
        """p50/p99 of the last WAIT_WINDOW request waits [us]: from when the cycle thread took the query to
        when its reply was handed over (a prepared one: after its activation). (Any thread: a copy, then a sort
        of at most WAIT_WINDOW ints.)"""
        w = sorted(self._waits.copy())
        if not w:
            return {"request_wait_us_p50": 0.0, "request_wait_us_p99": 0.0}
        return {"request_wait_us_p50": round(w[len(w) // 2] / 1000.0, 1),
                "request_wait_us_p99": round(w[min(len(w) - 1, int(len(w) * 0.99))] / 1000.0, 1)}

    def stats(self) -> dict[str, Any]:
        """The stats map published on ``nc/<nc>/stats`` (protocol.json ``stats``)."""
        st = self.loop.stats
        d: dict[str, Any] = {"cycle": int(self.core.cycle), "cycle_time": self.config.cycle_time,
                             "missed_cycles": int(st.missed_cycles), "overruns": int(st.overruns),
                             "timing": st.timing}
        d.update(st.percentiles())
        d["claims"] = dict(self._claims_snapshot)
        d["clients"] = list(self._clients_snapshot)
        d.update({"requests": self.handler.requests, "request_errors": self.handler.errors,
                  "dedup_hits": self.handler.cache.hits, "faults": self.inputs.faults,
                  "plctonc_frames": self.transport.plc_frames, "plctonc_malformed": self.transport.plc_malformed,
                  "plctonc_ignored": self.transport.plc_ignored,
                  "frames_dropped": self._publisher_counters().dropped, "reply_errors": self.transport.reply_errors,
                  "publisher": self.config.publisher,
                  "publisher_restarts": self.publisher.restarts if self.publisher is not None else 0,
                  "publisher_failovers": self.publisher.failovers if self.publisher is not None else 0,
                  "publisher_standby": self.publisher.standby_ready if self.publisher is not None else False,
                  "gear_ratios_ignored": int(self.core.coupling.ignored_ratios), "step_errors": self.step_errors,
                  "replies_held": self.io.replies_held, "replies_not_kept": self.io.replies_not_kept,
                  "requests_prepared": self.prepared, "requests_activated_at_once": self.activated_at_once,
                  "requests_prepared_again": self.prepared_again,
                  "requests_not_activated": self.not_activated, "requests_forced": self.forced,
                  "request_reserve_us": {c: round(v / 1000.0, 1) for c, v in list(self._class_reserve.items())},
                  **self._wait_percentiles(),
                  "drive_errors": self._drive_errors(),
                  "drive_input_age": self._drive_input_age(),
                  "remote_couplings": self.core.coupling.remote_stats(self.core.axis_ids),
                  # (protocol 5: remote masters' samples of a lower epoch than their NC's highest, dropped)
                  "remote_stale_epoch": self.core.coupling.sources.stale_epoch,
                  "drive_link": self._drive_link(),
                  "stages": self.core.stage_times()})
        if self.ha is not None:
            d["ha"] = self.ha.status()
        return d

    def _drive_link(self) -> dict[int, dict[str, Any]]:
        """{AxisId: the figures of the link to its drive} of the axes whose drive has a link (CANopen, remote; any
        thread: the drive only reads for it). A drive that fails to give them costs the stats nothing else."""
        try:
            figures = self.core.drive.link_figures()
        except Exception as exc:  # (a backend's bug must not stop the stats)
            log.debug("drive link figures: %s", exc)
            return {}
        ids = self.core.axis_ids
        return {int(ids[i]): f for i, f in figures.items() if f}

    def _drive_input_age(self) -> dict[int, int]:
        """{AxisId: the age [NC cycles] of the drive inputs used in the last cycle} of the axes whose inputs were not
        fresh (any thread: the drive replaces its ``input_age`` array, it does not write into it)."""
        ages = np.asarray(getattr(self.core.drive, "input_age", ()), dtype=np.int64)
        ids = self.core.axis_ids
        return {int(ids[i]): int(ages[i]) for i in np.flatnonzero(ages)}

    def _drive_errors(self) -> dict[int, int]:
        """{AxisId: the drive's own error code (CiA 402 0x603F)} of the axes whose drive reports one (any thread:
        the drive replaces its ``error_code`` array, it does not write into it)."""
        codes = np.asarray(getattr(self.core.drive, "error_code", ()), dtype=np.int64)
        ids = self.core.axis_ids
        return {int(ids[i]): int(codes[i]) for i in np.flatnonzero(codes)}
