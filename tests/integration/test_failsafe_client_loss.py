"""Losing a PLC client (issue 8, section 2): real ``nc-server``, ``plc-run`` and client processes on
127.0.0.1, killed with SIGKILL or frozen with SIGSTOP.

* A holder is lost: on each axis it supplied the NC applies the axis's ClientLossReaction
  (axis 1 "stop_disable", 2 "stop", 3 "keep_others"), then its claims are released.
* A client that only commanded a motion (on an axis another client holds) is lost: that motion
  stops with 0x8F01 on the axis, the holder keeps it enabled.

Detection times are printed (kill: liveliness, milliseconds; freeze: the holder's PLCTONC watchdog,
or the zenoh lease of a client that only commands), never asserted.
"""
from __future__ import annotations

import signal
import time
from typing import Callable

import pytest

from znc_testing.failsafe_support import T, AxisWatch, ClientProcess, failsafe_config, resume_and_kill
from znc_testing.plc_harness import PlcProcess
from znc_testing import NcServerProcess, NcTestClient, wait_until

LOST = (0x8F01, 0x8F02)


@pytest.mark.parametrize("how", ["SIGKILL", "SIGSTOP"])
def test_lost_holder_each_reaction(start_nc: Callable[..., NcServerProcess], how: str) -> None:
    # the watchdog catches the frozen holder (its zenoh lease is longer than it): 0x8F02
    nc = start_nc(failsafe_config(["stop_disable", "stop", "keep_others"], watchdog=1.0))
    a = PlcProcess(nc.endpoint, "plc-a", extra=["--lease-ms", "3000"])
    b = NcTestClient(nc.port, "op-b")
    watch = AxisWatch(nc.port, [1, 2, 3])
    try:
        a.wait_started(60)
        for ax in (1, 2, 3):
            a.set(f"pw{ax}", "MC_Power", axis=ax, Enable=True, Enable_Positive=True, Enable_Negative=True)
        for ax in (1, 2, 3):
            a.wait(f"pw{ax}", lambda r: r.o["Status"], T)
        a.set("mv1", "MC_MoveVelocity", axis=1, Execute=True, Velocity=50.0)
        a.set("mv2", "MC_MoveVelocity", axis=2, Execute=True, Velocity=50.0)
        for ax in (1, 2):
            a.wait(f"mv{ax}", lambda r: r.o["InVelocity"], T)
        # axis 3: held and supplied by a, its motion commanded by b (another live client)
        start3 = watch.last(3).pos
        r = wait_until(lambda: (x := b.request("MoveAbsolute", axis=3, Position=start3 + 150.0, Velocity=50.0))
                       ["error"] == 0 and x, T, "b's move on axis 3")
        watch.wait(3, lambda s: s.velo > 49.0, what="axis 3 moving")

        t0 = time.monotonic()
        if how == "SIGKILL":
            a.proc.kill()
        else:
            a.proc.send_signal(signal.SIGSTOP)
        e1 = watch.wait(1, lambda s: s.err in LOST, after=t0, what="axis 1 faulted")
        e2 = watch.wait(2, lambda s: s.err in LOST, after=t0, what="axis 2 faulted")
        print(f"\n[failsafe] holder {how}: axis 1 fault 0x{e1.err:X} after {(e1.t - t0) * 1e3:.0f} ms, "
              f"axis 2 after {(e2.t - t0) * 1e3:.0f} ms")
        if how == "SIGKILL":
            # 0x8F01 (liveliness), not the 1 s watchdog's 0x8F02: the kill is seen without waiting for anything; the time
                # is printed, bounded only against a hang (a CI run at load 29 took 5.5 s to show it)
                assert e1.err == 0x8F01 and (e1.t - t0) < 30.0
        else:
            assert e1.err == 0x8F02
        # 1 stop_disable: stop ramp, then disabled
        s1 = watch.wait(1, lambda s: abs(s.velo) < 1e-9, after=e1.t, what="axis 1 stands")
        watch.wait(1, lambda s: not s.enabled, after=s1.t, what="axis 1 disabled")
        # 2 stop: stop ramp, then enabled holding its position
        s2 = watch.wait(2, lambda s: abs(s.velo) < 1e-9, after=e2.t, what="axis 2 stands")
        time.sleep(1.0)
        later = watch.since(2, s2.t)
        assert later and all(s.enabled and s.err in LOST and s.pos == s2.pos for s in later), later[-3:]
        # 3 keep_others: b's motion goes on to its target without an error, then the axis is disabled.
        # Only the move's last one or two (enabled) frames are within 1e-6 of the target, and the publisher
        # puts the newest frame (under load it skips some); disabled, SetPos is the drive's held ActPos,
        # ~1.5e-5 short (SimTimeConstant 1 ms). A disable before the move's last cycles is > 4e-5 short.
        off3 = watch.wait(3, lambda s: not s.enabled, after=t0, what="axis 3 disabled after the motion")
        assert abs(off3.pos - (start3 + 150.0)) < 1e-4, f"axis 3 disabled short of b's target: {off3}"
        assert all(s.err == 0 for s in watch.since(3, t0))
        # the claims were released: b can take every axis
        for ax in (1, 2, 3):
            assert b.request("Claim", axis=ax)["error"] == 0, ax
    finally:
        watch.close()
        b.close()
        resume_and_kill(a.proc)


@pytest.mark.parametrize("how", ["SIGKILL", "SIGSTOP"])
def test_lost_commander_motion_stops_with_0x8F01(start_nc: Callable[..., NcServerProcess], how: str) -> None:
    """c commanded the motion of axis 1, which b holds and supplies; c is lost: 0x8F01 on the axis,
    which stops and stays enabled (b's PLCTONC)."""
    nc = start_nc(failsafe_config(["stop_disable"]), extra_args=("--watchdog-timeout", "3.0"))
    b = NcTestClient(nc.port, "op-b")
    watch = AxisWatch(nc.port, [1])
    c = None
    try:
        b.claim(1)
        b.feed_plctonc([1])
        watch.wait(1, lambda s: s.enabled, what="axis 1 enabled")
        c = ClientProcess(nc.port, "op-c", commands=[["MoveVelocity", 1, {"Velocity": 40.0}]], lease_ms=500)
        c.wait_ready()
        watch.wait(1, lambda s: s.velo > 39.0, what="axis 1 moving")
        t0 = c.signal(signal.SIGKILL if how == "SIGKILL" else signal.SIGSTOP)
        e = watch.wait(1, lambda s: s.err != 0, after=t0, what="axis 1 faulted")
        print(f"\n[failsafe] commander {how}: 0x{e.err:X} after {(e.t - t0) * 1e3:.0f} ms (lease 500 ms)")
        assert e.err == 0x8F01
        s = watch.wait(1, lambda s: abs(s.velo) < 1e-9, after=e.t, what="axis 1 stands")
        time.sleep(0.5)
        assert all(x.enabled for x in watch.since(1, s.t)), "b still supplies the axis"
        assert b.request("Reset", axis=1)["error"] == 0
        watch.wait(1, lambda s: s.err == 0 and s.enabled, after=s.t, what="reset by b")
    finally:
        watch.close()
        b.close()
        if c is not None:
            c.kill()
