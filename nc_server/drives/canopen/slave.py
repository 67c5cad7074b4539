"""Simulated CiA 402 slaves: python-canopen LocalNodes on a python-can virtual bus, one per drive.

:class:`SimulatedSlaves` puts ``len(node_ids)`` LocalNodes (object dictionary from an EDS: the shipped
``cia402_sim.eds`` or one per node) on their own bus instance of a virtual channel (:class:`.vbus.VirtualBus`); the NC's
:class:`~.link.CanopenLink` opens another instance of the same channel. Each node is a row of one
:class:`~..cia402.device.Cia402Device` (the simulated drives: state machine, CSP/CSV, quick stop, the
mechanical model), stepped once per SYNC for all rows:

* the master configures the nodes over SDO (stored in each LocalNode's data store); on NMT operational a
  node reads its PDO mapping back from its own dictionary (as a real drive does), so the slaves follow
  whatever mapping the master wrote;
* on SYNC (in the slave network's notifier thread): the RPDOs received since the last SYNC are applied
  (synchronous RPDOs), the device steps one cycle, each operational node sends its synchronous TPDOs
  (type 1..240: every n-th SYNC; type 0: only when the payload changed); a changed 0x603F sends an EMCY;
* SDO reads of the actual values (0x6041, 0x6064, 0x606C, 0x6077, 0x603F, 0x6061, 0x60B9, 0x60BA, 0x60BC, 0x60BD) answer
  the device's values of the last SYNC; an SDO write of 0x6060 sets the mode;
* heartbeat producer: canopen's NmtSlave (0x1017, started when the master writes it); node guarding: a remote
  frame on 0x700 + id is answered with the NMT state and the toggle bit (python-canopen's NmtSlave does not; a
  listener of the slave network's notifier does). Life guarding (0x100C x 0x100D without a guarding request) is
  not simulated: the drive does not react to a master that stops guarding.

Test hooks: :meth:`SimulatedSlaves.silence` (a node stops answering: no PDOs, no heartbeat or guarding answer, no
SDO, no NMT), :meth:`SimulatedSlaves.revive`, :meth:`SimulatedSlaves.reboot` (a power cycle: the master's
configuration gone, a boot-up message), :meth:`SimulatedSlaves.inject_fault`, :meth:`SimulatedSlaves.stalled`.

Decisions: the slaves are clocked by the SYNC (their time stands while no SYNC comes); the device is stepped
for every row, also for a silenced or non-operational node (the drive runs on; only its communication is
gone). A SYNC older than one cycle when the slaves' notifier thread gets to it, with the master's next SYNC
already waiting behind it (the thread ran behind: the GIL, a loaded machine), is dropped: neither stepped nor
answered (the NC counts the missing TPDOs: their age), so the simulation catches up at once instead of running
ever further behind (stepping the devices for the dropped SYNCs kept a starved thread from ever catching up).
python-can's virtual bus works inside one process only, so the slaves run in the NC's process
(``simulate_slaves = true``) or in a test process, and share the GIL with the NC cycle (bench/canopen_cycle.py
measures it). Their notifier thread (like the link's) runs at normal priority: on a loaded machine it may be
scheduled tens of ms late behind a SCHED_FIFO NC cycle and the other processes (the NC sees the ages); raising
it to SCHED_FIFO next to the cycle thread was tried and made the GIL hand-over stall (priority inversion).

It may import: numpy, can, canopen, nc_server.core.params, nc_server.drives.cia402, .link, .pdo, .vbus.
"""
from __future__ import annotations

import logging
import threading
import time
from contextlib import contextmanager
from typing import Any, Iterator, Sequence

import can
import canopen
import numpy as np
from canopen.pdo.base import PdoMap

from ...core.params import AxisParams
from ..cia402 import objects as obj
from ..cia402.image import RxImage, TxImage
from . import pdo
from .link import SIM_EDS
from .vbus import VirtualBus

log = logging.getLogger(__name__)

#: RPDO objects -> RxImage field
_RX_FIELDS = {obj.CONTROLWORD: "controlword", obj.TARGET_POSITION: "target_position",
              obj.MODES_OF_OPERATION: "mode", obj.TARGET_VELOCITY: "target_velocity",
              obj.TOUCH_PROBE_FUNCTION: "probe_function"}
#: TxImage field <- object (TPDO mapping and SDO reads)
_WRAPPED = frozenset({"position_actual", "probe_position", "probe2_pos", "probe2_neg"})
_TX_FIELDS = {obj.STATUSWORD: "statusword", obj.POSITION_ACTUAL: "position_actual",
              obj.VELOCITY_ACTUAL: "velocity_actual", obj.TORQUE_ACTUAL: "torque_actual",
              obj.ERROR_CODE: "error_code", obj.MODES_OF_OPERATION_DISPLAY: "mode_display",
              obj.TOUCH_PROBE_STATUS: "probe_status", obj.TOUCH_PROBE_POS1_POS: "probe_position",
              obj.TOUCH_PROBE_POS2_POS: "probe2_pos", obj.TOUCH_PROBE_POS2_NEG: "probe2_neg"}
