"""plc-run's shutdown is bounded: SIGTERM ends it with 0 within a few seconds, whatever its NC does.

The hang these tests pin down: with the NC frozen (SIGSTOP), the PLC's zenoh session notices the
lost lease (~1 s) and starts reconnecting; the kernel accepts the TCP connection for the frozen
process, and zenoh's handshake then waits for an answer until its ``open_timeout`` (10 s).
``Session.close()`` waits for that handshake: plc-run used to need ~11 s after SIGTERM, beyond
``PlcProcess.stop``'s 10 s before SIGKILL (rc -9). The same wait happens whenever a connection
attempt to an NC that does not answer is pending at shutdown (presumably what made
test_plc_nc_restart.py end with -9 once on a loaded machine; not reproduced there).
"""
from __future__ import annotations

import signal
import subprocess
import time
from typing import Callable

import pytest

from znc_testing.plc_harness import NC_ARGS, T, PlcProcess, power_on
from znc_testing import NcServerProcess

#: what a clean shutdown may take here: 3 cycles, <= 1 s for the Release replies, <= 2 s for the
#: sessions to close, the process exit; generous for a loaded machine (a plc-run stalled ~3 s), below the old
#: 9.4-10.9 s hang and the 10 s SIGKILL
EXIT_WITHIN = 8.5


def _moving(p: PlcProcess) -> None:
    p.wait_started()
    power_on(p)
    p.set("mv", "MC_MoveVelocity", Execute=True, Velocity=10.0)
    p.wait("mv", lambda r: r.o["InVelocity"], T)


def _sigterm(p: PlcProcess, within: float = EXIT_WITHIN) -> tuple[int, float]:
    """SIGTERM ``p`` and wait up to ``within`` seconds; returns (rc, seconds it took)."""
    t0 = time.monotonic()
    p.proc.terminate()
    try:
        rc = p.proc.wait(within)
    except subprocess.TimeoutExpired:
        raise AssertionError(f"plc-run still running {within} s after SIGTERM:\n{''.join(p.err_lines[-20:])}")
    return rc, time.monotonic() - t0


@pytest.mark.parametrize("after", [0.0, 1.5], ids=["lease-running", "reconnecting"])
def test_sigterm_while_the_nc_is_frozen(start_nc: Callable[..., NcServerProcess], after: float) -> None:
    """``after`` seconds after the PLC saw the frames stop: 0 - the lease still runs (the Release
    requests wait for it, then zenoh reconnects during the close); 1.5 - the lease (1 s) has run out
    and zenoh is in the handshake with the frozen NC. plc-run took ~10.9 s and ~9.4 s before."""
    nc = start_nc(extra_args=NC_ARGS)
    with PlcProcess(nc.endpoint, "plc-a") as a:
        _moving(a)
        nc.send_signal(signal.SIGSTOP)
        try:
            a.wait("mv", lambda r: not r.a["Valid"], T)  # no more frames: the axis data is invalid
            time.sleep(after)
            rc, took = _sigterm(a)
        finally:
            nc.send_signal(signal.SIGCONT)
        assert rc == 0, "".join(a.err_lines[-20:])
        assert took < EXIT_WITHIN
        # (usually with the warning "did not close within 2.0 s"; not asserted: on a loaded machine
        # zenoh may not have started the reconnection yet, then the session closes at once)


def test_sigterm_just_after_the_nc_was_killed(start_nc: Callable[..., NcServerProcess]) -> None:
    nc = start_nc(extra_args=NC_ARGS)
    with PlcProcess(nc.endpoint, "plc-a") as a:
        _moving(a)
        nc.kill()
        rc, took = _sigterm(a)
        assert rc == 0, "".join(a.err_lines[-20:])
        assert took < EXIT_WITHIN


def test_sigterm_with_the_nc_reachable_releases_the_claim(start_nc: Callable[..., NcServerProcess]) -> None:
    nc = start_nc(extra_args=NC_ARGS)
    with PlcProcess(nc.endpoint, "plc-a") as a, PlcProcess(nc.endpoint, "plc-b") as b:
        _moving(a)
        b.wait_started()
        b.set("pos", "MC_ReadActualPosition", Enable=True)
        b.wait("pos", lambda r: r.o["Valid"], T)
        rc, took = _sigterm(a)
        assert rc == 0 and took < EXIT_WITHIN, "".join(a.err_lines[-20:])
        assert not any("no reply" in line or "did not close" in line for line in a.err_lines), a.err_lines
        # released before the token went: the NC did not fault the axis for a lost client (0x8F01)
        b.wait_cycles(30)
        r = b.last("pos")
        assert r is not None and r.a["Valid"] and r.a["ErrorId"] == 0 and r.a["State"] != "ERRORSTOP", r
        # and another PLC can take the axis at once
        pw = power_on(b)
        assert not pw.o["Error"], pw
