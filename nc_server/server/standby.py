"""The hot-standby pair on zenoh (docs/standby.md): roles, epochs, the replication keys, takeover and demotion.

One :class:`HotStandby` per nc-server process with ``[redundancy] enabled``; the cycle thread calls
:meth:`HotStandby.before_cycle` first in every cycle (a standby replays the active NC's logs there and skips the
rest of the cycle) and :meth:`HotStandby.after_step` after the active NC's step (its log out, snapshots served).

Keys (``nc/<nc>/ha/...``):

* ``log``: every cycle, the active NC's :class:`~.replication.CycleLog` of its last LOG_REPEAT cycles (pickled; each as
  (epoch, cycle, pickled log): the receiver unpickles only what it replays);
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
import math
import os
import pickle
import socket
import time
from typing import TYPE_CHECKING, Any

import msgpack
import zenoh
from zenoh.handlers import FifoChannel, RingChannel

from nc_schema import Keys, frame_header
from nc_server.drives.remote.config import LIMIT_CAP_S, takeover_bound

from .config import NODE_MAX, Redundancy
from .replication import (FINGERPRINT, STAMP, CoreRecorder, CycleLog, Follower, HandlerRecorder, RecordingDrive,
                          ReplayDrive, SoftwareMismatch, install_handler, loads_plain, merge_handler,
                          peer_fingerprint, snapshot, stamp)
from .transport import drain

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
#: the loss detector (LossDetector): how long the gaps between the active NC's logs are remembered [s] (in bins of
#: GAP_BIN_S, the largest gap of each), the factor on the largest one, the warm-up after a standby comes in step and its
#: floor, and the cap of the limit [s]. 10 s and 2x were too little on 2 cores with the pair, a drive host, a router
#: and clients: every 1-2 minutes a silence of 20-90 ms just above 2x the largest gap of the 10 s before, a takeover
#: of a live NC (bench/many_clients.py --standby, docs/standby.md)
GAP_WINDOW_S = 60.0
GAP_BIN_S = 1.0
GAP_FACTOR = 3.0
WARMUP_S = 3.0
WARMUP_FLOOR_S = 0.5
#: how long an active NC counts a standby's published limit (its ha status) [s]
PEER_STATUS_S = 10.0
# (LIMIT_CAP_S: nc_server.drives.remote.config, whose timeout checks count with it)
#: an active NC that stalled longer than this share of its standby's limit (or of its lease) demotes itself
STALL_MARGIN = 0.75
#: an active NC that stalled longer than this share of that limit (but not long enough to demote itself) listens for
#: HOLD_S [s] for a log of a higher epoch before its cycle goes on
HOLD_SHARE = 0.5
HOLD_S = 0.01
#: the period [ms] of the frames (a view of no axis: their header) a standby watches as a second sign of life of the
#: active NC: its Cycle going on while its logs are late (docs/standby.md, "Loss detection")
SIGN_FRAME_MS = 10


class LossDetector:
    """When a standby deems the active NC lost by the silence of its logs (a freeze, a link cut; a kill is seen at
    once from the active NC's liveliness token), and the limit it publishes (ha status ``takeover_limit_cycles``).

    The limit is ``takeover_cycles`` while the logs come on time; a loaded machine makes them late (the active NC's
    cycle thread, zenoh's threads or the standby's own cycle thread descheduled: 150 ms seen at load average 20 with
    realtime off), so the limit follows GAP_FACTOR x the largest gap between logs of the last GAP_WINDOW_S, capped
    at LIMIT_CAP_S: a late log is no loss, a missing one is. The gaps are kept per GAP_BIN_S bin (the largest of
    each), so the window is GAP_WINDOW_S however many gaps the load makes, and they outlive a re-sync and a role
    change (how late logs come is the machine's, not the role's: with a fresh history after each takeover of a live
    NC, the next one came sooner). For WARMUP_S after the standby came in step (the active NC has just built a
    snapshot) it is at least WARMUP_FLOOR_S. And a silence is judged only in a cycle of the standby that is itself
    on time, or the second in a row: after its own stall the logs may still be on their way through zenoh's threads.

    Args:
        base_s: ``takeover_cycles`` x the cycle time [s].
        cap_s: the cap of the limit [s]: LIMIT_CAP_S, or the active NC's lease when shorter (its tokens go then: the
            limit published and the one applied are the same).
    """

    def __init__(self, base_s: float, cap_s: float = LIMIT_CAP_S) -> None:
        self.base = base_s
        self.cap = cap_s
        self.last = 0.0       # when the newest log was taken
        self.since = -1e9     # when the standby came in step (the warm-up's start)
        self.restarted = False  # restart() was called: before, no gap is kept (the first log's "gap" is the clock)
        #: (bin start [s], the largest gap that ended in that bin [s]), oldest first
        self.gaps: collections.deque[tuple[float, float]] = collections.deque()
        self._max_gap = 0.0  # the largest gap in :attr:`gaps` (-1: to be found again)
        self._prev_cycle = 0.0
        self._deferred = False

    def restart(self, now: float, forget: bool = False) -> None:
        """In step from a snapshot (or a new role): the warm-up starts; ``forget``: the gap history too."""
        self.last = self.since = now
        self.restarted = True
        if forget:
            self.gaps.clear()
            self._max_gap = 0.0
        self._deferred = False

    def seed(self, now: float, gap: float) -> None:
        """Keep ``gap`` [s] as if seen now (a demoted active NC: the gaps its standby saw, from the limit it published;
        its own detector saw none while it was active)."""
        self._keep(now, gap)

    def log(self, now: float, record: bool = True) -> None:
        """A log of the active NC was taken at ``now``; ``record`` False: the gap before it is not kept (a standby
        not in step: waiting for a snapshot, its gaps are the cut or the snapshot's cost, not the machine's)."""
        gap = now - self.last
        self.last = now
        if record and self.restarted and gap > self.base / 4:  # (within a quarter of the base: never raises it)
            self._keep(now, gap)

    def _keep(self, now: float, gap: float) -> None:
        """Keep ``gap`` [s] in the bin of ``now`` (the largest of a bin stays)."""
        start = now - now % GAP_BIN_S
        g = self.gaps
        if g and g[-1][0] == start:
            if gap > g[-1][1]:
                g[-1] = (start, gap)
        else:
            g.append((start, gap))
        if self._max_gap >= 0.0:
            self._max_gap = max(self._max_gap, gap)

    def limit(self, now: float) -> float:
        """The silence [s] that is a loss now."""
        g = self.gaps
        while g and now - g[0][0] > GAP_WINDOW_S + GAP_BIN_S:
            if g.popleft()[1] >= self._max_gap:
                self._max_gap = -1.0  # (the largest went: found again below)
        if not g:
            self._max_gap = 0.0
        elif self._max_gap < 0.0:  # (called every standby cycle: the max of up to 61 bins only when it changed)
            self._max_gap = max(x for _, x in g)
        lim = max(self.base, GAP_FACTOR * self._max_gap)
        if now - self.since < WARMUP_S:
            lim = max(lim, WARMUP_FLOOR_S)
        return max(self.base, min(lim, self.cap))

    def silent(self, now: float) -> bool:
        """The logs have been missing longer than :meth:`limit` (call once per standby cycle, at its start)."""
        own = now - self._prev_cycle
        self._prev_cycle = now
        if own > self.base / 2 and not self._deferred:  # this cycle is late itself: the next one judges
            self._deferred = True
            return False
        self._deferred = False
        return now - self.last > self.limit(now)


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


class _Unusable(Exception):
    """A log of an ha log sample that cannot be replayed (it did not unpickle, or is not what its header says)."""


#: the most logs a sample may carry (a sender sends LOG_REPEAT; more: not a sample of any release)
SAMPLE_LOGS_MAX = 64


def _headers(batch: Any, foreign: bool) -> list[tuple[int, int, bytes]]:
    """The (epoch, cycle, pickled log) entries of a builtins-only unpickled ha log sample, checked: a list of at most
    SAMPLE_LOGS_MAX 3-tuples of int (not bool), int, bytes, taken as they are (nothing converted: ``bytes(n)`` of an
    int would allocate n bytes); a foreign sample's logs are never read, they are dropped (b"").

    Raises:
        ValueError: the sample is not one (it is unusable).
    """
    if type(batch) is not list or len(batch) > SAMPLE_LOGS_MAX:
        raise ValueError(f"not an ha log sample: {type(batch).__name__}")
    out = []
    for h in batch:
        if type(h) is not tuple or len(h) != 3 or type(h[0]) is not int or type(h[1]) is not int \
                or type(h[2]) is not bytes:
            raise ValueError("not an ha log sample: an entry is not (int, int, bytes)")
        out.append((h[0], h[1], b"" if foreign else h[2]))
    return out


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
        self.detect_s = self.work_s = self.serve_s = 0.0  # the last takeover's parts (docs/standby.md)
        self._serve_pending = False
        self._serve_tries = 0  # (failed declarations of the takeover so far: retried every cycle)
        self._lost_at = self._detected_at = 0.0
        self._lost_why = ""
        self.logs_in = 0
        self.logs_out = 0
        self.snapshots_served = 0
        self.snapshot_s = 0.0  # the longest snapshot built in the cycle thread (it makes that cycle late)
        self.stale_logs = 0
        self.unusable_logs = 0  # ha logs that did not unpickle (a peer of another release)
        self._unusable_warned = -1e9
        #: (standby) why it refuses to get in step: the active NC runs other NC software ("" if not); the fingerprint
        #: of the newest log sample's NC when it differs from this NC's (no snapshot is asked for then)
        self.refused = ""
        self._foreign = ""
        #: silences of the logs forgiven because the active NC's frames showed its Cycle going on (a takeover then
        #: would have started from a state behind what the clients saw: their Cycle would go back, an NC restart)
        self.frames_alive = 0
        self._frame_sub: Any = None
        self._view_token: Any = None
        self._view_sel = ""
        self._frame_epoch = -1       # the epoch and Cycle of the newest frame of the active NC taken
        self._frame_cycle = -1
        self._frame_alive = -1e9     # when a frame of the followed epoch last showed its Cycle going on [monotonic]
        self._forgiving = False      # (the silence of the logs is forgiven now: counted once per silence)
        self.synced_once = False
        self.followed = False  # in step with an active NC once (a takeover since is no cold start: docs/standby.md)
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
        # (standby in step) the NC's tokens nc/<nc>/alive and nc/<nc>/alive/<instance> (the active NC's instance),
        # held like the active NC holds them: a kill of the active NC is no "NC gone" for the clients (_nc_tokens)
        self._nc_token: Any = None
        self._nc_inst_token: Any = None
        self._nc_inst = ""
        self._next_status = 0.0
        self._excused = False  # the last cycle served a snapshot
        self._current = False  # (_take_logs) the sample held a log of the highest epoch
        self._recent: collections.deque[tuple[int, int, bytes]] = collections.deque(maxlen=LOG_REPEAT)
        self._dt = server.config.cycle_time
        self._silence = settings.takeover_cycles * self._dt
        # the drive hosts learn the pair's takeover bound with the outputs (they warn if their timeout is shorter);
        # the limit in force follows the loss detector (_refresh_limit, in the cycle thread)
        self.takeover_limit_ms = bound_ms = takeover_bound(settings.takeover_cycles, self._dt) * 1e3
        for lk in drive_links(self.real_drive):
            lk.takeover_limit_ms = bound_ms
        zn = getattr(server.config, "zenoh", None)
        self._lease = float(getattr(zn, "lease_ms", 500)) / 1000.0  # (a freeze this long drops this NC's tokens)
        self.detector = LossDetector(self._silence, min(LIMIT_CAP_S, self._lease))
        self._peer_limits: dict[str, tuple[float, float]] = {}  # (active) node -> (its limit [s], when seen)
        self._status_sub: Any = None
        self._limit = settings.takeover_cycles  # the published limit [cycles] (_refresh_limit)
        self._grace = START_GRACE_S  # (standby, never in step) no active NC this long: take over
        # (active) until a drive host's inputs carry this NC's epoch: the inputs of another epoch taken since it
        # became active (None: confirmed, or no remote drives); the links' input counts at the last look
        self._unconfirmed: int | None = None
        self._received: list[int] = []

    # ---- session (start, before the cycle thread) ---------------------------------------------------------------
    def open(self, session: zenoh.Session) -> None:
        """Declare the ha keys on the NC's session; start as ``[redundancy] start`` says."""
        self._session = s = session
        k = self.keys
        self._log_pub = s.declare_publisher(f"{k}/log", congestion_control=zenoh.CongestionControl.DROP,
                                            priority=zenoh.Priority.DATA_HIGH)
        # (the peer NC's logs only: the active NC's own samples, every cycle, came back to it to be ignored)
        self._log_sub = s.declare_subscriber(f"{k}/log", FifoChannel(LOG_CHANNEL), allowed_origin=zenoh.Locality.REMOTE)
        self._status_pub = s.declare_publisher(f"{k}/status/{self.node}")
        self._active_sub = s.liveliness().declare_subscriber(f"{k}/active/*", FifoChannel(256), history=True)
        self._standby_sub = s.liveliness().declare_subscriber(f"{k}/standby/*", FifoChannel(256), history=True)
        self._status_sub = s.declare_subscriber(f"{k}/status/*", FifoChannel(64))
        # (the newest only, one frame per SIGN_FRAME_MS of NC time: a view of no axis, i.e. the frame header alone,
        # asked for as a client "ha-<node>" does, by the view token, held while this NC is a standby: _view; the
        # config caps the node name so that ha-<node> is a client id, and the roles file reserves the prefix)
        ks = Keys(self.srv.config.name)
        client = f"ha-{self.node}"
        try:
            self._view_sel, key = ks.view_select(client, SIGN_FRAME_MS, ()), ks.view(client)
        except ValueError as exc:
            raise ValueError(f"redundancy node {self.node!r}: {exc} (at most {NODE_MAX} characters)") from None
        self._frame_sub = s.declare_subscriber(key, RingChannel(1))
        self._started = self._last_log = time.monotonic()
        if self.settings.start == "active":
            self._become_active(time.monotonic(), first=True)
        else:
            self._view(True)
            self._ask_snapshot(time.monotonic())
            for lk in drive_links(self.real_drive):
                lk.epoch = 0

    def _view(self, on: bool) -> None:
        """Declare (``on``, a standby) or undeclare (the active NC: its own publisher would send the view back to it
        every SIGN_FRAME_MS) the view token of the frames' sign of life."""
        s = self._session
        try:
            if on and self._view_token is None and s is not None and self._view_sel:
                self._view_token = s.liveliness().declare_token(self._view_sel)
            elif not on and self._view_token is not None:
                self._view_token, tok = None, self._view_token
                tok.undeclare()
        except Exception as exc:  # (no sign of life from the frames then: the logs alone, as before)
            log.warning("standby %s: the frames' view token: %s", self.node, exc)

    def close(self) -> None:
        self._nc_tokens(False)
        for d in (self._token, self._snap_q, self._log_sub, self._log_pub, self._status_pub, self._active_sub,
                  self._standby_sub, self._status_sub, self._frame_sub, self._view_token):
            if d is not None:
                try:
                    d.undeclare()
                except Exception:
                    pass
        self._token = self._snap_q = self._frame_sub = self._view_token = None

    # ---- per cycle (cycle thread) -------------------------------------------------------------------------------
    def before_cycle(self, now: float) -> bool:
        """The pair's work at the start of a cycle; True: this NC is a standby (the cycle does nothing else)."""
        self._take_tokens()
        self._take_logs(now)
        if self.role == "active":
            if self._replaced():
                self._become_standby(now, "a drive host follows a higher epoch")
            elif self._unconfirmed_too_long():
                self._become_standby(now, f"no drive host follows its epoch {self.epoch} after "
                                          f"{self._unconfirmed} inputs of others")
        else:
            self._take_snapshot(now)
            self._take_frame(now)
            if self._lost(now):
                self._become_active(now)
        # (a takeover's figures come after its first step: no status before, unless its declarations failed)
        if now >= self._next_status and not (self._serve_pending and self._serve_tries == 0):
            self._next_status = now + STATUS_PERIOD_S
            self._refresh_limit(now)
            self._publish_status()
        return self.role != "active"

    def after_step(self) -> None:
        """The active NC's log of the cycle just stepped; snapshots asked for (after the log: a follower starting
        from it replays the next one)."""
        if self._serve_pending:
            self._finish_takeover()
        lg = self.rec.take(self.hrec.take(), self.epoch)
        # (epoch and cycle beside the pickled log: a receiver skips its own logs and the repeats without unpickling)
        self._recent.append((lg.epoch, lg.cycle, pickle.dumps(lg, protocol=pickle.HIGHEST_PROTOCOL)))
        try:  # (the last LOG_REPEAT logs in each sample: a sample dropped on the way costs no re-sync)
            self._log_pub.put(stamp(pickle.dumps(list(self._recent), protocol=pickle.HIGHEST_PROTOCOL)))
            self.logs_out += 1
        except Exception as exc:
            log.debug("log put: %s", exc)
        q = self._snap_q
        if q is not None:
            for query in drain(q):
                try:  # (sent by the I/O thread: a reply may block on a slow querier)
                    t0 = time.perf_counter()
                    data = snapshot(self.rec, self.hrec.full())
                    self.snapshot_s = max(self.snapshot_s, time.perf_counter() - t0)
                    self.srv.io.submit_replies([(query, data)])
                    self.snapshots_served += 1
                    self._excused = True  # (tens of ms: the gap it makes is no stall, see after_stall)
                except Exception as exc:
                    log.warning("snapshot: %s", exc)

    def after_stall(self, gap: float) -> bool:
        """The active NC's cycle thread stalled ``gap`` [s]: longer than a takeover, with a standby in step, this
        NC must assume it was replaced (it stops driving before anything goes out). True: it is a standby now."""
        excused, self._excused = self._excused, False
        # the standby took over after the published limit from its last log, or when this NC's session lease ran
        # out (its tokens go: a freeze longer than the lease): a stall a bit shorter than that may have been one
        # too (the last log reached the standby late); a demotion without a takeover costs a takeover by the standby,
        # not demoting after one costs frames of this NC after the new one's (the clients' Cycle goes back)
        raw = min(self.peer_limit(time.monotonic()), self._lease)
        limit = max(self._silence, STALL_MARGIN * raw)
        if self.role != "active" or not self.peer_in_step or excused:
            return False
        if gap > limit:
            self._become_standby(time.monotonic(), f"stalled {gap:.3f} s (the standby's limit {limit:.3f} s) with a "
                                 "standby in step")
            # (if the standby did not take over after all, e.g. the stall was close to its limit, no NC would drive:
            # this one takes over again after a grace without an active NC, with the epoch it drove with: at least
            # START_GRACE_S, for its session to come back and show a successor's token or logs, _lost, _become_active)
            self._grace = max(START_GRACE_S, 2 * limit + 0.1)
            return True
        if gap > max(self._silence, HOLD_SHARE * raw):
            # a stall not far below the standby's limit: if it took over, its logs (a higher epoch) may still be in
            # this NC's zenoh threads, which resumed with it; listen for them for HOLD_S before anything of this
            # cycle goes out (frames of this NC after the new one's: the clients' Cycle would go back)
            end = time.monotonic() + HOLD_S
            while True:
                self._take_logs(time.monotonic())  # (a log of a higher epoch demotes this NC: _take_log)
                if self.role != "active":
                    return True
                if time.monotonic() >= end:
                    return False
                time.sleep(0.0005)
        return False

    def peer_limit(self, now: float) -> float:
        """(active) The silence a standby in step takes for a loss now [s]: the largest limit of the ha statuses of
        the other nodes of the last PEER_STATUS_S (their LossDetector's), at least ``takeover_cycles``; none: the
        detector's cap."""
        sub = self._status_sub
        for s in drain(sub) if sub is not None else ():
            try:
                st = msgpack.unpackb(s.payload.to_bytes(), raw=False)
                if st.get("node") != self.node and st.get("role") == "standby" and st.get("in_step"):
                    self._peer_limits[str(st["node"])] = (float(st["takeover_limit_cycles"]) * self._dt, now)
            except Exception:
                continue
        # (a status some seconds old still holds: a loaded machine delays them too; none yet: the cap, the most a
        # standby ever waits)
        fresh = [lim for lim, t in self._peer_limits.values() if now - t < PEER_STATUS_S]
        return max([self._silence, *fresh]) if fresh else max(self._silence, LIMIT_CAP_S)

    # ---- the parts ----------------------------------------------------------------------------------------------
    def _take_tokens(self) -> None:
        for sub, peers in ((self._active_sub, None), (self._standby_sub, self._peers)):
            for ev in drain(sub):
                node = str(ev.key_expr).rsplit("/", 1)[-1]
                if node == self.node:
                    continue
                present = ev.kind == zenoh.SampleKind.PUT
                if peers is None:
                    self.active_token_seen = present
                    if not present and self.role == "standby":
                        self._token_gone = True  # the active NC's token went: take over now
                    elif present:
                        # (back: its session was dropped in a stall and re-established, the NC lives; a latched
                        # "gone" would take over from a live NC as soon as this standby is in step)
                        self._token_gone = False
                elif present:
                    peers.add(node)
                else:
                    peers.discard(node)
        self.peer_in_step = bool(self._peers)

    def _take_logs(self, now: float) -> None:
        sub = self._log_sub
        for s in drain(sub):
            payload = s.payload.to_bytes()
            # (another NC software's logs are never unpickled; their headers are builtins only, read by loads_plain:
            # their epochs still count, an active NC of a higher epoch is one whatever it runs)
            foreign = "" if payload.startswith(STAMP) else peer_fingerprint(payload) or "-"
            try:
                body = payload[len(STAMP):] if foreign != "-" else payload
                logs = _headers(loads_plain(body, bounded=bool(foreign)), bool(foreign))
            except Exception as exc:
                self._warn_unusable(now, exc)
                continue
            self._current = False
            for epoch, cycle, data in logs:
                try:
                    if self._take_log(epoch, cycle, data, now, foreign):
                        return
                except _Unusable as exc:
                    self._warn_unusable(now, exc)
                    break
            if self._current and self.role == "standby":
                # (a sign of life of the NC followed: only logs of the highest epoch; a zombie of a lower one must
                # not keep the standby from judging the silence of the active NC)
                self.detector.log(now, record=self.synced_once and not self.follower.waiting)
                self._forgiving = False

    def _warn_unusable(self, now: float, exc: Exception) -> None:
        """Log an unusable ha log at most every 5 s (a peer of another release sends 1000 a second: both NCs of a
        pair must run the same release, the logs are pickles of its classes)."""
        self.unusable_logs += 1
        if now - self._unusable_warned >= 5.0:
            self._unusable_warned = now
            log.warning("unusable ha log (%d so far; both NCs of a pair must run the same release): %s",
                        self.unusable_logs, exc)

    def _take_log(self, epoch: int, cycle: int, data: bytes, now: float, foreign: str = "") -> bool:
        """One log of a sample (its epoch, its cycle and the pickled :class:`CycleLog`, unpickled only when it is
        replayed or held: the active NC's own logs and the repeats are not); True: this NC stopped being active (the
        rest of the sample is not its). ``foreign``: the sample's fingerprint when it is not this NC's ("-": none):
        the log is refused unread (:meth:`_refuse`).

        Raises:
            _Unusable: the log did not unpickle, or its epoch and cycle are not the sample's.
        """
        if epoch > self.highest:
            self.highest = epoch
        if self.role == "active":
            if epoch > self.epoch:
                self._become_standby(now, f"an NC of epoch {epoch} is active")
                return True
            return False  # (its own, or an older NC's: ignored)
        if epoch < self.highest:
            self.stale_logs += 1
            return False
        self._current = True  # (the sample came from the NC followed: a sign of life even if a log of it is unusable)
        self._foreign = foreign
        if foreign:
            # (before the repeat filter: a peer restarted with other software that took over, a higher epoch from a
            # low cycle, sends only cycles <= this core's; dropped as repeats they would keep this standby in step)
            # out of step for good (no snapshot asked for); a sign of life as an unusable log was: a standby that
            # never got in step takes over only START_GRACE_S after the last one, with its own state (_lost)
            self._last_log = now
            self._refuse(SoftwareMismatch("" if foreign == "-" else foreign, "log"))
            return False
        core = self.follower.core
        if core is not None and not self.follower.waiting and cycle <= core.cycle:
            return False  # (a repeat: the samples carry the last LOG_REPEAT logs)
        try:
            lg: CycleLog = pickle.loads(data)
        except Exception as exc:
            raise _Unusable(f"cycle {cycle}: {exc}") from None
        if lg.epoch != epoch or lg.cycle != cycle:
            raise _Unusable(f"a log of epoch {lg.epoch} cycle {lg.cycle} sent as epoch {epoch} cycle {cycle}")
        self.logs_in += 1
        self._last_log = now
        if self.follower.apply(lg):
            self.synced_once = self.followed = True
            self._declare_standby(True)
        return False

    def _ask_snapshot(self, now: float) -> None:
        if self._session is None or self._foreign:  # (another software's snapshot would be refused: none built)
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
                    # (after the load, which takes a while: the silence counts from now; the active NC's cycle that
                    # built the snapshot was late too: the detector's warm-up)
                    self._last_log = time.monotonic()
                    self.detector.restart(self._last_log)
                    self._forget_frames()
                    self.refused = ""
                    return
                except SoftwareMismatch as exc:
                    self._foreign = exc.theirs or "-"
                    self._refuse(exc)
                except Exception as exc:
                    log.warning("unusable snapshot: %s", exc)
        if now - self._asked > SNAPSHOT_RETRY_S and not self._foreign:
            self._ask_snapshot(now)

    def _refuse(self, exc: SoftwareMismatch) -> None:
        """The active NC runs other NC software: this standby does not get in step (one warning per peer software;
        the ha status ``refused`` says why); in step before (with an NC of this software), it is out of step now."""
        if not self.follower.waiting:
            self.follower.lose(str(exc), False)
        why = (f"the active NC runs NC software {exc.theirs[:12] or 'unknown (unstamped)'}, this standby "
               f"{FINGERPRINT[:12]}: not in step (a pair must run the same NC software)")
        if why != self.refused:
            self.refused = why
            log.warning("standby %s: %s", self.node, why)

    def _resync(self, reason: str) -> None:
        # (refused: the active NC runs other software, _ask_snapshot asks for none)
        log.warning("standby %s: out of step (%s): %s", self.node, reason,
                    "no snapshot asked for (other NC software)" if self._foreign else "asking for a snapshot")
        self._forget_frames()
        self._declare_standby(False)
        self._ask_snapshot(time.monotonic())

    def _lost(self, now: float) -> bool:
        """The active NC is lost: its token went, or no log for ``takeover_cycles`` (a standby that never followed
        one: none for START_GRACE_S and no active token)."""
        if not self.synced_once:
            # an NC that drove (an epoch) and saw a higher one since (a log, a drive host's inputs) is behind its
            # successor: its core is stale, it waits for a snapshot (a takeover from it would be a jump); else (nobody
            # else took over since: its own state is the newest) it takes over after the grace without an active NC
            seen = max([self.highest, *(lk.host_epoch for lk in drive_links(self.real_drive))])
            if self.epoch and seen > self.epoch:
                return False
            g = self._grace
            return now - self._last_log > g and not self.active_token_seen and now - self._started > g
        if self.follower.waiting:
            return False
        if self._token_gone:
            self._lost_why = "its token went"
            return True
        if self.detector.silent(now):
            limit = self.detector.limit(now)
            if now - self._frame_alive <= limit:
                # (bounded: the logs go CongestionControl.DROP and are heavy, under load all of them may drop while
                # the frames get through; a standby forgiving that for ever stays "in step" on a state seconds old,
                # and a later kill, its token gone, would take over from it: a SetPos jump, the Cycle going back)
                quiet = now - self._last_log
                behind = (self._frame_cycle - int(self.core.cycle)) * self._dt \
                    if self._frame_epoch == self.highest else 0.0
                if max(quiet, behind) > self.detector.cap:
                    self.follower.lose(f"no log for {quiet * 1e3:.0f} ms while the frames go on (frame cycle "
                                       f"{self._frame_cycle}, this standby at {self.core.cycle}; cap "
                                       f"{self.detector.cap * 1e3:.0f} ms)", False)
                    return False
                # the active NC's frames show its Cycle going on: it lives, only its logs are late (the heavy ones:
                # 8 cycles' logs a sample, every cycle, through zenoh and the router). Taking over now would start
                # from its state of the last log, behind what the clients saw (their Cycle would go back: an NC
                # restart for them; the commands of the cycles in between lost). The logs come later (or a gap asks
                # for a snapshot); when the frames stop too, the limit runs out and it takes over
                if not self._forgiving:
                    self._forgiving = True
                    self.frames_alive += 1
                    log.info("standby %s: no log for %.0f ms (limit %.0f) but the active NC's frames go on (cycle %d, "
                             "this standby at %d): no takeover", self.node, (now - self.detector.last) * 1e3,
                             limit * 1e3, self._frame_cycle, self.core.cycle)
                return False
            self._lost_why = f"no log for {(now - self.detector.last) * 1e3:.0f} ms, limit {limit * 1e3:.0f}"
            return True
        return False

    def _take_frame(self, now: float) -> None:
        """(standby) The newest decimated status frame: one of the followed epoch whose Cycle went on since the last
        one taken is a sign of life of the active NC (:meth:`_lost`). The first frame of an epoch is none (no
        progress seen yet)."""
        sub = self._frame_sub
        if sub is None:
            return
        try:
            s = sub.try_recv()
        except Exception:  # (the session closing)
            return
        if s is None:
            return
        try:
            h = frame_header(s.payload.to_bytes())
        except ValueError:
            return
        if h.Epoch != self._frame_epoch:
            self._frame_epoch, self._frame_cycle = int(h.Epoch), int(h.Cycle)
            return
        if h.Cycle > self._frame_cycle:
            self._frame_cycle = int(h.Cycle)
            # (life beyond what the logs show only: a frame of a cycle the logs already brought, e.g. of a burst
            # queued in a stall, would put the takeover off past the published limit)
            if h.Epoch == self.highest and self.highest and h.Cycle > self.core.cycle:
                self._frame_alive = now

    def _forget_frames(self) -> None:
        """The frames' sign of life starts over (in step from a snapshot, a resync, a role change)."""
        self._frame_epoch = self._frame_cycle = -1
        self._frame_alive = -1e9
        self._forgiving = False

    def _replaced(self) -> bool:
        return any(lk.host_epoch > self.epoch for lk in drive_links(self.real_drive))

    def _unconfirmed_too_long(self) -> bool:
        """(active) No drive host's inputs carried this NC's epoch since it became active, while more than
        :meth:`_confirm_cycles` cycles with inputs of another epoch came: its outputs do not reach the drives or are
        refused; a standby that reaches them takes over once this NC steps down."""
        if self._unconfirmed is None:
            return False
        links = drive_links(self.real_drive)
        if any(lk.input_epoch == self.epoch for lk in links):
            self._unconfirmed = None
            return False
        counts = [lk.received for lk in links]
        if counts != self._received:  # (new inputs, none of them with this NC's epoch)
            self._received = counts
            self._unconfirmed += 1
        return self._unconfirmed > self._confirm_cycles()

    def _confirm_cycles(self) -> int:
        """Cycles with inputs of another epoch an active NC waits for its own (_unconfirmed_too_long): its limit,
        at least LIMIT_CAP_S (a loaded machine delays the round trip through zenoh by 100s of ms: a false step-down
        leaves the drives without an NC until a retake)."""
        return max(self.settings.takeover_cycles, self._limit, math.ceil(LIMIT_CAP_S / self._dt - 1e-9))

    def _declare_standby(self, on: bool) -> None:
        s = self._session
        if s is None:
            return
        if self.role == "standby":
            self._nc_tokens(on)
        if on and self._token is None and self.role == "standby":
            self._token = s.liveliness().declare_token(f"{self.keys}/standby/{self.node}")
        elif not on and self._token is not None and self.role == "standby":
            self._token.undeclare()
            self._token = None

    def _nc_tokens(self, on: bool) -> None:
        """(standby) Declare (``on``) or undeclare the NC's tokens ``nc/<nc>/alive`` and ``nc/<nc>/alive/<instance>``
        with the active NC's instance id (the replicated handler state's). A standby in step holds them too: zenoh
        keeps a liveliness key alive while any session holds it, so a kill of the active NC is no "NC gone" for the
        clients (nc_link: every block ended with 0x4B0F) while this NC takes over (it hands them to the transport,
        _hand_over). Out of step (waiting for a snapshot, demoted) it holds none: no NC could serve then."""
        if not on:
            for d in (self._nc_inst_token, self._nc_token):
                if d is not None:
                    try:
                        d.undeclare()
                    except Exception as exc:
                        log.debug("NC token undeclare: %s", exc)
            self._nc_token = self._nc_inst_token = None
            self._nc_inst = ""
            return
        hs = self.follower.handler_state
        inst = str(getattr(hs, "instance", "") or "")
        if self._nc_token is not None and inst == self._nc_inst:
            return  # (every log in step comes here: nothing to do)
        s = self._session
        if s is None:
            return
        try:
            keys = Keys(self.srv.config.name)
            if inst != self._nc_inst and self._nc_inst_token is not None:  # (another instance's snapshot)
                self._nc_inst_token.undeclare()
                self._nc_inst_token, self._nc_inst = None, ""
            if self._nc_token is None:
                self._nc_token = s.liveliness().declare_token(keys.alive)
            if self._nc_inst_token is None and inst:
                self._nc_inst_token = s.liveliness().declare_token(keys.alive_instance(inst))
                self._nc_inst = inst
        except Exception as exc:  # (tried again with the next log in step)
            log.warning("standby %s: the NC's tokens: %s", self.node, exc)

    def _hand_over(self) -> None:
        """(takeover, before transport.serve()) The NC's tokens this standby held go to the transport, which then
        declares only what is missing: the key is held all along (no DELETE for the clients)."""
        t = self.srv.transport
        if self._nc_token is not None and getattr(t, "token", "") is None:
            t.token, self._nc_token = self._nc_token, None
        if self._nc_inst_token is not None and getattr(t, "instance_token", "") is None \
                and self._nc_inst == getattr(t, "instance", None):
            t.instance_token, self._nc_inst_token, self._nc_inst = self._nc_inst_token, None, ""

    def _take_back(self) -> None:
        """(a takeover whose declarations failed: transport.unserve() follows) The NC's tokens back to this NC, held
        until the next try hands them over again (unserve would drop them: a DELETE for the clients)."""
        t = self.srv.transport
        if getattr(t, "token", None) is not None and self._nc_token is None:
            self._nc_token, t.token = t.token, None
        if getattr(t, "instance_token", None) is not None and self._nc_inst_token is None:
            self._nc_inst_token, t.instance_token = t.instance_token, None
            self._nc_inst = str(getattr(t, "instance", ""))

    def _become_active(self, now: float, first: bool = False) -> None:
        srv = self.srv
        lost_at = self._last_log
        # (the takeover's figures count from the last sign of life, a log or a frame beyond the logs; the catch-up
        # from the last log: the state the core continues from)
        alive_at = max(lost_at, self._frame_alive)
        self._forget_frames()
        self._token_gone = False
        self._grace = START_GRACE_S
        self.refused = self._foreign = ""  # (a refusal is a standby's: the active NC is refused by nobody)
        if self.epoch and not self.synced_once and not first:
            # an NC that drove and demoted itself, in step with nobody since: it takes over again with the epoch it
            # drove with (a new one could win the tie against a successor it does not see, its state older than the
            # successor's); the drive hosts take it only if nobody took over meanwhile (else their epoch demotes it)
            log.warning("NC %s (node %s): no active NC: drives again with its epoch %d", srv.config.name, self.node,
                        self.epoch)
        else:
            self.epoch = next_epoch(max(self.highest, self.epoch), self.node)
        self.highest = max(self.highest, self.epoch)
        links = drive_links(self.real_drive)
        self._unconfirmed = 0 if links else None
        self._received = [lk.received for lk in links]
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
        self.role = "active"
        if first:
            self._serve()
            srv.became_active(now)
            log.info("NC %s active (epoch %d, node %s)", srv.config.name, self.epoch, self.node)
            return
        if not self.synced_once:  # (a retake from its own core: no catch-up; the declarations after the step)
            srv.became_active(now, serve=False)
            self._lost_at, self._detected_at, self.catch_up = 0.0, now, 0
            self._serve_pending, self._serve_tries = True, 0
            log.info("NC %s active (epoch %d, node %s)", srv.config.name, self.epoch, self.node)
            return
        srv.became_active(now, serve=False)
        self._lost_at, self._detected_at = alive_at, now
        # the drives extrapolated their targets while the lost NC was silent (at most catch_up_ms): the core
        # steps over that time at once, so its first set-point is where the drives' targets are now. The catch-up
        # steps send nothing to the drives (their set-points are behind the drives' targets: a step back, then
        # forward); the cycle's own step after them sends the first outputs
        quiet = max(0.0, now - lost_at) if lost_at > 0 else 0.0
        k = int(min(quiet, self.settings.catch_up_ms / 1000.0) / self._dt + 1e-6)  # (a quiet time of 10 ms measured as 9.99999... ms)
        self.catch_up = k
        self.takeovers += 1
        links = drive_links(self.real_drive)
        for lk in links:
            lk.mute = True
        try:
            for _ in range(max(0, k - 1)):
                self.rec.step()
                self.after_step()
        finally:
            for lk in links:
                lk.mute = False
        # the zenoh declarations (the active token, the snapshot and command queryables, the stats and claims
        # publishers, the NC's tokens: 7 calls, milliseconds on a loaded machine) come after the cycle's own step,
        # whose set-point is the first thing the drives need (after_step)
        self._serve_pending, self._serve_tries = True, 0

    def _serve(self) -> None:
        """Declare what the active NC of the pair declares (its token, the snapshot queryable, the NC's keys)."""
        if self._token is not None:
            self._token.undeclare()
        self._token = self._session.liveliness().declare_token(f"{self.keys}/active/{self.node}") \
            if self._session is not None else None
        if self._snap_q is None and self._session is not None:
            self._snap_q = self._session.declare_queryable(f"{self.keys}/snapshot", FifoChannel(16))

    def _finish_takeover(self) -> None:
        """After the takeover's first step (its set-point is out): the times, then the declarations. A declaration
        that fails (zenoh) is logged and tried again after the next cycle's step: the NC drives meanwhile."""
        t = time.monotonic()
        lost_at, srv = self._lost_at, self.srv
        if self._serve_tries == 0:
            self.takeover_s = t - lost_at if lost_at > 0 else 0.0
            self.takeover_cycles = int(round(self.takeover_s / self._dt)) if lost_at > 0 else 0
            self.detect_s = self._detected_at - lost_at if lost_at > 0 else 0.0
            self.work_s = t - self._detected_at
        self._serve_tries += 1
        try:
            self._serve()
            self._hand_over()
            srv.transport.serve()
            self._nc_tokens(False)  # (any left: another instance id than the transport's, which declared its own)
            self._view(False)  # (after the first set-point, like the other declarations)
        except Exception as exc:
            if self._serve_tries <= 3 or self._serve_tries % 1000 == 0:
                log.error("NC %s: took over, but its declarations failed (try %d; again next cycle): %s",
                          srv.config.name, self._serve_tries, exc)
            self._take_back()
            try:  # (what transport.serve() declared before it failed: all of it again next time)
                unserve = getattr(srv.transport, "unserve", None)
                if unserve is not None:
                    unserve()
            except Exception:
                pass
            return
        self._serve_pending = False
        self._next_status = 0.0  # (the ha status with the takeover's figures: the next cycle)
        self.serve_s = time.monotonic() - t
        log.warning("NC %s: took over at cycle %d (epoch %d, node %s; the active NC lost: %s): first set-point %.1f ms "
                    "after the last log (detection %.1f ms, then %.1f ms to the first step; %d cycles caught up; "
                    "declarations %.1f ms after it)", srv.config.name, self.core.cycle, self.epoch, self.node,
                    self._lost_why, self.takeover_s * 1e3, self.detect_s * 1e3, self.work_s * 1e3, self.catch_up,
                    self.serve_s * 1e3)

    def _become_standby(self, now: float, why: str) -> None:
        srv = self.srv
        log.warning("NC %s (node %s, epoch %d): %s: standby from now on, the drives are not driven by it",
                    srv.config.name, self.node, self.epoch, why)
        self.core.drive = ReplayDrive.of(self.real_drive)  # nothing goes to the drives any more
        self.rec.attach_drive(None)
        self.role = "standby"
        self.demotions += 1
        self._serve_pending = False  # (a takeover whose declarations had not been made yet)
        self._nc_tokens(False)  # (out of step until a snapshot: no NC token of its own; the transport's go below)
        for d in (self._snap_q, self._token):
            if d is not None:
                try:
                    d.undeclare()
                except Exception:
                    pass
        self._snap_q = self._token = None
        self._view(True)
        srv.became_standby()
        self.follower.waiting = True
        self.synced_once = False
        self._forget_frames()
        self._last_log = now
        self.detector.restart(now)  # (its last log as a standby may be minutes old: no gap of it)
        # (its detector saw no gap while it was active: its standby's published limit, fresh, is what the machine
        # showed; the first minute as the standby judges by it, not by a fresh history)
        fresh = [lim for lim, t in self._peer_limits.values() if now - t < PEER_STATUS_S]
        if fresh:
            self.detector.seed(now, max(fresh) / GAP_FACTOR)
        self._started = now
        self._ask_snapshot(now)

    def _refresh_limit(self, now: float) -> None:
        """(cycle thread: the detector's gaps and the peers' statuses are the cycle thread's) The published limit,
        for status(); the limit in force (it grows with the log gaps under load) goes to the drive hosts with the
        outputs."""
        self._limit = limit = self._limit_cycles(now)
        self.takeover_limit_ms = takeover_bound(limit, self._dt) * 1e3
        for lk in drive_links(self.real_drive):
            lk.takeover_limit_ms = self.takeover_limit_ms

    def status(self) -> dict[str, Any]:
        """The ha status (``nc/<nc>/ha/status/<node>``, the stats' ``ha``): read from the cycle thread and the I/O
        thread (stats): it only reads what the cycle thread computed."""
        f = self.follower
        limit = self._limit
        return {"node": self.node, "role": self.role, "epoch": self.epoch, "highest_epoch": self.highest,
                "in_step": self.role == "active" or (not f.waiting and self.synced_once),
                "cycle": int(self.core.cycle), "lag_cycles": self._lag(), "logs_in": self.logs_in,
                "logs_out": self.logs_out, "resyncs": f.resyncs, "diverged": f.diverged,
                "snapshots_served": self.snapshots_served,
                "snapshot_max_ms": round(self.snapshot_s * 1e3, 3), "takeovers": self.takeovers,
                "demotions": self.demotions,
                "takeover_ms": round(self.takeover_s * 1e3, 3), "takeover_cycles": self.takeover_cycles,
                "takeover_detect_ms": round(self.detect_s * 1e3, 3), "takeover_work_ms": round(self.work_s * 1e3, 3),
                "takeover_serve_ms": round(self.serve_s * 1e3, 3),
                "catch_up_cycles": self.catch_up, "frames_alive": self.frames_alive, "stale_logs": self.stale_logs,
                "unusable_logs": self.unusable_logs, "takeover_limit_cycles": limit,
                "takeover_limit_ms": round(self.takeover_limit_ms, 3),
                "peer_in_step": self.peer_in_step, "frames_fenced": self._fenced(),
                "software": FINGERPRINT[:12], "refused": self.refused, "time": time.time()}

    def _lag(self) -> int:
        """The replication lag [cycles]: the newest log's cycle less the core's, or (a standby) the newest frame's of
        the highest epoch less the core's when more (the logs late or cut while the frames come)."""
        lag = int(self.follower.lag)
        fe, fc = self._frame_epoch, self._frame_cycle  # (another thread's read: plain ints)
        if self.role == "standby" and self.highest and fe == self.highest:
            lag = max(lag, fc - int(self.core.cycle))
        return lag

    def _limit_cycles(self, now: float | None = None) -> int:
        """The published bound of a takeover after a freeze or link cut [cycles]: the standby's loss detector's
        limit (the active NC's: what its standby last published, at least ``takeover_cycles``)."""
        now = time.monotonic() if now is None else now
        # (a freeze of the active NC longer than its lease drops its token: a takeover then at the latest)
        lim = min(self.detector.limit(now) if self.role == "standby" else self.peer_limit(now), self._lease)
        return math.ceil(lim / self._dt - 1e-9)  # (0.2 / 0.001 is 200.00000000000003)

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
