"""CiA 402 process data over CANopen: a :class:`~..cia402.image.ProcessDataLink` on a python-canopen network.

:class:`CanopenLink` is the NMT master and SYNC producer of one CAN bus (python-can: ``interface``, ``channel``,
``bitrate``). At start, per node: NMT pre-operational, a check that the node is a CiA 402 device (0x1000), the
SDO configuration (the PDO mapping of :mod:`.pdo`, modes of operation 0x6060, interpolation time period 0x60C2
from the NC cycle, producer heartbeat time 0x1017), then NMT operational for all, and one SYNC whose TPDOs
every node must answer. Per NC cycle, :meth:`CanopenLink.exchange`:

1. reads the newest TPDO payloads the canopen notifier thread stored (never waits on the bus), with per node
   the age in SYNCs of its cyclic TPDOs and ``alive`` from the heartbeat consumer;
2. sends the RPDOs with this cycle's outputs (positions rounded to increments, modulo 2^32 as INT32: an endless
   axis wraps, and the actual position read back is unwrapped, so ActPos stays continuous), then one SYNC.

Ordering: the RPDOs of cycle k go out before cycle k's SYNC; the drives apply them at that SYNC (the start of
their cycle k+1: "the frames for cycle k+1 are sent in cycle k") and answer with TPDOs, which the NC uses in
cycle k+1. So the actual values lag the targets by one NC cycle, as on any SYNC-clocked fieldbus.

Age: the link counts its SYNCs; a TPDO arriving after SYNC s was sent is stamped s. In cycle k (s = k SYNCs
sent so far) a node whose cyclic TPDOs all answer the previous SYNC has age 0; each SYNC they missed adds 1.
Where the bus stamps frames with the wall clock (virtual, socketcan: checked at start), a TPDO the notifier
thread handles late is dated by its own timestamp (a frame sent before SYNC s answers an older one), so a
receive thread that runs behind shows as age, not as fresh data.

Decisions:

* Loss detection (``monitoring``): the heartbeat by default (the node produces 0x1017 = ``heartbeat_period``, the
  link consumes it: ``alive`` is False once no heartbeat came for ``heartbeat_timeout`` or the node reports an NMT
  state other than operational), or node guarding (``"node_guarding"``, for drives without a heartbeat producer:
  the link polls each node every ``heartbeat_period`` with a remote frame on 0x700 + id, the node answers with its
  NMT state; 0x1017 = 0, guard time 0x100C = the period, life time factor 0x100D = timeout / period, so the node
  can tell the master is gone; the same ``heartbeat_timeout`` and ``alive``). CiA 301 recommends the heartbeat (no
  remote frames, half the frames). The fast detection is the TPDO age (``max_age`` cycles in
  :class:`~..cia402.drive.Cia402Drive`).
* A node that comes back is set up again: after its boot-up message (it rebooted: its SDO configuration is
  gone), or when its heartbeat (guarding answer) reports a state other than operational (it rebooted unseen, or
  was sent elsewhere). A heartbeat back after ``heartbeat_timeout`` without one that says operational (a cut
  cable, a late notifier thread) is checked first: the node's heartbeat time (guard time) read over SDO, and the
  node set up again only if it is not what the link wrote (its configuration is gone). A supervisor thread of the
  link does this, never the cycle: NMT pre-operational, the start's SDO configuration, NMT operational; meanwhile
  the cycle sends the node nothing and keeps its last inputs (aging: invalid I/O data; and not alive: lost
  communication). The drive comes back in Switch on disabled; the axis keeps its error until MC_Reset, then
  MC_Power enables it again. A failed set-up is retried every second. Counted per node (``setups``, the stats'
  ``drive_link``).
* The cycle and the supervisor's re-setup share nothing canopen rewrites: the cycle sends its RPDOs itself
  (``Network.send_message`` with payloads it packs), reads the TPDO payloads the link's own subscriptions store
  (one reference per TPDO and node), and takes a node's COB-IDs and structs from one :class:`_Cyclic` object that
  a re-setup replaces whole (None meanwhile) -- no lock the cycle could wait on.
* A CAN transmit error in a cycle (bus off, full transmit queue on real hardware), or any other failure packing or
  sending one node's RPDOs, is counted
  (:attr:`CanopenLink.tx_errors`) and logged once; it never raises into the cycle: the other nodes and the SYNC
  are still sent (the ages grow instead).
* Close: NMT pre-operational for the nodes (their PDOs stop; a real drive sees the master go), then the
  network and the bus are shut down.

It may import: numpy, can, canopen, nc_server.drives.cia402, .pdo, .vbus.
"""
from __future__ import annotations

