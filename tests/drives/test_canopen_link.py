"""CanopenLink against SimulatedSlaves on python-can's virtual bus (real canopen master and LocalNodes, one process):
the NMT/SDO configuration as the slaves' object dictionaries hold it, the cyclic exchange (INT32 targets, ages),
heartbeat loss, and the start errors (missing node, missing bus, an EDS without a mapped object) -- bounded."""
from __future__ import annotations

import time
import uuid
from pathlib import Path
from typing import Iterator

import numpy as np
import pytest

import nc_server.core  # noqa: F401  (first: nc_server.drives imports the core, which imports drives.base)
from nc_server.core.params import AxisParams
from nc_server.drives.canopen import pdo
from nc_server.drives.canopen.link import SIM_EDS, BusConfig, CanopenLink, CanopenStartError, NodeConfig
from nc_server.drives.canopen.slave import SimulatedSlaves
from nc_server.drives.cia402.image import RxImage
from nc_server.drives.cia402.objects import CMD_SHUTDOWN, Mode
from znc_testing.until import wait_until

DT = 0.001


def _channel() -> str:
    return f"test-{uuid.uuid4().hex[:10]}"


class Rig:
    def __init__(self, nodes: list[NodeConfig], bus: BusConfig, slave_ids: list[int] | None = None) -> None:
        ids = slave_ids if slave_ids is not None else [n.node_id for n in nodes]
        self.slaves = SimulatedSlaves(ids, [AxisParams(AxisEncoderScalingFactor=0.001) for _ in ids], DT,
                                      channel=bus.channel, eds=[n.eds for n in nodes] if slave_ids is None else None)
        self.link: CanopenLink | None = None
        try:
            self.link = CanopenLink(nodes, DT, bus)
        except BaseException:
            self.slaves.close()
            raise

    def close(self) -> None:
        if self.link is not None:
            self.link.close()
        self.slaves.close()


@pytest.fixture
def rig() -> Iterator[Rig]:
    r = Rig([NodeConfig(2), NodeConfig(5, csv=True)], BusConfig(channel=_channel()))
    yield r
    r.close()


def _rx(n: int, pos: float = 0.0) -> RxImage:
    rx = RxImage.zeros(n)
    rx.controlword[:] = CMD_SHUTDOWN
    rx.target_position[:] = pos
    return rx


def test_start_configures_the_nodes_over_sdo(rig: Rig) -> None:
    csp, csv = rig.slaves.nodes
    for node in (csp, csv):
        assert rig.slaves.nmt_state(rig.slaves.nodes.index(node)) == "OPERATIONAL"
        sdo = node.sdo
        assert (sdo[0x60C2][1].raw, sdo[0x60C2][2].raw) == (1, -3)  # 1 x 10^-3 s: the NC cycle
        assert sdo[0x1017].raw == 100                             # heartbeat producer time [ms]
        # the TPDO mapping and transmission types the master wrote (read back from the slave's dictionary)
        for k, entries in pdo.TPDO_LAYOUT.items():
            assert sdo[0x1A00 + k - 1][0].raw == len(entries)
            assert [sdo[0x1A00 + k - 1][s + 1].raw for s in range(len(entries))] == \
                [(i << 16) | b for i, b in entries]
            assert sdo[0x1800 + k - 1][1].raw == 0x80 + 0x100 * k + node.id
            assert sdo[0x1800 + k - 1][2].raw == pdo.TPDO_TRANS[k]
        assert not sdo[0x1803][1].raw & (1 << 31)  # TPDO4 on: touch probe 2's positions (MC_TouchProbe)
        assert sdo[0x1400][1].raw == 0x200 + node.id and sdo[0x1400][2].raw == 1
        assert [sdo[0x1600][s].raw for s in (1, 2, 3)] == [0x60400010, 0x607A0020, 0x60600008]
    assert csp.sdo[0x6060].raw == Mode.CSP and csv.sdo[0x6060].raw == Mode.CSV
    assert [csp.sdo[0x1601][s].raw for s in range(2)] == [1, 0x60B80010]
    assert [csv.sdo[0x1601][s].raw for s in range(3)] == [2, 0x60FF0020, 0x60B80010]


