"""The hot-standby pair on zenoh (docs/standby.md): roles, epochs, the replication keys, takeover and demotion.

One :class:`HotStandby` per nc-server process with ``[redundancy] enabled``; the cycle thread calls
:meth:`HotStandby.before_cycle` first in every cycle (a standby replays the active NC's logs there and skips the
rest of the cycle) and :meth:`HotStandby.after_step` after the active NC's step (its log out, snapshots served).

Keys (``nc/<nc>/ha/...``):

* ``log``: every cycle, the active NC's :class:`~.replication.CycleLog` of its last LOG_REPEAT cycles (pickled);
* ``snapshot``: queryable of the active NC: a snapshot to (re)start a follower from;
* ``active/<node>``: liveliness token of the active NC (its loss is a takeover at once);
* ``standby/<node>``: liveliness token of a standby in step (the active NC knows a peer can take over);
* ``status/<node>``: msgpack, about every 100 ms: role, epoch, lag, counters (nc-status shows it).

Epochs: an integer, ``(count << 16) | tie``, ``tie`` 16 bits of a hash of the node name: two standbys that take
over at once get different epochs, and the higher one wins. The drive hosts follow the highest epoch they have
seen only (nc-drive-sim refuses outputs of a lower one), so exactly one NC drives at any time; an NC that sees a
higher epoch (in a drive host's inputs, or another NC's log) stops driving and becomes a standby.
"""
from __future__ import annotations

import collections
import hashlib
import logging
import os
import pickle
import socket
import time
from typing import TYPE_CHECKING, Any

import msgpack
import zenoh
from zenoh.handlers import FifoChannel

from nc_server.drives.remote.config import takeover_bound

from .config import Redundancy
from .replication import (CoreRecorder, CycleLog, Follower, HandlerRecorder, RecordingDrive, ReplayDrive,
                          install_handler, merge_handler, snapshot)

if TYPE_CHECKING:
    from .app import NcServer

log = logging.getLogger("nc_server.standby")

#: logs the standby's channel holds (a replay that falls this far behind re-syncs from a snapshot)
LOG_CHANNEL = 4096
#: logs in each ``log`` sample (the newest last): a follower misses a log only when this many samples in a row are lost
LOG_REPEAT = 8
#: how long a standby waits for a snapshot before asking again [s]
SNAPSHOT_RETRY_S = 1.0
#: a standby that never followed anyone takes over only after this long without an active NC [s]
START_GRACE_S = 2.0
#: ha status period [s]
STATUS_PERIOD_S = 0.1


def node_name(configured: str) -> str:
    """The pair member's name: the configured one, else ``<host>-<pid>``."""
    if configured:
        return configured
    host = "".join(c if c.isascii() and (c.isalnum() or c in "-_") else "-" for c in socket.gethostname())[:40]
    return f"{host or 'nc'}-{os.getpid()}"


def tie_break(node: str) -> int:
    """16 bits of ``node``'s hash: the low bits of its epochs."""
    return int.from_bytes(hashlib.blake2b(node.encode(), digest_size=2).digest(), "little")


def next_epoch(highest: int, node: str) -> int:
    """The epoch of a takeover after the ``highest`` one seen."""
    return (((highest >> 16) + 1) << 16) | tie_break(node)


def drive_links(drive: Any) -> list[Any]:
    """The remote drive links of the core's drive (a RemoteDrive, or the remote parts of a DriveGroup)."""
    inner = getattr(drive, "inner", drive)
    parts = [d for d, _ in getattr(inner, "parts", [])] or [inner]
    return [p.link for p in parts if hasattr(getattr(p, "link", None), "host_epoch")]