import logging
import math
import os
import struct
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import can
import canopen
import numpy as np
from canopen.pdo.base import PdoMap
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from ..cia402 import objects as obj
from ..cia402.objects import CMD_SHUTDOWN
from ..cia402.image import ProcessDataLink, RxImage, TxImage
from . import pdo
from .vbus import open_bus

log = logging.getLogger(__name__)

#: the EDS of the simulated drive, used for a node without an EDS of its own
SIM_EDS = os.path.join(os.path.dirname(__file__), "cia402_sim.eds")
NMT_OPERATIONAL = 5
_DEVICE_TYPE = 0x1000
_RING = 64
_HEARTBEAT_TIME = 0x1017
_GUARD_TIME = 0x100C
_LIFE_TIME_FACTOR = 0x100D
MONITORING = ("heartbeat", "node_guarding")
#: [s] between two tries of a node's set-up after it came back
SETUP_RETRY = 1.0


class CanopenStartError(RuntimeError):
    """The CAN bus cannot be opened, or a node does not answer or cannot be configured at start."""


@dataclass(frozen=True)
class NodeConfig:
    """One CiA 402 drive on the bus.

    Attributes:
        node_id: CANopen node id, 1..127.
        csv: cyclic synchronous velocity (0x6060 = 9) instead of position (8).
        eds: the drive's EDS file; None: the simulated drive's (``cia402_sim.eds``).
    """

    node_id: int
    csv: bool = False
    eds: str | None = None


@dataclass(frozen=True)
class BusConfig:
    """The CAN bus and the master's timing.

    Attributes:
        interface: python-can interface ("virtual", "socketcan", "pcan", ...).
        channel: python-can channel ("can0"; any name on the virtual bus).
        bitrate: [bit/s] (ignored by the virtual bus).
        sdo_timeout: [s] per SDO response at start (canopen retries once).
        heartbeat_period: [s] producer heartbeat time written to each node (0x1017, whole ms); with node guarding
            the guard time (0x100C) and the master's polling period.
        heartbeat_timeout: [s] consumer time: no heartbeat (guarding answer) for this long = the node is lost.
        start_timeout: [s] for the heartbeat after NMT operational and the first TPDOs.
        monitoring: "heartbeat" or "node_guarding" (module docstring).
    """

    interface: str = "virtual"
    channel: str = "can0"
    bitrate: int = 1_000_000
    sdo_timeout: float = 0.3
    heartbeat_period: float = 0.1
    heartbeat_timeout: float = 0.35
    start_timeout: float = 2.0
    monitoring: str = "heartbeat"


def interpolation_period(cycle_time: float) -> tuple[int, int]:
    """0x60C2 (sub 1 value UINT8, sub 2 index INT8) with value * 10**index == cycle_time [s] exactly.

    Raises:
        ValueError: the cycle has no such representation (value <= 255, index -6..0).
    """
    for index in range(0, -7, -1):
        value = cycle_time / 10.0 ** index
        if abs(value - round(value)) < 1e-6 and 1 <= round(value) <= 255:
            return int(round(value)), index
    raise ValueError(f"cycle time {cycle_time} s cannot be written as 0x60C2 (value 1..255 x 10^-6..0 s)")


@dataclass(frozen=True)
class _Cyclic:
    """All the cycle uses of one node's set-up: its RPDO COB-IDs and the packing structs. Built after each SDO
    configuration and replaced whole (``_Node.cyclic``: one reference, read once per node and cycle), so the cycle
    never sees half of an old and half of a new set-up and never touches canopen's PdoMap objects, which the
    supervisor's re-setup rewrites (clear, add_variable: ``PdoMap.data`` replaced, shorter for a moment).

    Attributes:
        sent_rpdo2: ``[payload]`` of the RPDO2 last sent (b"": none since this set-up; the cycle's alone).
    """

    rpdo1_cob: int
    rpdo2_cob: int
    s_rpdo1: struct.Struct
    s_rpdo2: struct.Struct
    s_tpdo: Mapping[int, struct.Struct]
    sent_rpdo2: list[bytes] = field(default_factory=lambda: [b""])