def test_exchange_packs_int32_targets_and_returns_the_newest_inputs(rig: Rig) -> None:
    link = rig.link
    assert link is not None
    rx = _rx(2)
    rx.target_position[:] = [1234.4, -1e12]  # rounded; modulo 2^32 (an INT32 on the wire)
    rx.target_velocity[:] = [0.0, -250.6]
    rx.mode[:] = [Mode.CSP, Mode.CSV]
    link.exchange(rx)
    assert link.wait_answered(5.0)
    dev_rx = rig.slaves.applied  # what the slaves applied at the SYNC
    assert list(dev_rx.target_position) == [1234.0, float(pdo.wrap32(np.array([-1e12]))[0])]
    assert list(dev_rx.controlword) == [CMD_SHUTDOWN, CMD_SHUTDOWN]
    assert dev_rx.target_velocity[1] == -251.0 and list(dev_rx.mode) == [Mode.CSP, Mode.CSV]
    tx = link.exchange(rx)
    assert list(tx.age) == [0, 0] and tx.alive.all()
    # the statusword of the device after the shutdown command: Ready to switch on (0x21 with its bits)
    assert all(int(sw) & 0x6F == 0x21 for sw in tx.statusword)
    # SDO reads of the actual values answer the device's last step (the same as the TPDO carried)
    assert rig.slaves.nodes[0].sdo[0x6041].raw == int(tx.statusword[0])


def test_a_node_whose_pdo_map_is_swapped_mid_cycle_does_not_break_the_cycle(rig: Rig) -> None:
    """The cycle does not use canopen's PdoMap objects, which a re-setup rewrites: what python-canopen's clear() /
    add_variable() can leave for a moment changes nothing for the cycle (it was a struct.error, counted)."""
    link = rig.link
    assert link is not None
    syncs = link.syncs
    errors = link.tx_errors
    link.nodes[0].rpdo1.data = bytearray(2)
    link.nodes[1].tpdo[1].data = bytearray(1)
    link.exchange(_rx(2, 100.0))
    assert link.tx_errors == errors and link.syncs == syncs + 1
    assert link.wait_answered(5.0)
    assert list(rig.slaves.applied.target_position) == [100.0, 100.0]
    tx = link.exchange(_rx(2, 100.0))
    assert all(int(sw) & 0x6F == 0x21 for sw in tx.statusword) and list(tx.age) == [0, 0]


def test_a_re_setup_swaps_the_cycles_view_of_a_node_whole(rig: Rig) -> None:
    """``_Node.cyclic`` is replaced whole by a re-setup (None meanwhile: the node gets nothing, keeps its last
    inputs); the cycle reads one reference per node."""
    link = rig.link
    assert link is not None
    link.exchange(_rx(2, 10.0))
    assert link.wait_answered(5.0)
    node = link.nodes[0]
    old = node.cyclic
    assert old is not None and old.sent_rpdo2[0] != b""
    node.cyclic = None  # (what _setup_again does while it rewrites the node's maps)
    before = rig.slaves.applied.target_position.copy()
    tx = link.exchange(_rx(2, 20.0))
    assert link.wait_answered(5.0, [1])
    tx = link.exchange(_rx(2, 20.0))
    assert rig.slaves.applied.target_position[0] == before[0] and rig.slaves.applied.target_position[1] == 20.0
    node.cyclic = node.make_cyclic()
    assert node.cyclic is not old and node.cyclic.sent_rpdo2 == [b""]  # (RPDO2 sent again after a set-up)
    link.exchange(_rx(2, 30.0))
    assert link.wait_answered(5.0)
    assert list(rig.slaves.applied.target_position) == [30.0, 30.0]