class HotStandby:
    """This process's part of the pair (see the module docstring).

    Args:
        server: the NC server (its core is a :class:`CoreRecorder`).
        settings: the ``[redundancy]`` section.

    Attributes:
        role: ``"active"`` or ``"standby"``.
        epoch: the epoch this NC drives with (active) or the highest seen (standby).
        takeovers, demotions: role changes of this process.
        takeover_s: the last takeover's time from the last log of the lost NC to this NC's first set-point [s].
    """

    def __init__(self, server: NcServer, settings: Redundancy) -> None:
        self.srv = server
        self.settings = settings
        self.node = node_name(settings.node)
        self.keys = f"nc/{server.config.name}/ha"
        rec = server.core
        assert isinstance(rec, CoreRecorder)
        self.rec = rec
        self.core = rec.core
        drive = self.core.drive
        self.real_drive = drive.inner if isinstance(drive, RecordingDrive) else drive
        self.hrec = HandlerRecorder(server.handler)
        self.hrec.instance = server.transport.instance  # (the pair is one NC instance for its clients)
        self.follower = Follower(on_resync=self._resync, on_handler=merge_handler, core=self.core)
        self.role = "standby"
        self.epoch = 0
        self.highest = 0
        self.takeovers = 0
        self.demotions = 0
        self.takeover_s = 0.0
        self.takeover_cycles = 0  # NC cycles of the last takeover (detection included)
        self.catch_up = 0         # cycles stepped at once at the last takeover
        self.logs_in = 0
        self.logs_out = 0
        self.snapshots_served = 0
        self.stale_logs = 0
        self.synced_once = False
        self.active_token_seen = False
        self.peer_in_step = False  # (active) a standby in step is there
        self._peers: set[str] = set()
        self._last_log = 0.0       # monotonic time of the newest log taken
        self._token_gone = False   # (standby) the active NC's liveliness token went since the last log
        self._started = 0.0
        self._asked = 0.0          # when the last snapshot query went out
        self._snap_replies: Any = None
        self._session: zenoh.Session | None = None
        self._log_pub: Any = None
        self._log_sub: Any = None
        self._snap_q: Any = None
        self._status_pub: Any = None
        self._active_sub: Any = None
        self._standby_sub: Any = None
        self._token: Any = None
        self._next_status = 0.0
        self._excused = False  # the last cycle served a snapshot
        self._recent: collections.deque[bytes] = collections.deque(maxlen=LOG_REPEAT)
        self._dt = server.config.cycle_time
        self._silence = settings.takeover_cycles * self._dt
        # the drive hosts learn the pair's takeover bound with the outputs (they warn if their timeout is shorter)
        self.takeover_limit_ms = bound_ms = takeover_bound(settings.takeover_cycles, self._dt) * 1e3
        for lk in drive_links(self.real_drive):
            lk.takeover_ms = bound_ms

    # ---- session (start, before the cycle thread) ---------------------------------------------------------------
    def open(self, session: zenoh.Session) -> None:
        """Declare the ha keys on the NC's session; start as ``[redundancy] start`` says."""
        self._session = s = session
        k = self.keys
        self._log_pub = s.declare_publisher(f"{k}/log", congestion_control=zenoh.CongestionControl.DROP,
                                            priority=zenoh.Priority.DATA_HIGH)
        self._log_sub = s.declare_subscriber(f"{k}/log", FifoChannel(LOG_CHANNEL))
        self._status_pub = s.declare_publisher(f"{k}/status/{self.node}")
        self._active_sub = s.liveliness().declare_subscriber(f"{k}/active/*", FifoChannel(256), history=True)
        self._standby_sub = s.liveliness().declare_subscriber(f"{k}/standby/*", FifoChannel(256), history=True)
        self._started = self._last_log = time.monotonic()
        if self.settings.start == "active":
            self._become_active(time.monotonic(), first=True)
        else:
            self._ask_snapshot(time.monotonic())
            for lk in drive_links(self.real_drive):
                lk.epoch = 0

    def close(self) -> None:
        for d in (self._token, self._snap_q, self._log_sub, self._log_pub, self._status_pub, self._active_sub,
                  self._standby_sub):
            if d is not None:
                try:
                    d.undeclare()
                except Exception:
                    pass
        self._token = self._snap_q = None

    # ---- per cycle (cycle thread) -------------------------------------------------------------------------------
    def before_cycle(self, now: float) -> bool:
        """The pair's work at the start of a cycle; True: this NC is a standby (the cycle does nothing else)."""
        self._take_tokens()
        self._take_logs(now)
        if self.role == "active":
            if self._replaced():
                self._become_standby(now, "a drive host follows a higher epoch")
        else:
            self._take_snapshot(now)
            if self._lost(now):
                self._become_active(now)
        if now >= self._next_status:
            self._next_status = now + STATUS_PERIOD_S
            self._publish_status()
        return self.role != "active"

    def after_step(self) -> None:
        """The active NC's log of the cycle just stepped; snapshots asked for (after the log: a follower starting
        from it replays the next one)."""
        lg = self.rec.take(self.hrec.take(), self.epoch)
        self._recent.append(pickle.dumps(lg, protocol=pickle.HIGHEST_PROTOCOL))
        try:  # (the last LOG_REPEAT logs in each sample: a sample dropped on the way costs no re-sync)
            self._log_pub.put(pickle.dumps(list(self._recent), protocol=pickle.HIGHEST_PROTOCOL))
            self.logs_out += 1
        except Exception as exc:
            log.debug("log put: %s", exc)
        q = self._snap_q
        if q is not None:
            while True:
                try:
                    query = q.try_recv()
                except Exception:
                    break
                if query is None:
                    break
                try:  # (sent by the I/O thread: a reply may block on a slow querier)
                    self.srv.io.submit_replies([(query, snapshot(self.rec, self.hrec.full()))])
                    self.snapshots_served += 1
                    self._excused = True  # (tens of ms: the gap it makes is no stall, see after_stall)
                except Exception as exc:
                    log.warning("snapshot: %s", exc)

    def after_stall(self, gap: float) -> bool:
        """The active NC's cycle thread stalled ``gap`` [s]: longer than a takeover, with a standby in step, this
        NC must assume it was replaced (it stops driving before anything goes out). True: it is a standby now."""
        excused, self._excused = self._excused, False
        if self.role == "active" and self.peer_in_step and gap > self._silence and not excused:
            self._become_standby(time.monotonic(), f"stalled {gap:.3f} s with a standby in step")
            return True
        return False

    # ---- the parts ----------------------------------------------------------------------------------------------
    def _take_tokens(self) -> None:
        for sub, peers in ((self._active_sub, None), (self._standby_sub, self._peers)):
            while True:
                try:
                    ev = sub.try_recv()
                except Exception:
                    break
                if ev is None:
                    break
                node = str(ev.key_expr).rsplit("/", 1)[-1]
                if node == self.node:
                    continue
                present = ev.kind == zenoh.SampleKind.PUT
                if peers is None:
                    self.active_token_seen = present
                    if not present and self.role == "standby":
                        self._token_gone = True  # the active NC's token went: take over now
                elif present:
                    peers.add(node)
                else:
                    peers.discard(node)
        self.peer_in_step = bool(self._peers)

    def _take_logs(self, now: float) -> None:
        sub = self._log_sub
        while True:
            try:
                s = sub.try_recv()
            except Exception:
                break
            if s is None:
                break
            try:
                batch: list[bytes] = pickle.loads(s.payload.to_bytes())
                logs: list[CycleLog] = [pickle.loads(b) for b in batch]
            except Exception as exc:
                log.warning("unusable ha log: %s", exc)
                continue
            for lg in logs:
                if self._take_log(lg, now):
                    return

    def _take_log(self, lg: CycleLog, now: float) -> bool:
        """One log of a sample; True: this NC stopped being active (the rest of the sample is not its)."""
        if True:
            if lg.epoch > self.highest:
                self.highest = lg.epoch
            if self.role == "active":
                if lg.epoch > self.epoch:
                    self._become_standby(now, f"an NC of epoch {lg.epoch} is active")
                    return True
                return False  # (its own, or an older NC's: ignored)
            if lg.epoch < self.highest:
                self.stale_logs += 1
                return False
            core = self.follower.core
            if core is not None and not self.follower.waiting and lg.cycle <= core.cycle:
                return False  # (a repeat: the samples carry the last LOG_REPEAT logs)
            self.logs_in += 1
            self._last_log = now
            if self.follower.apply(lg):
                self.synced_once = True
                self._declare_standby(True)
        return False

    def _ask_snapshot(self, now: float) -> None:
        if self._session is None:
            return
        self._asked = now
        try:
            self._snap_replies = self._session.get(f"{self.keys}/snapshot", FifoChannel(4), timeout=SNAPSHOT_RETRY_S)
        except Exception as exc:
            log.debug("snapshot query: %s", exc)

    def _take_snapshot(self, now: float) -> None:
        if not self.follower.waiting:
            return
        r = self._snap_replies
        if r is not None:
            try:
                reply = r.try_recv()
            except Exception:
                reply = None
            if reply is not None and reply.ok is not None:
                try:
                    self.follower.load(reply.ok.payload.to_bytes())
                    self._snap_replies = None
                    log.info("standby %s: in step from cycle %d (snapshot)", self.node, self.core.cycle)
                    self._last_log = now
                    return
                except Exception as exc:
                    log.warning("unusable snapshot: %s", exc)
        if now - self._asked > SNAPSHOT_RETRY_S:
            self._ask_snapshot(now)

    def _resync(self, reason: str) -> None:
        log.warning("standby %s: out of step (%s): asking for a snapshot", self.node, reason)
        self._declare_standby(False)
        self._ask_snapshot(time.monotonic())

    def _lost(self, now: float) -> bool:
        """The active NC is lost: its token went, or no log for ``takeover_cycles`` (a standby that never followed
        one: none for START_GRACE_S and no active token)."""
        quiet = now - self._last_log
        if not self.synced_once:
            return quiet > START_GRACE_S and not self.active_token_seen and now - self._started > START_GRACE_S
        return (quiet > self._silence or self._token_gone) and not self.follower.waiting

    def _replaced(self) -> bool:
        return any(lk.host_epoch > self.epoch for lk in drive_links(self.real_drive))

    def _declare_standby(self, on: bool) -> None:
        s = self._session
        if s is None:
            return
        if on and self._token is None and self.role == "standby":
            self._token = s.liveliness().declare_token(f"{self.keys}/standby/{self.node}")
        elif not on and self._token is not None and self.role == "standby":
            self._token.undeclare()
            self._token = None

    def _become_active(self, now: float, first: bool = False) -> None:
        srv = self.srv
        lost_at = self._last_log
        self._token_gone = False
        self.epoch = next_epoch(max(self.highest, self.epoch), self.node)
        self.highest = self.epoch
        for lk in drive_links(self.real_drive):
            lk.epoch = self.epoch
        core = self.core
        if isinstance(core.drive, ReplayDrive):  # (a follower's): the real drives from now on
            self.real_drive.resync(core.drive.device_error)  # (their state now, not at their last exchange)
            core.drive = RecordingDrive(self.real_drive)
        self.rec.attach_drive(core.drive)
        hs = self.follower.handler_state
        if hs is not None:
            install_handler(srv.handler, hs)
            if hs.instance:
                srv.transport.instance = self.hrec.instance = hs.instance
        srv.claims.rebase(now)
        if self._token is not None:
            self._token.undeclare()
        self._token = self._session.liveliness().declare_token(f"{self.keys}/active/{self.node}") \
            if self._session is not None else None
        self._snap_q = self._session.declare_queryable(f"{self.keys}/snapshot", FifoChannel(16)) \
            if self._session is not None else None
        self.role = "active"
        srv.became_active(now)
        if first or not self.synced_once:
            log.info("NC %s active (epoch %d, node %s)", srv.config.name, self.epoch, self.node)
            return
        # the drives extrapolated their targets while the lost NC was silent (at most catch_up_ms): the core
        # steps over that time at once, so its first set-point is where the drives' targets are now
        quiet = max(0.0, now - lost_at) if lost_at > 0 else 0.0
        k = int(min(quiet, self.settings.catch_up_ms / 1000.0) / self._dt)
        for _ in range(max(0, k - 1)):
            self.rec.step()
            self.after_step()
        self.catch_up = k
        self.takeovers += 1
        self.takeover_s = time.monotonic() - lost_at if lost_at > 0 else 0.0
        self.takeover_cycles = int(round(self.takeover_s / self._dt)) if lost_at > 0 else 0
        log.warning("NC %s: took over at cycle %d (epoch %d, node %s): %.1f ms after the last log, %d cycles "
                    "caught up", srv.config.name, core.cycle, self.epoch, self.node, self.takeover_s * 1e3, k)

    def _become_standby(self, now: float, why: str) -> None:
        srv = self.srv
        log.warning("NC %s (node %s, epoch %d): %s: standby from now on, the drives are not driven by it",
                    srv.config.name, self.node, self.epoch, why)
        self.core.drive = ReplayDrive.of(self.real_drive)  # nothing goes to the drives any more
        self.rec.attach_drive(None)
        self.role = "standby"
        self.demotions += 1
        for d in (self._snap_q, self._token):
            if d is not None:
                try:
                    d.undeclare()
                except Exception:
                    pass
        self._snap_q = self._token = None
        srv.became_standby()
        self.follower.waiting = True
        self.synced_once = False
        self._last_log = now
        self._started = now
        self._ask_snapshot(now)

    def status(self) -> dict[str, Any]:
        """The ha status (``nc/<nc>/ha/status/<node>``, the stats' ``ha``)."""
        f = self.follower
        return {"node": self.node, "role": self.role, "epoch": self.epoch, "highest_epoch": self.highest,
                "in_step": self.role == "active" or (not f.waiting and self.synced_once),
                "cycle": int(self.core.cycle), "lag_cycles": int(f.lag), "logs_in": self.logs_in,
                "logs_out": self.logs_out, "resyncs": f.resyncs, "diverged": f.diverged,
                "snapshots_served": self.snapshots_served, "takeovers": self.takeovers, "demotions": self.demotions,
                "takeover_ms": round(self.takeover_s * 1e3, 3), "takeover_cycles": self.takeover_cycles,
                "catch_up_cycles": self.catch_up, "takeover_limit_cycles": self.settings.takeover_cycles,
                "takeover_limit_ms": round(self.takeover_limit_ms, 3),
                "peer_in_step": self.peer_in_step, "frames_fenced": self._fenced(), "time": time.time()}

    def _fenced(self) -> int:
        try:
            return int(self.srv.frames.ring.fenced)
        except (ValueError, AttributeError):  # (the ring is closed: the NC is stopping)
            return 0

    def _publish_status(self) -> None:
        try:
            self._status_pub.put(msgpack.packb(self.status()))
        except Exception as exc:
            log.debug("ha status put: %s", exc)
