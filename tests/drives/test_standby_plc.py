"""A PLC (``plc-run``) on a hot-standby NC pair whose standby takes over while the active NC is still alive (a false
takeover, as under load at set-up in ``bench/many_clients.py --standby``): the clients had seen the active NC's
frames of cycles the standby never had a log of.

The rig is tests/drives/test_standby_process.py's (an ``nc-router``, nodes ``a`` active and ``b`` standby of NC
``nc1`` behind it, ``nc-drive-sim``); the false takeover is forced by freezing the router (SIGSTOP) for longer than
the standby's loss limit (at most 1 s): the standby gets no log, takes over; the active NC runs on meanwhile (its frames
and logs queue up or are dropped), and after SIGCONT the PLC gets the old NC's newest frames, then the new one's.
The router's freeze stops the active NC's frames too (the standby's second sign of life, docs/standby.md "Loss
detection"), so the standby takes over; the PLC may then see an NC restart (the old NC's queued frames were cycles
ahead of the new NC's: the state of those cycles is lost with it, the documented partition case of the epoch rule).
Either way its MC_Power, Enable held TRUE all along, has Status again: after a restart the task forgot its claims and
claims again (plc_client/task.py), without one the claim holds on the new active NC.
"""
from __future__ import annotations

import os
import signal
import time
from typing import Any, Callable

from test_standby_process import CYCLE, DONE, T, Procs, active_node, ha_status, pair, servers, wait_logged  # noqa: F401

from znc_testing import NcTestClient
from znc_testing.plc_harness import PlcProcess, power_on
from znc_testing.standby_rig import LEASE_MS

FREEZE_S = 2.0  # above the loss detection's cap (1 s), below the drive host's timeout (3 s) and the leases (3 s)


def _plc(p: Procs) -> PlcProcess:
    # (staleness 4 s: the router's freeze makes every frame late; not what this test is about)
    return PlcProcess(f"tcp/127.0.0.1:{p['port']}", "plc1",
                      extra=["--lease-ms", str(LEASE_MS), "--stale-cycles", "400"])


def _freeze_router(p: Procs, router: Any) -> None:
    os.killpg(router.proc.pid, signal.SIGSTOP)
    try:
        time.sleep(FREEZE_S)
    finally:
        os.killpg(router.proc.pid, signal.SIGCONT)


def test_mc_power_has_status_again_after_a_takeover_of_a_live_active_nc(pair: Callable[..., Procs]) -> None:
    p = pair(max_age=int(2 * FREEZE_S / CYCLE))  # (the drive inputs stop with the router: no 0x4655 for that)
    router = p["router"]
    cl = NcTestClient(p["port"], client_id="obs", lease_ms=LEASE_MS, token=False)
    plc = _plc(p)
    try:
        act = wait_logged(lambda: (n := active_node(cl)) is not None and (n,), "the pair up", servers(p))[0]
        epoch = int((ha_status(cl, act) or {})["epoch"])
        wait_logged(lambda: (s := p["drives"].status()) is not None and s["connected"] and s["rx_count"] > 0,
                    "the drive host receiving outputs", servers(p))
        plc.wait_started()
        # (the NC started before its drive host: its remote axis began in 0x4651; MC_Reset, as the bench does)
        plc.set("pw", "MC_Power", Enable=True, Enable_Positive=True, Enable_Negative=True)
        plc.set("rs", "MC_Reset", Execute=True)
        plc.wait("rs", lambda r: r.o["Done"], T)
        power_on(plc)
        plc.wait_cycles(20)
        _freeze_router(p, router)
        other = "b" if act == "a" else "a"
        wait_logged(lambda: (s := ha_status(cl, other)) is not None and s["role"] == "active" and s["epoch"] > epoch,
                    f"{other} took over", servers(p))
        wait_logged(lambda: (s := p["drives"].status()) is not None and s["epoch"] > epoch,
                    "the drive host follows the new active NC", servers(p))
        plc.wait_cycles(100, T)
        # the PLC's MC_Power (Enable TRUE all along) has Status again, on the new active NC (its newest record)
        try:
            plc.wait("pw", lambda r: r.o["Status"] and not r.o["Error"], T)
        except AssertionError:
            raise AssertionError("MC_Power without Status after the takeover: " + "\n".join(map(repr, plc.history('pw')[-6:])) + "\n"
                                 + "".join(plc.err_lines[-30:])
                                 + "\n".join(f"--- {n}:\n{x.stderr()[-3000:]}" for n, x in servers(p).items()))
        restarts = [ln for ln in plc.err_lines if "restarted" in ln]
        r = plc.last("pw")
        assert r is not None and r.a["Valid"] and r.a["ErrorId"] == 0, r
        # (a restart seen: nc_epoch stepped, the claim made again; none: the same claim on the new NC. nc_epoch also
        # steps when the NC's token goes, without a "restarted" line: at least one step per restart logged)
        assert r.a["Epoch"] >= (1 if restarts else 0), (r, restarts)
        print(f"NC restarts seen by the PLC: {len(restarts)}, nc_epoch {r.a['Epoch']}")
    finally:
        try:
            plc.stop()
        finally:
            cl.close()