def test_wrap32_and_unwrap32() -> None:
    big = np.array([2**31 - 1, 2**31, -2**31 - 1, 5 * 2**32 + 7], dtype=np.int64)
    assert pdo.wrap32(big).tolist() == [2**31 - 1, -2**31, 2**31 - 1, 7]
    assert pdo.wrap32(np.array([1.6, np.nan, 1e300])).tolist()[:2] == [2, 0]
    assert pdo.unwrap32(pdo.wrap32(big), big - 1000).tolist() == big.tolist()


def test_an_endless_axis_crosses_the_int32_range_without_a_jump(rig: Rig) -> None:
    """Positions travel modulo 2^32 (a drive's 32-bit counter): the target and the actual position cross
    INT32_MAX continuously on both sides; clipping would stop the axis there and a raw reading would jump 2^32."""
    link = rig.link
    assert link is not None
    start = float(pdo.INT32_MAX - 300)
    rig.slaves.device.position[0] = start  # the motor stands near the end of the INT32 range
    rx = _rx(2, start)
    rx.mode[:] = [Mode.CSP, Mode.CSV]
    for cw in (0x06, 0x07, 0x0F, 0x0F):  # shutdown, switch on, enable operation
        rx.controlword[:] = cw
        link.exchange(rx)
        assert link.wait_answered(5.0)
    seen = []
    for k in range(1, 13):  # 50 increments per cycle across 2^31
        rx.target_position[0] = start + 50 * k
        tx = link.exchange(rx)
        assert link.wait_answered(5.0)
        seen.append(float(tx.position_actual[0]))
    tx = link.exchange(rx)
    final = float(tx.position_actual[0])
    assert rig.slaves.device.position[0] > pdo.INT32_MAX  # the drive followed the target beyond the range
    assert final > pdo.INT32_MAX and abs(final - rig.slaves.device.position[0]) < 2
    assert all(0 <= b - a < 100 for a, b in zip(seen, seen[1:])), seen  # no 2^32 jump, never backwards


def test_closing_switches_the_drives_off_before_nmt(rig: Rig) -> None:
    """close() sends Shutdown (and its SYNC) before NMT pre-operational: an enabled drive ends in Ready to switch
    on, as commanded, not with a communication abort."""
    from nc_server.drives.cia402.objects import State

    link = rig.link
    assert link is not None
    rx = _rx(2)
    rx.mode[:] = [Mode.CSP, Mode.CSV]
    for cw in (0x06, 0x07, 0x0F, 0x0F):
        rx.controlword[:] = cw
        link.exchange(rx)
        assert link.wait_answered(5.0)
    assert rig.slaves.device.state.tolist() == [State.OPERATION_ENABLED] * 2
    link.close()
    wait_until(lambda: rig.slaves.device.state.tolist() == [State.READY_TO_SWITCH_ON] * 2, 10.0,
               "both drives in Ready to switch on after close()")


def test_the_cycle_never_waits_while_the_slaves_are_silent(rig: Rig) -> None:
    link = rig.link
    assert link is not None
    link.exchange(_rx(2))
    assert link.wait_answered(5.0)
    rig.slaves.silence(0)
    rig.slaves.silence(1)
    # let TPDOs already in flight land: until the receive stamps stop changing (no SYNC is sent meanwhile)
    def stamps() -> list[list[int]]:
        return [link._stamp[k].tolist() for k in sorted(link._stamp)]

    deadline, before = time.monotonic() + 10.0, stamps()
    while True:
        time.sleep(0.05)
        now = stamps()
        if now == before:
            break
        assert time.monotonic() < deadline, "TPDOs kept arriving from silenced slaves"
        before = now
    ages, worst = [], 0.0
    for _ in range(50):
        t0 = time.perf_counter()
        tx = link.exchange(_rx(2))
        worst = max(worst, time.perf_counter() - t0)
        ages.append(int(tx.age[0]))
    assert ages == list(range(ages[0], ages[0] + 50))  # every missing TPDO counted, one per cycle
    assert worst < 0.1  # far below any SDO or heartbeat timeout: nothing waited on the bus