class _Node:
    """The master's view of one node: its canopen RemoteNode and PDO maps (the SDO configuration's, the supervisor
    thread's) and the cycle's :class:`_Cyclic` (None while it is being set up: the cycle leaves it alone)."""

    def __init__(self, cfg: NodeConfig, remote: canopen.RemoteNode) -> None:
        self.cfg = cfg
        self.remote = remote
        self.rpdo1: PdoMap = remote.rpdo[1]
        self.rpdo2: PdoMap = remote.rpdo[2]
        self.tpdo: dict[int, PdoMap] = {k: remote.tpdo[k] for k in pdo.TPDO_LAYOUT}
        self.cyclic: _Cyclic | None = None
        self.cyclic = self.make_cyclic()  # (checks the EDS has the mapped objects at start)

    def make_cyclic(self) -> _Cyclic:
        r, nid = self.remote, self.cfg.node_id
        return _Cyclic(rpdo1_cob=0x200 + nid, rpdo2_cob=0x300 + nid, s_rpdo1=_struct(r, pdo.RPDO1),
                       s_rpdo2=_struct(r, pdo.rpdo_layout(self.cfg.csv)[2]),
                       s_tpdo={k: _struct(r, m) for k, m in pdo.TPDO_LAYOUT.items()})


def _struct(remote: canopen.RemoteNode, entries: Sequence[pdo.Entry]) -> struct.Struct:
    types = []
    for index, bits in entries:
        if index not in remote.object_dictionary:
            raise CanopenStartError(f"node {remote.id}: its EDS has no object 0x{index:04X}, which the NC maps")
        var = remote.object_dictionary[index]
        if not isinstance(var, canopen.objectdictionary.ODVariable) or len(var) != bits:
            raise CanopenStartError(f"node {remote.id}: object 0x{index:04X} in its EDS is not a {bits}-bit "
                                    f"variable")
        types.append(var.data_type)
    return pdo.struct_for(types)


