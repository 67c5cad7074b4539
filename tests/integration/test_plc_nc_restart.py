"""Killing the NC under a running PLC, and restarting it on the same endpoint (also fast, with the new
Cycle above the old one's); the NC frozen past its lease (its liveliness tokens go and come back, the
same instance runs on) is no restart."""
from __future__ import annotations

import os
import signal
import time
from typing import Callable

from znc_testing.plc_harness import NC_ARGS, T, PlcProcess, power_on
from znc_testing import NcServerProcess, NcTestClient, free_port, wait_until


def _nc_and_powered_plc(
        start_nc: Callable[..., NcServerProcess]) -> tuple[NcServerProcess, tuple[str, str], PlcProcess]:
    """An NC on a port of its own (its restart listens there again: ``listen``) and a PLC that powered axis 1."""
    port = free_port()
    listen = ("--listen", f"tcp/127.0.0.1:{port}")
    nc = start_nc(extra_args=(*NC_ARGS, *listen))
    a = PlcProcess(f"tcp/127.0.0.1:{port}", "plc-a")
    try:
        a.wait_started()
        power_on(a)
    except BaseException:
        a.stop()
        raise
    return nc, listen, a


def test_nc_killed_and_restarted(start_nc: Callable[..., NcServerProcess]) -> None:
    nc, listen, plc = _nc_and_powered_plc(start_nc)
    with plc as a:
        a.set("pos", "MC_ReadActualPosition", Enable=True)
        a.set("jog", "MC_MoveVelocity", Execute=True, Velocity=20.0)
        a.set("mv", "MC_MoveAbsolute", Execute=True, Position=800.0, Velocity=10.0)  # aborts jog, runs long
        a.wait("mv", lambda r: r.o["Active"], T)
        assert a.last("mv").a["Epoch"] == 0

        nc.kill()  # SIGKILL: no goodbye
        for name in ("pw", "pos", "mv"):
            r = a.wait(name, lambda r: r.o["Error"], T)
            assert r.o["ErrorID"] == 0x4B0F and not r.a["Valid"], (name, r)
        assert not a.last("pw").o["Status"] and not a.last("pos").o["Valid"]
        a.wait_cycles(20)
        assert a.proc.poll() is None, "the PLC keeps cycling without its NC"

        nc2 = start_nc(extra_args=(*NC_ARGS, *listen))
        # the session reconnects by itself; MC_Power claims the axis again on the new instance
        r = a.wait("pw", lambda r: r.o["Status"] and not r.o["Error"], T)
        assert r.a["Valid"] and r.a["State"] == "STANDSTILL"
        # one restart, one nc_epoch step: its token came back and its cycle counter went back
        wait_until(lambda: any("NC nc1 is back" in line for line in a.err_lines), T, "the NC's token back")
        a.trace(1)
        a.wait_trace(1, lambda r: r.a["Valid"], T)
        a.wait_cycles(10)
        assert {s.a["Epoch"] for s in a.trace_of(1)} == {1}
        a.trace(1, on=False)
        p = a.wait("pos", lambda r: r.o["Valid"], T)
        # nothing moves by itself: mv still shows its error (Execute stays TRUE: no new edge)
        time.sleep(1.0)
        a.wait_cycles(10)
        assert a.last("mv").o["Error"] and not a.last("mv").o["Busy"]
        now = a.last("pos")
        assert now.a["State"] == "STANDSTILL" and abs(now.o["Position"] - p.o["Position"]) < 1e-9
        # and the new NC accepts commands from the same PLC
        a.set("mv", Execute=False)
        a.wait_cycles(2)
        a.set("mv", Execute=True, Position=10.0, Velocity=100.0)
        done = a.wait("mv", lambda r: r.o["Done"], T)
        assert abs(done.a["ActPos"] - 10.0) < 0.02
        assert a.stop() == 0
    nc2.stop()