_SYNC, _NMT, _NMT_ERROR = 0x80, 0x000, 0x700
_RANGES = {"b": (-(1 << 7), (1 << 7) - 1), "B": (0, (1 << 8) - 1), "h": (-(1 << 15), (1 << 15) - 1),
           "H": (0, (1 << 16) - 1), "i": (-(1 << 31), (1 << 31) - 1), "I": (0, (1 << 32) - 1)}


def _read(node: canopen.LocalNode, index: int) -> int:
    """A VAR object of a local node's dictionary (its data store, else the EDS default)."""
    var = node.object_dictionary[index]
    assert isinstance(var, canopen.objectdictionary.ODVariable)
    return int(var.decode_raw(node.get_data(index, 0)))


class _Rpdo:
    def __init__(self, m: PdoMap) -> None:
        self.map = m
        self.struct = pdo.struct_for([v.od.data_type for v in m.map])
        self.fields = [_RX_FIELDS.get(v.index) for v in m.map]


class _Tpdo:
    def __init__(self, m: PdoMap) -> None:
        self.map = m
        self.struct = pdo.struct_for([v.od.data_type for v in m.map])
        self.fields = [_TX_FIELDS.get(v.index) for v in m.map]
        fmt = self.struct.format.lstrip("<")
        self.ranges = [_RANGES.get(c, (-(1 << 63), (1 << 63) - 1)) for c in fmt]
        self.every = int(m.trans_type or 0)  # 0: on change
        self.last = b""


class _GuardingListener(can.Listener):
    """Node guarding requests (remote frames, which canopen's own listener drops) to :meth:`SimulatedSlaves._guard`."""

    def __init__(self, slaves: SimulatedSlaves) -> None:
        self.slaves = slaves

    def on_message_received(self, msg: can.Message) -> None:
        if msg.is_remote_frame and _NMT_ERROR < msg.arbitration_id <= _NMT_ERROR + 127:
            self.slaves._guard(msg.arbitration_id - _NMT_ERROR)


