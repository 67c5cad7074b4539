"""A hot-standby pair with retain files, real processes over real zenoh on 127.0.0.1 (docs/standby.md, "Retain
files"): node ``a`` starts active with ``a.retain``, ``b`` standby with ``b.retain`` (two hosts: two files), or both
with ``a.retain`` (one host, one path: the lock decides who writes).

Only the active NC writes its file; kill -9 of the active NC during a standstill: the new active NC's file then
holds the axis position (its first snapshot at once after the takeover), and moves on it are kept there; the old
node restarted comes back as a standby in step and does not apply its stale file (nor write it).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Callable

import pytest

from nc_server.server.retain import RetainData, RetainError, parse_retain
from znc_testing import start_nc_router, start_nc_server
from znc_testing.remote_drives import DriveSim

from test_standby_process import (CONFIG, CYCLE, DRIVE_TIMEOUT, LEASE_MS, TAKEOVER_CYCLES, Procs, done, kill_active,
                                  move, servers, setup, took_over, wait_logged)
from znc_testing.standby_rig import close_all, ha_status


def retained(path: Path) -> RetainData | None:
    try:
        return parse_retain(path.read_bytes(), "nc1", [1])
    except (OSError, RetainError):
        return None


def holds(path: Path, pos: float) -> Callable[[], Any]:
    """The file holds axis 1 at ``pos`` (within 1e-3), at standstill."""
    def pred() -> bool:
        d = retained(path)
        a = None if d is None else d.axes.get(1)
        return a is not None and a.position is not None and abs(a.position - pos) < 1e-3 and bool(a.standstill)
    return pred


@pytest.mark.parametrize("shared", [False, True], ids=["two-files", "one-path"])
def test_kill_9_at_standstill_the_new_active_keeps_the_position_the_old_node_comes_back_standby(
        tmp_path: Path, shared: bool) -> None:
    started: list[Any] = []
    text = CONFIG.format(cycle=CYCLE, port="{port}", takeover=TAKEOVER_CYCLES)
    text = text.replace('Name = "X"\n', 'Name = "X"\nAxisEnDataPersistence = true\n')
    # (one-path: both nodes on one host name the same file; its lock decides who writes)
    fa, fb = tmp_path / "a.retain", tmp_path / ("a.retain" if shared else "b.retain")
    cl = tr = None
    try:
        router = start_nc_router(tmp_path / "router", ["--lease-ms", str(LEASE_MS)])
        started.append(router)
        text = text.replace("{port}", str(router.port))
        cfg = tmp_path / "nc.toml"
        cfg.write_text(text)

        def node(name: str, retain: Path, start: str, where: str) -> Any:
            args = ["--set", f"redundancy.node={name}", "--retain", str(retain)]
            if start == "active":
                args += ["--set", "redundancy.start=active"]
            h = start_nc_server(tmp_path / where, text, name="nc1", connect=router.endpoint, extra_args=args)
            started.append(h)
            return h

        p: Procs = {"a": node("a", fa, "active", "a"), "b": node("b", fb, "standby", "b")}
        sim = DriveSim(tmp_path, ["--config", str(cfg), "--host", "drives1", "--connect", router.endpoint,
                                  "--timeout", str(DRIVE_TIMEOUT), "--lease-ms", str(LEASE_MS)])
        started.append(sim)
        p.update(drives=sim, port=router.port, router=router)
        cl, tr = setup(p, [1])
        r, _ = move(cl, 1, 30.0)
        done(p, cl, 1, r["CmdNo"], 30.0)
        files = {"a": fa, "b": fb}
        old, new, epoch = kill_active(p, cl, ready=lambda: wait_logged(
            lambda: all(holds(files[n], 30.0)() for n in ("a", "b") if (ha_status(cl, n) or {}).get("role") == "active"),
            "the active NC's file holds 30 at standstill", servers(p)))
        if old == "a" and not shared:  # (no role change before: the standby never wrote its file)
            assert not fb.exists()
        took_over(p, cl, new, epoch)
        wait_logged(holds(files[new], 30.0), f"{new}'s file holds 30 (its first snapshot after the takeover)",
                    servers(p))
        r, _ = move(cl, 1, 12.5)
        done(p, cl, 1, r["CmdNo"], 12.5)
        wait_logged(holds(files[new], 12.5), f"{new}'s file holds 12.5", servers(p))
        stale = files[old].read_bytes()
        # the old node comes back (a standby): it follows the new one, and neither applies nor writes its stale file
        p[old] = node(old, files[old], "standby", f"{old}2")
        wait_logged(lambda: (s := ha_status(cl, old)) is not None and s["role"] == "standby" and s["in_step"],
                    f"{old} back, a standby in step", servers(p))
        x = cl.nctoplc(1)
        assert x is not None and abs(float(x["ActPos"]) - 12.5) < 1e-3, x
        st = ha_status(cl, new)
        assert st is not None and st["role"] == "active", st
        err = p[old].stderr()
        assert "loaded (saved" not in err and "does not exist yet" not in err, err[-3000:]
        assert "locked by this NC" not in err
        if not shared:
            assert files[old].read_bytes() == stale
        assert "locked by this NC" in p[new].stderr()  # (the takeover took the lock: the retain thread's line)
        print(f"{old} killed, {new} took over; {new}'s file holds 12.5; {old} back as a standby"
              + ("" if shared else ", its own file untouched"))
        assert holds(files[new], 12.5)()
    finally:
        close_all(tr, cl, started)