def test_nc_frozen_past_its_lease_is_no_restart_but_a_new_instance_is(
        start_nc: Callable[..., NcServerProcess]) -> None:
    """The NC SIGSTOPped 1.2 s (its lease: 0.5 s): the PLC's zenoh drops the link, so the NC's liveliness
    token goes and comes back while the same instance runs on - what a starved process on a loaded machine
    does. No restart is declared (before: every token return was one: claims forgotten, nc_epoch + 1).
    Then a new nc-server on the same port: a restart, seen at its first frame (no valid sample of the new
    instance with the old epoch)."""
    nc, listen, plc = _nc_and_powered_plc(start_nc)
    with plc as a:
        a.trace(1)
        a.wait_trace(1, lambda r: r.a["Valid"], T)
        for _ in range(2):
            gone = sum("NC nc1 is gone" in line for line in a.err_lines)
            nc.send_signal(signal.SIGSTOP)
            try:
                time.sleep(1.2)
            finally:
                nc.send_signal(signal.SIGCONT)
            wait_until(lambda: sum("NC nc1 is gone" in line for line in a.err_lines) > gone, T,
                       "the NC's token gone for the PLC (its link dropped)")
            wait_until(lambda: sum("NC nc1 is back" in line for line in a.err_lines) > gone, T, "the NC's token back")
            n = len(a.trace_of(1))
            a.wait_trace(1, lambda r: r.a["Valid"] and len(a.trace_of(1)) > n, T)
        a.wait_cycles(20)
        assert not [line for line in a.err_lines if "restarted" in line], "".join(a.err_lines[-20:])
        assert {s.a["Epoch"] for s in a.trace_of(1)} == {0}

        n_before = len(a.trace_of(1))
        nc.kill()
        t_start = time.monotonic()
        nc2 = start_nc(extra_args=(*NC_ARGS, *listen))
        t_ready = time.monotonic()
        try:
            wait_until(lambda: any("NC nc1 restarted" in line for line in a.err_lines), T, "the restart detected")
        except AssertionError as exc:
            seen = [(r.c, r.a["NcCycle"], r.a["Valid"], r.a["Epoch"]) for r in a.trace_of(1)[n_before:]]
            raise AssertionError(f"{exc}\n{''.join(a.err_lines[-20:])}\nsamples (c, NcCycle, Valid, Epoch): "
                                 f"{seen[:5]} ... {seen[-5:]}") from None
        print(f"\n[restart] new NC instance detected {(time.monotonic() - t_start) * 1e3:.0f} ms after nc-server was "
              f"started ({(t_ready - t_start) * 1e3:.0f} ms to its ready line)")
        a.wait_trace(1, lambda r: r.a["Valid"] and r.a["Epoch"] == 1, T)
        after = a.trace_of(1)[n_before:]
        lost = next(i for i, r in enumerate(after) if not r.a["Valid"])  # the old instance's end
        new_epochs = {r.a["Epoch"] for r in after[lost:] if r.a["Valid"]}
        assert new_epochs == {1}, f"valid samples of the new instance with the old epoch: {new_epochs}"
        a.wait("pw", lambda r: r.o["Status"] and not r.o["Error"], T)  # claimed again on the new instance
        assert a.stop() == 0
    nc2.stop()


def test_a_fast_restart_is_one_restart_although_its_cycle_went_on_higher(
        start_nc: Callable[..., NcServerProcess], nc_client: Callable[..., NcTestClient]) -> None:
    """The defect: the old NC ran briefly (here: from the PLC's first connection until it had powered the
    axis), the PLC's first frame of the new NC on the same port carries a *higher* Cycle than the old one's
    last. Before, no rule fired: the PLC kept its 'held' claim that the new NC did not know, MC_Power never
    claimed again. Made deterministic by freezing the PLC (SIGSTOP) across the restart until the new NC's
    Cycle is well above the old one's. Now the new instance token tells: one restart, nc_epoch + 1 once."""
    port = free_port()
    listen = ("--listen", f"tcp/127.0.0.1:{port}")
    with PlcProcess(f"tcp/127.0.0.1:{port}", "plc-a") as a:  # waiting before the NC: the old NC lives briefly
        a.wait_started()
        a.set("pw", "MC_Power", Enable=True, Enable_Positive=True, Enable_Negative=True)
        a.trace(1)
        nc = start_nc(extra_args=(*NC_ARGS, *listen))
        a.wait("pw", lambda r: r.o["Status"] and r.a["Epoch"] == 0, T)  # claimed and enabled on the old NC
        os.kill(a.proc.pid, signal.SIGSTOP)
        try:
            # a stats sample sent after the freeze: the old NC's Cycle then, not below anything the PLC saw
            old = nc_client(port)
            c_old = wait_until(lambda: (s := old.stats()) and s["cycle"], T, "the old NC's stats")
            nc.kill()
            nc2 = start_nc(extra_args=(*NC_ARGS, *listen))
            new = nc_client(port)
            c_new = wait_until(lambda: (s := new.stats()) and s["cycle"] > c_old + 500 and s["cycle"], T,
                               "the new NC's cycle well above the old one's")
        finally:
            os.kill(a.proc.pid, signal.SIGCONT)
        assert nc2.instance() != nc.instance()
        print(f"\n[fast restart] old NC's last Cycle <= {c_old}, new NC's Cycle {c_new} when the PLC went on")
        restarted = lambda: [line for line in a.err_lines if "NC nc1 restarted" in line]  # noqa: E731
        try:
            wait_until(restarted, T, "the restart detected")
            a.wait("pw", lambda r: r.o["Status"] and not r.o["Error"] and r.a["Epoch"] == 1, T)  # claimed again
        except AssertionError as exc:
            seen = [(r.c, r.a["NcCycle"], r.a["Valid"], r.a["Epoch"]) for r in a.trace_of(1)]
            raise AssertionError(f"{exc}\n{''.join(a.err_lines[-20:])}\nsamples (c, NcCycle, Valid, Epoch): "
                                 f"{seen[-10:]}") from None
        a.wait_cycles(20)
        assert len(restarted()) == 1 and nc2.instance() in restarted()[0], restarted()
        samples = [r for r in a.trace_of(1) if r.a["Valid"]]
        old_last = max(r.a["NcCycle"] for r in samples if r.a["Epoch"] == 0)
        new_first = next(r.a["NcCycle"] for r in samples if r.a["Epoch"] == 1)
        assert new_first > old_last, (old_last, new_first)  # the case the frames alone cannot show
        # no data of the old instance is valid under the new epoch (the restart came before its frames)
        assert all(r.a["NcCycle"] > c_old for r in samples if r.a["Epoch"] == 1), [
            (r.c, r.a["NcCycle"], r.a["Epoch"]) for r in samples if r.a["Epoch"] == 1][:5]
        epochs = [r.a["Epoch"] for r in a.trace_of(1)]
        assert epochs == sorted(epochs) and epochs[-1] == 1  # one step, never back
        assert a.stop() == 0
    nc2.stop()