class SimulatedSlaves:
    """Simulated CiA 402 drives on a virtual CAN channel, one LocalNode per drive.

    Args:
        node_ids: the node ids (row i of the device = ``node_ids[i]``).
        params: the axis parameters of each drive (the mechanical model).
        cycle_time: the NC cycle [s] (one device step per SYNC).
        channel: the virtual bus channel (the NC's ``[drives.canopen] channel``).
        eds: per node an EDS path or None (the shipped ``cia402_sim.eds``).
        device: the simulated drives (a ``Cia402Device`` with ``len(node_ids)`` rows; default: one made
            and configured from ``params``).
    """

    def __init__(self, node_ids: Sequence[int], params: Sequence[AxisParams], cycle_time: float,
                 channel: str = "can0", eds: Sequence[str | None] | None = None, device: Any = None) -> None:
        n = len(node_ids)
        if len(params) != n:
            raise ValueError(f"{n} node ids, {len(params)} parameter sets")
        if device is None:
            from ..cia402.device import Cia402Device
            device = Cia402Device(n, cycle_time)
            for i, p in enumerate(params):
                device.configure(i, p)
        self.device = device
        self.node_ids = list(node_ids)
        self.cycle_time = float(cycle_time)
        self.syncs = 0
        #: SYNCs older than a cycle when the notifier got to them (the slaves ran behind): dropped
        self.dropped_syncs = 0
        #: CPU seconds of the SYNC handler (all of it: RPDOs, device step, TPDOs; the notifier thread's CPU time,
        #: not wall time), for the bench
        self.busy_s = 0.0
        self._lock = threading.Lock()
        self._rx = RxImage.zeros(n)
        self._tx: TxImage = TxImage.zeros(n)
        self._silent = np.zeros(n, dtype=bool)
        self._emcy_code = np.zeros(n, dtype=np.uint16)  # the 0x603F each node last sent an EMCY for
        self._rpdos: list[list[_Rpdo]] = [[] for _ in range(n)]
        self._tpdos: list[list[_Tpdo]] = [[] for _ in range(n)]
        self._operational = np.zeros(n, dtype=bool)
        self._toggle = [0] * n  # node guarding: the toggle bit of the next answer
        self._row = {nid: j for j, nid in enumerate(node_ids)}
        self._closed = False
        self.network = canopen.Network()
        self.network.NOTIFIER_CYCLE = 0.1  # the notifier's receive timeout: close() joins within it
        self.network.bus = VirtualBus(channel=channel)
        self.network.connect()
        self.nodes: list[canopen.LocalNode] = []
        try:
            for j, nid in enumerate(node_ids):
                node = canopen.LocalNode(nid, (eds[j] if eds else None) or SIM_EDS)
                self.network.add_node(node)
                node.add_read_callback(self._reader(j))
                node.add_write_callback(self._writer(j))
                self.nodes.append(node)
                self._rx.mode[j] = _read(node, obj.MODES_OF_OPERATION)
            self.network.subscribe(_NMT, self._on_nmt)
            self.network.subscribe(_SYNC, self._on_sync)
            assert self.network.notifier is not None
            self.network.notifier.add_listener(_GuardingListener(self))
            for node in self.nodes:  # power on: boot-up message, pre-operational
                node.nmt.send_command(0x81)
                node.nmt.send_command(0x80)
        except BaseException:
            self.close()
            raise

    # -- test hooks --------------------------------------------------------------------------------------

    def silence(self, i: int) -> None:
        """Node ``i`` (row) stops answering: no PDOs, heartbeat, SDO or NMT (a cut cable, a dead drive)."""
        with self._lock:
            node = self.nodes[i]
            if self._silent[i]:
                return
            self._silent[i] = True
            node.nmt.stop_heartbeat()
            self.network.unsubscribe(node.sdo.rx_cobid, node.sdo.on_request)
            self.network.unsubscribe(_NMT, node.nmt.on_command)

    def revive(self, i: int) -> None:
        """Node ``i`` answers again (heartbeat, SDO, NMT and, when operational, PDOs)."""
        with self._lock:
            node = self.nodes[i]
            if not self._silent[i]:
                return
            self._silent[i] = False
            self.network.subscribe(node.sdo.rx_cobid, node.sdo.on_request)
            # (its NMT handler before ours again: ours reads the mapping of a node that just became operational)
            self.network.unsubscribe(_NMT, self._on_nmt)
            self.network.subscribe(_NMT, node.nmt.on_command)
            self.network.subscribe(_NMT, self._on_nmt)
            node.nmt.start_heartbeat(_read(node, 0x1017))

    def reboot(self, i: int) -> None:
        """Node ``i`` (row) restarts, as after a power cycle of its electronics: its object dictionary back to the EDS
        defaults (the master's PDO mapping, mode, heartbeat time gone), the drive in Switch on disabled where the
        motor is, a boot-up message, then pre-operational (no heartbeat until the master writes 0x1017 again)."""
        with self._lock:
            node = self.nodes[i]
            node.nmt.stop_heartbeat()
            node.data_store.clear()
            self._operational[i] = False
            self._rpdos[i], self._tpdos[i] = [], []
            self._emcy_code[i] = 0
            self._toggle[i] = 0
            self.device.power_cycle(i)
            rx = self._rx
            rx.controlword[i], rx.target_velocity[i], rx.probe_function[i] = 0, 0.0, 0
            rx.target_position[i] = float(self.device.position[i])
            rx.mode[i] = _read(node, obj.MODES_OF_OPERATION)
            node.nmt.send_command(0x81)  # (reset node) INITIALISING: the boot-up message
            node.nmt.send_command(0x80)  # PRE-OPERATIONAL

    def inject_fault(self, i: int, code: int) -> None:
        """Drive ``i`` (row) faults with 0x603F = ``code`` (its TPDOs and an EMCY show it at the next SYNC)."""
        with self._lock:
            self.device.inject_fault(i, code)

    @contextmanager
    def stalled(self) -> Iterator[None]:
        """While inside: the slaves' SYNC handling blocks (a notifier thread that gets no CPU), for tests."""
        with self._lock:
            yield

    @property
    def applied(self) -> RxImage:
        """The outputs the drives applied at the last SYNC (the RPDOs received before it)."""
        return self._rx

    def nmt_state(self, i: int) -> str:
        return str(self.nodes[i].nmt.state)

    # -- notifier thread ---------------------------------------------------------------------------------

    def _guard(self, node_id: int) -> None:
        """A node guarding request: the node answers with its NMT state and the toggle bit (CiA 301)."""
        with self._lock:
            j = self._row.get(node_id)
            if j is None or self._silent[j] or self._closed:
                return
            node = self.nodes[j]
            state = int(node.nmt._state) & 0x7F  # (python-canopen keeps the state code there; no public getter)
            toggle, self._toggle[j] = self._toggle[j], self._toggle[j] ^ 0x80
            try:
                self.network.send_message(_NMT_ERROR + node_id, bytes([state | toggle]))
            except can.CanError as e:
                log.warning("simulated node %d: guarding answer: %s", node_id, e)

    def _reader(self, j: int) -> Any:
        def read(index: int, subindex: int, od: Any) -> int | None:
            name = _TX_FIELDS.get(index)
            if name is None:
                return None
            v = getattr(self._tx, name)[j:j + 1]
            return int((pdo.wrap32(v) if name in _WRAPPED else np.rint(v))[0])
        return read

    def _writer(self, j: int) -> Any:
        def write(index: int, subindex: int, od: Any, data: bytes) -> None:
            if index == obj.MODES_OF_OPERATION:
                self._rx.mode[j] = od.decode_raw(data)
        return write

    def _on_nmt(self, can_id: int, data: bytearray, timestamp: float) -> None:
        """After the nodes' own NMT handlers: a node entering operational reads its PDO mapping."""
        with self._lock:
            for j, node in enumerate(self.nodes):
                op = node.nmt.state == "OPERATIONAL" and not self._silent[j]
                if op and not self._operational[j]:
                    try:
                        node.rpdo.read()
                        node.tpdo.read()
                        self._rpdos[j] = [_Rpdo(m) for m in node.rpdo.values() if m.enabled and m.map]
                        self._tpdos[j] = [_Tpdo(m) for m in node.tpdo.values() if m.enabled and m.map]
                    except Exception as e:  # a mapping the simulation cannot serve: no PDOs (the NC sees age)
                        log.error("simulated node %d: PDO mapping: %s", node.id, e)
                        self._rpdos[j], self._tpdos[j] = [], []
                self._operational[j] = op

    def _backlog(self) -> bool:
        """The master's next SYNC waits in this bus instance's receive queue (python-can's virtual bus): this one is
        superseded. (Other frames waiting, e.g. the SDO transfers of a node's set-up, do not make a SYNC stale: a
        master that waits for the answer to its SYNC would wait forever.)"""
        q = getattr(self.network.bus, "queue", None)
        if q is None or not q.qsize():
            return False
        with q.mutex:
            return any(m.arbitration_id == _SYNC for m in q.queue)

    def _on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if time.time() - timestamp > self.cycle_time and self._backlog():  # the master's next cycle is queued
            self.dropped_syncs += 1
            return
        t0 = time.thread_time()
        with self._lock:
            self.syncs += 1
            rx = self._rx
            active = [j for j in range(len(self.nodes)) if self._operational[j] and not self._silent[j]]
            for j in active:
                for r in self._rpdos[j]:
                    d = r.map.data
                    if len(d) >= r.struct.size:
                        for f, v in zip(r.fields, r.struct.unpack_from(d)):
                            if f == "target_position":  # INT32 modulo 2^32: continue from the last target
                                prev = np.array([int(np.rint(rx.target_position[j]))], dtype=np.int64)
                                rx.target_position[j] = float(pdo.unwrap32(np.array([v]), prev)[0])
                            elif f is not None:
                                getattr(rx, f)[j] = v
            rx.cycle = self.syncs
            # a fresh image per step: the device may keep the last one (e.g. for the controlword's edges)
            tx = self._tx = self.device.step(RxImage(rx.controlword.copy(), rx.mode.copy(),
                                                     rx.target_position.copy(), rx.target_velocity.copy(),
                                                     rx.probe_function.copy(), rx.cycle))
            cols: dict[str, list[int]] = {}
            for j in active:
                for t in self._tpdos[j]:
                    if t.every and self.syncs % t.every:
                        continue
                    vals = []
                    for f, (lo, hi) in zip(t.fields, t.ranges):
                        if f is None:
                            vals.append(0)
                            continue
                        col = cols.get(f)
                        if col is None:
                            v = getattr(tx, f)
                            # positions wrap as a drive's 32-bit counter does; the others are clamped below
                            col = cols[f] = (pdo.wrap32(v) if f in _WRAPPED else np.rint(v).astype(np.int64)).tolist()
                        vals.append(min(max(col[j], lo), hi))
                    payload = t.struct.pack(*vals)
                    if not t.every and payload == t.last:
                        continue
                    t.last = payload
                    t.map.data = bytearray(payload)
                    t.map.transmit()
            for j in np.flatnonzero(tx.error_code != self._emcy_code).tolist():
                if j in active:
                    code = self._emcy_code[j] = int(tx.error_code[j])
                    if code:
                        self.nodes[j].emcy.send(code, 0x01)
                    else:
                        self.nodes[j].emcy.reset()
        self.busy_s += time.thread_time() - t0

    def close(self) -> None:
        """Stop the heartbeats, the network and this bus instance (idempotent)."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
        for node in getattr(self, "nodes", []):
            node.nmt.stop_heartbeat()
        try:
            self.network.disconnect()
        except Exception as e:
            log.warning("closing the simulated slaves' network: %s", e)