class CanopenLink(ProcessDataLink):
    """The process data of ``len(nodes)`` CiA 402 drives on one CAN bus (column i = ``nodes[i]``).

    Args:
        nodes: the drives, in the NC's axis order (node ids unique).
        cycle_time: the NC cycle [s] (0x60C2).
        bus: the bus and the master's timing.
        can_bus: an open python-can bus to use instead of opening one from ``bus`` (the link shuts it down).

    Raises:
        CanopenStartError: the bus cannot be opened; a node does not answer its SDOs (within
            ``sdo_timeout`` per request), is no CiA 402 device, refuses its configuration, sends no
            operational heartbeat or no TPDOs (within ``start_timeout``). The message names the node.
        ValueError: the cycle cannot be written as 0x60C2.
    """

    def __init__(self, nodes: Sequence[NodeConfig], cycle_time: float, bus: BusConfig = BusConfig(),
                 can_bus: can.BusABC | None = None) -> None:
        ids = [c.node_id for c in nodes]
        if len(set(ids)) != len(ids):
            raise ValueError(f"duplicate node ids in {ids}")
        self.n = len(nodes)
        self.cycle_time = float(cycle_time)
        self.bus_config = bus
        self.period = interpolation_period(cycle_time)
        self.tx_errors = 0
        self.syncs = 0
        #: a list to collect SYNC -> TPDO arrival delays [s] in (the bench sets it; None: not collected)
        self.timing: list[float] | None = None
        self._sync_t = 0.0
        #: wall-clock send time of the last SYNCs (SYNC s at [s % _RING]), to date late-handled TPDOs
        self._sync_wall = np.zeros(_RING)
        #: the NC cycle (RxImage.cycle) of the RPDOs sent before SYNC s, at [s % _RING]: what a TPDO stamped s answers
        self._sync_cycle = np.zeros(_RING, dtype=np.int64)
        #: the bus stamps frames with time.time() (virtual, socketcan): checked on the first TPDOs at start
        self._wall_clock_stamps = False
        #: per node: the SYNC count when each cyclic TPDO last arrived (-1: never)
        self._stamp = {k: np.full(self.n, -1, dtype=np.int64) for k in pdo.TPDO_LAYOUT}
        #: per TPDO and node the payload last received (the notifier thread replaces the reference, the cycle reads it)
        self._tpdo_data: dict[int, list[bytes]] = {k: [b""] * self.n for k in pdo.TPDO_LAYOUT}
        self._tpdo1_ts: float | None = None  # the bus's timestamp of the last TPDO1 (the wall clock check at start)
        #: per node: cycles whose inputs did not answer the last SYNC (late or missing TPDOs), and SYNCs whose TPDOs
        #: never came (the newest answered SYNC jumped over them); the stats' ``drive_link``
        self.tpdo_late = np.zeros(self.n, dtype=np.int64)
        self.tpdo_missed = np.zeros(self.n, dtype=np.int64)
        self._answered = np.zeros(self.n, dtype=np.int64)  # the newest SYNC answered by all cyclic TPDOs, as used
        #: the age and rx_cycle of the inputs used last (a node being set up keeps its inputs: they age from these)
        self._last_age = np.zeros(self.n, dtype=np.int64)
        self._last_rx_cycle = np.zeros(self.n, dtype=np.int64)
        self._pos = np.zeros(self.n, dtype=np.int64)  # the unwrapped actual positions [inc]
        self._pos_seen = np.zeros(self.n, dtype=bool)
        self._hb_time = np.full(self.n, -math.inf)
        self._hb_state = np.zeros(self.n, dtype=np.int64)
        if bus.monitoring not in MONITORING:
            raise ValueError(f"monitoring must be one of {', '.join(MONITORING)}, got {bus.monitoring!r}")
        self._guarding = bus.monitoring == "node_guarding"
        #: per node: set-ups after it came back (a reboot, a heartbeat back after its loss)
        self.setups = np.zeros(self.n, dtype=np.int64)
        self._todo = [""] * self.n  # per node: "setup", "check" (its configuration, after a silence) or ""
        self._setup_why = [""] * self.n
        self._grace_until = [0.0] * self.n  # after a set-up: heartbeats sent before its NMT start are not judged
        self._configuring = [False] * self.n  # the supervisor sets the node up: the cycle leaves it alone
        self._any_configuring = False
        self._running = False  # started: a node coming back is set up again
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._supervisor: threading.Thread | None = None
        #: the last TPDO payloads read, per TPDO (rows: the mapped objects), kept for a node being set up
        self._t = {k: np.zeros((len(m), self.n), dtype=np.int64) for k, m in pdo.TPDO_LAYOUT.items()}
        #: the last EMCY code per node (0: none or reset)
        self.emcy_code = np.zeros(self.n, dtype=np.uint16)
        self._closed = False
        self._lock = threading.Lock()
        self.network = canopen.Network()
        self.network.NOTIFIER_CYCLE = 0.1  # the notifier's receive timeout: close() joins within it
        try:
            if can_bus is None:
                can_bus = open_bus(bus.interface, bus.channel, bus.bitrate)
        except Exception as e:  # python-can raises many kinds (CanInitializationError, OSError, ImportError)
            raise CanopenStartError(f"cannot open the CAN bus (interface {bus.interface!r}, channel "
                                    f"{bus.channel!r}): {e}") from e
        self.network.bus = can_bus
        try:
            self.network.connect()
            self.nodes = [self._add(c) for c in nodes]
            self._start()
        except BaseException:
            self.close()
            raise

    # -- start -------------------------------------------------------------------------------------------

    def _add(self, cfg: NodeConfig) -> _Node:
        if not 1 <= cfg.node_id <= 127:
            raise ValueError(f"node id {cfg.node_id} outside 1..127")
        try:
            remote = canopen.RemoteNode(cfg.node_id, cfg.eds or SIM_EDS)
        except Exception as e:
            raise CanopenStartError(f"node {cfg.node_id}: cannot read its EDS {cfg.eds!r}: {e}") from e
        remote.sdo.RESPONSE_TIMEOUT = self.bus_config.sdo_timeout
        self.network.add_node(remote)
        return _Node(cfg, remote)

    def _start(self) -> None:
        b = self.bus_config
        where = f"on {b.interface} channel {b.channel!r}"
        for node in self.nodes:
            node.remote.nmt.state = "PRE-OPERATIONAL"
            try:
                self._configure(node)
            except SdoCommunicationError as e:
                raise CanopenStartError(f"node {node.cfg.node_id} does not answer {where} (no SDO response "
                                        f"within {b.sdo_timeout} s: {e})") from e
            except SdoAbortedError as e:
                raise CanopenStartError(f"node {node.cfg.node_id} refused its configuration {where}: {e}") from e
        for j, node in enumerate(self.nodes):
            node.remote.nmt.add_heartbeat_callback(self._on_heartbeat(j))
            node.remote.emcy.add_callback(self._on_emcy(j))
            for k in node.tpdo:  # (the link's own subscriptions: the frames' payloads, not canopen's PdoMap.data)
                self.network.subscribe(0x180 + 0x100 * (k - 1) + node.cfg.node_id, self._on_tpdo(k, j))
            node.remote.nmt.state = "OPERATIONAL"
            if self._guarding:
                node.remote.nmt.start_node_guarding(self.bus_config.heartbeat_period)
        self._wait(lambda: self._hb_state == NMT_OPERATIONAL, "no operational heartbeat", where)
        self._sync_wall[0] = time.time()
        self.syncs = 1
        self.network.sync.transmit()
        self._wait(lambda: np.minimum(self._stamp[1], self._stamp[2]) >= 1, "no TPDO answered the first SYNC",
                   where)
        ts = self._tpdo1_ts
        self._wall_clock_stamps = ts is not None and abs(ts - time.time()) < 1.0
        self._running = True
        self._supervisor = threading.Thread(target=self._supervise, name="canopen-nmt", daemon=True)
        self._supervisor.start()

    def _configure(self, node: _Node) -> None:
        r, nid = node.remote, node.cfg.node_id
        device_type = int(r.sdo[_DEVICE_TYPE].raw)
        if device_type & 0xFFFF != 402:
            raise CanopenStartError(f"node {nid} is no CiA 402 drive (device type 0x{device_type:08X})")
        for k, entries in pdo.rpdo_layout(node.cfg.csv).items():
            _map(r.rpdo[k], 0x200 + 0x100 * (k - 1) + nid, entries, pdo.SYNC_EVERY)
        for k, entries in pdo.TPDO_LAYOUT.items():
            _map(r.tpdo[k], 0x180 + 0x100 * (k - 1) + nid, entries, pdo.TPDO_TRANS[k])
        for maps in (r.rpdo, r.tpdo):  # the node's other PDOs off
            for k in maps:
                if k not in (pdo.TPDO_LAYOUT if maps is r.tpdo else (1, 2)):
                    m = maps[k]
                    m.read()
                    if m.enabled:
                        m.enabled = False
                        m.save()
        r.sdo[obj.MODES_OF_OPERATION].raw = int(obj.Mode.CSV if node.cfg.csv else obj.Mode.CSP)
        value, index = self.period
        r.sdo[obj.INTERPOLATION_TIME_PERIOD][1].raw = value
        r.sdo[obj.INTERPOLATION_TIME_PERIOD][2].raw = index
        period_ms = max(1, round(self.bus_config.heartbeat_period * 1000))
        if self._guarding:
            if _GUARD_TIME not in r.object_dictionary or _LIFE_TIME_FACTOR not in r.object_dictionary:
                raise CanopenStartError(f"node {nid}: its EDS has no guard time (0x100C) or life time factor "
                                        f"(0x100D): node guarding needs them")
            r.sdo[_HEARTBEAT_TIME].raw = 0
            r.sdo[_GUARD_TIME].raw = period_ms
            r.sdo[_LIFE_TIME_FACTOR].raw = min(255, math.ceil(self.bus_config.heartbeat_timeout
                                                              / self.bus_config.heartbeat_period))
        else:
            r.sdo[_HEARTBEAT_TIME].raw = period_ms

    def _wait(self, done: Any, what: str, where: str) -> None:
        deadline = time.monotonic() + self.bus_config.start_timeout
        while not np.all(done()):
            if time.monotonic() > deadline:
                missing = [n.cfg.node_id for n, ok in zip(self.nodes, done()) if not ok]
                raise CanopenStartError(f"node{'s' if len(missing) > 1 else ''} "
                                        f"{', '.join(map(str, missing))}: {what} within "
                                        f"{self.bus_config.start_timeout} s {where}")
            time.sleep(0.002)

    # -- notifier thread callbacks (they only store) -----------------------------------------------------

    def _on_tpdo(self, k: int, j: int) -> Any:
        stamp, data_k = self._stamp[k], self._tpdo_data[k]

        def cb(can_id: int, data: bytearray, ts: float | None) -> None:
            data_k[j] = bytes(data)  # (before the stamp: the cycle reads the stamp first, then the payload)
            if k == 1:
                self._tpdo1_ts = ts
            s = self.syncs
            if self._wall_clock_stamps and ts is not None:
                # a frame sent before SYNC s (we got to it late: this thread ran behind) answers an older SYNC
                wall = self._sync_wall
                while s > 1 and self.syncs - s < _RING - 1 and ts < wall[(s - 1) % _RING]:
                    s -= 1
            stamp[j] = s
            if self.timing is not None:
                self.timing.append(time.perf_counter() - self._sync_t)
        return cb

    def _on_heartbeat(self, j: int) -> Any:
        def cb(state: int) -> None:
            now = time.monotonic()
            if self._running and not self._stop.is_set() and not self._configuring[j] and self._todo[j] != "setup":
                if state == 0:
                    self._todo[j], self._setup_why[j] = "setup", "its boot-up message"
                elif state != NMT_OPERATIONAL and now > self._grace_until[j]:
                    self._todo[j], self._setup_why[j] = "setup", f"its heartbeat reports NMT state {state}"
                elif now - self._hb_time[j] > self.bus_config.heartbeat_timeout and not self._todo[j]:
                    self._todo[j], self._setup_why[j] = "check", "its heartbeat came back"
                if self._todo[j]:
                    self._wake.set()
            self._hb_time[j] = now
            self._hb_state[j] = state
        return cb

    # -- a node that came back (supervisor thread) --------------------------------------------------------

    def _supervise(self) -> None:
        while not self._stop.is_set():
            self._wake.wait(0.5)
            self._wake.clear()
            for j in range(self.n):
                if self._todo[j] and not self._stop.is_set():
                    if not self._setup_again(j):
                        self._stop.wait(SETUP_RETRY)
                        self._wake.set()

    def _monitor_time(self) -> tuple[int, int]:
        """The object that tells whether a node still has the link's configuration, and the value the link wrote."""
        ms = max(1, round(self.bus_config.heartbeat_period * 1000))
        return (_GUARD_TIME, ms) if self._guarding else (_HEARTBEAT_TIME, ms)

    def _setup_again(self, j: int) -> bool:
        """Node ``j`` came back: check it (``check``) or set it up as at start (NMT pre-operational, SDO
        configuration, NMT operational); False: failed (tried again)."""
        node = self.nodes[j]
        nid = node.cfg.node_id
        if self._todo[j] == "check":
            index, value = self._monitor_time()
            try:
                kept = int(node.remote.sdo[index].raw) == value
            except Exception as e:  # no SDO answer (gone again): the next heartbeat tells
                log.warning("node %d: %s, its configuration not readable (%s)", nid, self._setup_why[j], e)
                self._todo[j] = ""
                return True
            if kept:
                log.info("node %d: %s, its configuration kept", nid, self._setup_why[j])
                self._todo[j] = ""
                return True
            self._todo[j], self._setup_why[j] = "setup", f"{self._setup_why[j]} without its configuration"
        self._configuring[j] = True
        self._any_configuring = True
        node.cyclic = None  # the cycle leaves the node alone from its next read (one that read it goes on: harmless)
        try:
            log.warning("node %d: %s: setting it up again (SDO configuration, NMT start)", nid, self._setup_why[j])
            node.remote.nmt.state = "PRE-OPERATIONAL"
            self._configure(node)
            # the new set-up for the cycle, whole (its RPDO2 not yet sent: the node lost what RPDO2 carried)
            node.cyclic = node.make_cyclic()
            self._grace_until[j] = time.monotonic() + self.bus_config.heartbeat_timeout
            node.remote.nmt.state = "OPERATIONAL"
            self.setups[j] += 1
            self._todo[j] = ""
            log.warning("node %d: operational again (set-up %d); the axis needs MC_Reset", nid, int(self.setups[j]))
            return True
        except Exception as e:  # SDO timeout or abort, a bus error: tried again
            log.warning("node %d: its set-up failed (%s: %s); again in %g s", nid, type(e).__name__, e, SETUP_RETRY)
            return False
        finally:
            self._configuring[j] = False
            self._any_configuring = any(self._configuring)

    def _on_emcy(self, j: int) -> Any:
        def cb(err: Any) -> None:
            self.emcy_code[j] = err.code
            if err.code:
                log.warning("node %d: EMCY 0x%04X", self.nodes[j].cfg.node_id, err.code)
        return cb

    # -- the cycle ---------------------------------------------------------------------------------------

    def exchange(self, rx: RxImage) -> TxImage:
        """Return the newest inputs, then send this cycle's RPDOs and one SYNC (never waits on the bus)."""
        tx = self._inputs()
        self._outputs(rx)
        return tx

    def peek(self) -> TxImage:
        """The newest inputs the notifier thread stored, no RPDO or SYNC sent (the link's figures, tpdo_late and
        tpdo_missed, and its position unwrapping are updated as by a cycle's read)."""
        return self._inputs()

    def _inputs(self) -> TxImage:
        t1, t2, t3, t4 = self._t[1], self._t[2], self._t[3], self._t[4]  # (written in place: the TxImage gets copies)
        # the stamps before the payloads: a TPDO1 arriving in between makes the data newer than the stamp, never older
        # (a statusword is never taken to answer newer outputs than it does)
        s1 = self._stamp[1].copy()
        s3, s4 = self._stamp[3].copy(), self._stamp[4].copy()
        d1, d2, d3, d4 = (self._tpdo_data[k] for k in (1, 2, 3, 4))
        held: list[int] = []
        for j, node in enumerate(self.nodes):
            cyc = node.cyclic
            if cyc is None:  # being set up (or its set-up failed): its last inputs stay, and age
                held.append(j)
                continue
            # TPDO3 (0x60B9: a latch stored) and TPDO4 (0x60BC/0x60BD: its positions) go out after the same SYNC,
            # TPDO3 first (on change only, both): a TPDO3 newer than TPDO4 and than the next SYNC's TPDO1 may be a
            # latch whose position has not arrived yet; its previous payload stays a cycle longer (never a latch
            # with the position of the one before)
            hold3 = s3[j] > s4[j] and s1[j] <= s3[j]
            for k, out, d in ((1, t1, d1), (2, t2, d2), (3, t3, d3), (4, t4, d4)):
                if k == 3 and hold3:
                    continue
                data = d[j]
                s = cyc.s_tpdo[k]
                out[:, j] = s.unpack_from(data) if len(data) >= s.size else 0
        k = self.syncs
        answered = np.minimum(self._stamp[1], self._stamp[2])
        if held:  # (the notifier may go on stamping its frames: not what the payloads kept here answer)
            answered[held] = self._answered[held]
        age = k - answered
        age[answered < 0] = k + 1
        if held:
            age[held] = self._last_age[held] + 1
        if np.count_nonzero(age):  # (figures only; the steady state skips them)
            self.tpdo_late = self.tpdo_late + (age > 0)
        jump = answered - self._answered
        if np.count_nonzero(jump > 1):
            self.tpdo_missed = self.tpdo_missed + np.where(jump > 1, jump - 1, 0)
        self._answered = np.maximum(answered, self._answered)
        alive = ((time.monotonic() - self._hb_time) <= self.bus_config.heartbeat_timeout) & \
            (self._hb_state == NMT_OPERATIONAL)
        # INT32 positions wrap on an endless axis: continue from the last reading (the first one is taken as is)
        pos = self._pos = np.where(self._pos_seen, pdo.unwrap32(t1[1], self._pos), t1[1])
        self._pos_seen |= t1[0] != 0  # (a statusword of 0: nothing received yet)
        probe = pdo.unwrap32(t3[1], pos)
        # the NC cycle the statusword (TPDO1) answers: the RPDOs sent before the SYNC it answered (0: unknown)
        rx_cycle = np.where((s1 >= 1) & (k - s1 < _RING - 1), self._sync_cycle[s1 % _RING], 0)
        if held:
            rx_cycle[held] = self._last_rx_cycle[held]
        self._last_age, self._last_rx_cycle = age, rx_cycle
        return TxImage(statusword=t1[0].astype(np.uint16), mode_display=t2[2].astype(np.int8),
                       position_actual=pos.astype(np.float64), velocity_actual=t2[0].astype(np.float64),
                       torque_actual=t2[1].astype(np.float64), error_code=t1[2].astype(np.uint16),
                       probe_status=t3[0].astype(np.uint16), probe_position=probe.astype(np.float64),
                       probe2_pos=pdo.unwrap32(t4[0], pos).astype(np.float64),
                       probe2_neg=pdo.unwrap32(t4[1], pos).astype(np.float64), age=age, alive=alive, rx_cycle=rx_cycle)

    def _outputs(self, rx: RxImage) -> None:
        pos = pdo.wrap32(rx.target_position)  # (modulo 2^32: an endless axis goes on; the drive unwraps)
        velo = np.clip(np.rint(np.nan_to_num(rx.target_velocity)), pdo.INT32_MIN, pdo.INT32_MAX)
        cw, p, mode = rx.controlword.tolist(), pos.tolist(), rx.mode.tolist()
        self._last_out = (p, mode)
        v, probe = velo.astype(np.int64).tolist(), rx.probe_function.tolist()
        send = self.network.send_message
        for j, node in enumerate(self.nodes):
            cyc = node.cyclic  # (one reference: a re-setup replaces it whole)
            if cyc is None:  # being set up
                continue
            # per node and any exception (a CAN error hits one frame): the cycle goes on with the other nodes and
            # the SYNC (the ages tell)
            try:
                send(cyc.rpdo1_cob, cyc.s_rpdo1.pack(cw[j], p[j], mode[j]))
                payload = cyc.s_rpdo2.pack(v[j], probe[j]) if node.cfg.csv else cyc.s_rpdo2.pack(probe[j])
                if payload != cyc.sent_rpdo2[0]:
                    send(cyc.rpdo2_cob, payload)
                    cyc.sent_rpdo2[0] = payload
            except Exception as e:
                self._tx_error(e)
        try:
            self._sync_wall[self.syncs % _RING] = time.time()
            self.syncs += 1  # before the SYNC: a TPDO answering it is stamped with the new count
            self._sync_cycle[self.syncs % _RING] = rx.cycle
            self._sync_t = time.perf_counter()
            self.network.sync.transmit()
        except Exception as e:
            self._tx_error(e)

    def _tx_error(self, e: Exception) -> None:
        self.tx_errors += 1
        if self.tx_errors == 1:
            log.error("transmit error (counted in tx_errors, logged once): %s: %s", type(e).__name__, e)

    def wait_answered(self, timeout: float, rows: Sequence[int] | None = None) -> bool:
        """Wait until every node's (``rows``: these axes' nodes') cyclic TPDOs answered the last SYNC (True), or
        ``timeout`` [s] (False).

        For tests and tools that step the NC faster or slower than real time; the NC cycle never waits."""
        deadline = time.monotonic() + timeout
        sel = slice(None) if rows is None else np.asarray(rows, dtype=np.intp)
        while np.any(np.minimum(self._stamp[1][sel], self._stamp[2][sel]) < self.syncs):
            if time.monotonic() > deadline:
                return False
            time.sleep(0.0001)
        return True

    def figures(self) -> list[dict[str, Any]]:
        """Per node for the NC's stats ``drive_link``: ``node_id``, ``monitoring``, ``nmt`` (the NMT state its last
        heartbeat / guarding answer reported; None: none yet), ``alive``, ``heartbeat_age_ms`` (since it), the
        counters ``tpdo_late`` (cycles whose inputs were older than the last SYNC), ``tpdo_missed`` (SYNCs it never
        answered), ``setups`` (set up again after it came back), the bus's ``tx_errors`` and ``emcy``, the error code
        of the node's last EMCY (0: none, or its EMCY reset)."""
        from canopen.nmt import NMT_STATES

        now = time.monotonic()
        hb_t, hb_s = self._hb_time.copy(), self._hb_state.copy()
        late, missed, setups = self.tpdo_late.tolist(), self.tpdo_missed.tolist(), self.setups.tolist()
        emcy = self.emcy_code.tolist()
        timeout = self.bus_config.heartbeat_timeout
        out: list[dict[str, Any]] = []
        for j, node in enumerate(self.nodes):
            seen = math.isfinite(hb_t[j])
            age = now - hb_t[j]
            out.append({"link": "canopen", "node_id": node.cfg.node_id, "monitoring": self.bus_config.monitoring,
                        "nmt": NMT_STATES.get(int(hb_s[j]), str(int(hb_s[j]))) if seen else None,
                        "alive": bool(seen and age <= timeout and hb_s[j] == NMT_OPERATIONAL),
                        "heartbeat_age_ms": round(age * 1e3, 1) if seen else None,
                        "tpdo_late": int(late[j]), "tpdo_missed": int(missed[j]), "setups": int(setups[j]),
                        "tx_errors": int(self.tx_errors), "emcy": int(emcy[j])})
        return out

    def close(self) -> None:
        with self._lock:
            if self._closed:
                return
            self._closed = True
        self._stop.set()
        self._wake.set()
        if self._supervisor is not None:
            self._supervisor.join(5.0)
        for node in getattr(self, "nodes", []):
            node.remote.nmt.stop_node_guarding()
        self._shutdown_drives()
        for node in getattr(self, "nodes", []):
            try:
                node.remote.nmt.state = "PRE-OPERATIONAL"
            except Exception:  # the bus may be gone already
                pass
        try:
            self.network.disconnect()
        except Exception as e:
            log.warning("closing the CAN network: %s", e)


    def _shutdown_drives(self) -> None:
        """Before NMT leaves operational: one last RPDO with Shutdown (0x0006) at the last target, and its SYNC,
        so a drive still in Operation enabled is switched off as commanded rather than reacting to a
        communication abort (0x6007)."""
        p_mode = getattr(self, "_last_out", None)
        nodes = getattr(self, "nodes", [])
        if p_mode is None or not nodes:
            return
        p, mode = p_mode
        try:
            for j, node in enumerate(nodes):
                cyc = node.cyclic
                if cyc is not None:
                    self.network.send_message(cyc.rpdo1_cob, cyc.s_rpdo1.pack(CMD_SHUTDOWN, p[j], mode[j]))
            self.network.sync.transmit()
        except Exception as e:  # the bus may be gone already
            log.warning("CAN: the closing Shutdown could not be sent: %s", e)


def _map(m: PdoMap, cob_id: int, entries: Sequence[pdo.Entry], trans_type: int) -> None:
    """Write one PDO's mapping and communication parameters over SDO (canopen's PdoMap.save)."""
    m.clear()
    for index, bits in entries:
        m.add_variable(index, 0, bits)
    m.cob_id = cob_id
    m.trans_type = trans_type
    m.enabled = True
    m.save()