def test_heartbeat_loss_and_return(rig: Rig) -> None:
    link = rig.link
    assert link is not None
    assert link.exchange(_rx(2)).alive.all()
    rig.slaves.silence(1)
    def lost() -> object:
        t = link.exchange(_rx(2))
        return t if not t.alive[1] else "node 5 still alive"
    tx = wait_until(lost, 5.0, "node 5 lost")
    assert tx.alive[0] and not tx.alive[1]  # type: ignore[attr-defined]
    rig.slaves.revive(1)
    wait_until(lambda: link.exchange(_rx(2)).alive.all(), 5.0, "node 5 back")


def test_a_missing_node_is_a_clear_bounded_start_error() -> None:
    ch = _channel()
    t0 = time.monotonic()
    with pytest.raises(CanopenStartError, match=r"node 7 does not answer .*virtual channel") as e:
        Rig([NodeConfig(2), NodeConfig(7)], BusConfig(channel=ch, sdo_timeout=0.2), slave_ids=[2])
    assert time.monotonic() - t0 < 10.0
    assert "SDO" in str(e.value)


def test_a_missing_bus_is_a_clear_start_error() -> None:
    with pytest.raises(CanopenStartError, match="cannot open the CAN bus .*'no-such-interface'"):
        CanopenLink([NodeConfig(2)], DT, BusConfig(interface="no-such-interface", channel="x"))


def test_an_eds_per_node_and_one_without_a_mapped_object(tmp_path: Path) -> None:
    own = tmp_path / "drive.eds"
    own.write_text(Path(SIM_EDS).read_text())
    r = Rig([NodeConfig(3, eds=str(own))], BusConfig(channel=_channel()))
    try:
        assert r.link is not None and r.link.exchange(_rx(1)).alive.all()
    finally:
        r.close()
    text = Path(SIM_EDS).read_text()
    start = text.index("[60B8]")
    broken = tmp_path / "no_probe.eds"
    broken.write_text(text[:start] + text[text.index("[60B9]"):])
    with pytest.raises(CanopenStartError, match="node 4: its EDS has no object 0x60B8"):
        Rig([NodeConfig(4, eds=str(broken))], BusConfig(channel=_channel()), slave_ids=[4])


def test_interpolation_period_and_bus_load() -> None:
    from nc_server.drives.canopen.link import interpolation_period
    assert interpolation_period(0.001) == (1, -3)
    assert interpolation_period(0.0005) == (5, -4)
    assert interpolation_period(0.004) == (4, -3)
    with pytest.raises(ValueError):
        interpolation_period(0.2561)
    # 8 axes of RPDO1 + TPDO1 + TPDO2 do not fit 1 ms at 1 Mbit/s; at 4 ms they do
    assert pdo.bus_load(8, 0.001, 1_000_000) > 1.0 > pdo.bus_load(8, 0.004, 1_000_000)
    assert np.isclose(pdo.frame_bits(8), 47 + 64 + 24)


def test_slaves_that_ran_behind_drop_the_late_syncs_and_catch_up(rig: Rig) -> None:
    """A stalled slave thread (here: its lock held for 0.1 s while the NC runs on in real time) answers no SYNC
    it reaches a cycle late with newer frames queued: the NC sees the ages, and the slaves are current again
    soon after instead of working through the backlog."""
    link = rig.link
    assert link is not None
    link.exchange(_rx(2))
    assert link.wait_answered(5.0)
    with rig.slaves.stalled():  # the slaves' notifier thread blocks on its next SYNC
        for _ in range(50):
            link.exchange(_rx(2))
            time.sleep(0.002)
    sent = link.syncs

    def current() -> object:
        tx = link.exchange(_rx(2))
        time.sleep(DT)
        return tx.age.max() == 0 or f"age {tx.age}"
    wait_until(current, 10.0, "the slaves current again")
    assert rig.slaves.dropped_syncs > 0
    assert rig.slaves.syncs < sent  # not every SYNC of the stall was stepped: the backlog was dropped


def test_a_node_being_set_up_keeps_its_last_inputs_and_they_age(rig: Rig) -> None:
    """While ``node.cyclic`` is None (a re-setup, or one that failed) the cycle keeps the node's last payloads; their
    age grows by one per cycle and their rx_cycle stays, though the notifier thread goes on stamping the node's
    frames (here the slave still answers every SYNC): old inputs must not look fresh."""
    link = rig.link
    assert link is not None
    rx = _rx(2, 10.0)
    for c in range(1, 4):
        rx.cycle = c
        link.exchange(rx)
        assert link.wait_answered(5.0)
    rx.cycle = 4
    tx = link.exchange(rx)
    assert list(tx.age) == [0, 0] and list(tx.rx_cycle) == [3, 3]
    assert link.wait_answered(5.0)
    link.nodes[0].cyclic = None
    for c in range(5, 10):
        rx.cycle = c
        tx = link.exchange(rx)
        assert int(tx.age[0]) == c - 4 and int(tx.rx_cycle[0]) == 3  # (was: age 0, rx_cycle c - 1)
        assert int(tx.age[1]) == 0 and int(tx.rx_cycle[1]) == c - 1
        assert link.wait_answered(5.0)
    link.nodes[0].cyclic = link.nodes[0].make_cyclic()
    rx.cycle = 10
    link.exchange(rx)
    assert link.wait_answered(5.0)
    rx.cycle = 11
    tx = link.exchange(rx)
    assert list(tx.age) == [0, 0] and list(tx.rx_cycle) == [10, 10]


def test_peek_reads_the_newest_inputs_and_sends_nothing(rig: Rig) -> None:
    """CanopenLink.peek (a standby's takeover, Cia402Drive.resync): the stored TPDOs, no RPDO, no SYNC."""
    link = rig.link
    assert link is not None
    rx = _rx(2, 10.0)
    rx.cycle = 7
    link.exchange(rx)
    assert link.wait_answered(5.0)
    syncs, applied = link.syncs, rig.slaves.applied.target_position.copy()
    tx = link.peek()
    time.sleep(0.05)
    assert link.syncs == syncs and list(rig.slaves.applied.target_position) == list(applied)
    assert list(tx.rx_cycle) == [7, 7] and list(tx.age) == [0, 0]
    assert all(int(sw) & 0x6F == 0x21 for sw in tx.statusword)


def test_a_probe_latch_waits_for_its_positions(rig: Rig) -> None:
    """TPDO3 (0x60B9 with a latch stored) and TPDO4 (0x60BC/0x60BD) of one SYNC may be stored one after the other
    with an NC cycle between them: the cycle must not take the new status with the positions of the latch before
    (review of issue 20: MC_TouchProbe's RecordedPosition wrong, Done set, nothing flagged)."""
    link = rig.link
    assert link is not None
    link.exchange(_rx(2))
    assert link.wait_answered(5.0)
    time.sleep(0.1)  # (no SYNC is sent meanwhile: what is in flight lands)
    cyc = link.nodes[0].cyclic
    assert cyc is not None
    before = link.peek()
    s = link.syncs + 5  # (a SYNC later than every stamp: TPDO3 of it arrived, TPDO4 and the next TPDO1 not yet)
    status = int(before.probe_status[0]) | 0x0200  # probe 2 positive edge stored
    link._tpdo_data[3][0] = cyc.s_tpdo[3].pack(status, 0)
    link._stamp[3][0] = s
    tx = link.peek()
    assert int(tx.probe_status[0]) == int(before.probe_status[0])  # held: its positions are not in yet
    link._tpdo_data[4][0] = cyc.s_tpdo[4].pack(1234, 0)
    link._stamp[4][0] = s
    tx = link.peek()
    assert int(tx.probe_status[0]) == status and float(tx.probe2_pos[0]) == 1234.0
    # a TPDO3 change without a TPDO4 (positions unchanged: not sent) is taken once the next SYNC's TPDO1 is in
    link._tpdo_data[3][0] = cyc.s_tpdo[3].pack(status & ~0x0200, 0)
    link._stamp[3][0] = s + 1
    assert int(link.peek().probe_status[0]) == status
    link._stamp[1][0] = s + 2
    assert int(link.peek().probe_status[0]) == status & ~0x0200
