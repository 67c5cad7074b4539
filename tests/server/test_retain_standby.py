"""The retain file in a hot-standby pair (docs/standby.md, "Retain files"): only the active NC locks and writes
its file; a standby takes the lock at its takeover and writes its own state (never applying the file); a lock held
by another process is no stop (the NC drives, its durable replies are not kept, the lock is tried every second);
a demotion releases the lock after the write in progress; only a cold start applies the file."""
from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

import pytest

import nc_server.core  # noqa: F401  (before nc_server.drives)
from nc_server.core import NcCore
from nc_server.server import retain as R
from nc_server.server.config import load_config
from nc_server.server.retain import AxisRetain, RetainData, RetainKeeper, encode_retain, parse_retain, write_atomic
from znc_testing import wait_until

from test_retain import EncoderAt5000, cmd, make_core, ok  # noqa: E402 (tests/server on sys.path)

T = 60.0  # (deadlines of waits for the retain thread; no timing is asserted)
AXES = [1, 2, 3, 4]


def stored(path: Path) -> RetainData:
    return parse_retain(path.read_bytes(), "nc1", AXES)


def save(path: Path, data: RetainData) -> None:
    write_atomic(path, encode_retain(data))


def locked_by_other(path: Path) -> bool:
    """Another keeper cannot take the lock of ``path`` (tried and released at once)."""
    probe = RetainKeeper(path, "nc1", make_core())
    try:
        probe._lock()
    except R.RetainLockError:
        return True
    probe.close()
    return False



def following_keeper(path: Path, core: Any) -> RetainKeeper:
    """A standby's keeper, started: it follows (no lock, no write) until resume()."""
    k = RetainKeeper(path, "nc1", core)
    k.follow()
    k.start()
    return k

def test_a_standby_keeper_holds_no_lock_and_writes_nothing(tmp_path: Path) -> None:
    path = tmp_path / "nc1.retain"
    save(path, RetainData("nc1", {1: AxisRetain("A1", 130.0, True, True, 0.0)}))
    before = path.read_bytes()
    core = make_core()
    k = following_keeper(path, core)
    try:
        k.tick(core)  # (not applied: no snapshot)
        c = k.commit(core)
        wait_until(lambda: k.settled >= c, T, "the commit to be settled")
        assert k.durable < c and not k.owner and not locked_by_other(path)
        assert path.read_bytes() == before and k.writes == 0
    finally:
        k.stop(core)
    assert path.read_bytes() == before  # (no final write of a standby)


def test_a_takeover_in_step_keeps_its_own_state_at_once(tmp_path: Path) -> None:
    path = tmp_path / "nc1.retain"
    save(path, RetainData("nc1", {1: AxisRetain("A1", 130.0, True, True, 0.0)}))  # an older state
    core = make_core()
    ok(cmd(core, "SetActualPosition", 1, Position=42.0))
    core.step()
    k = following_keeper(path, core)
    try:
        k.resume()
        wait_until(lambda: k.owner, T, "the lock")
        assert locked_by_other(path)
        k.tick(core)  # the first snapshot at once: written at once, the file is not applied
        wait_until(lambda: stored(path).axes[1].position == pytest.approx(42.0), T, "the takeover's state in the file")
        assert core.act_pos[0] == pytest.approx(42.0) and k.status == "new"
        ok(cmd(core, "WriteParameter", 2, ParameterNumber=int(R.MC_AxisPara.AxisVeloMax), Value=321.0))
        c = k.commit(core)  # durable replies work on the active NC
        wait_until(lambda: k.settled >= c, T, "the commit")
        assert k.durable == c and stored(path).axes[2].params["AxisVeloMax"][0] == 321.0
    finally:
        k.stop(core)
    assert not locked_by_other(path)


def test_a_held_lock_is_retried_and_durable_replies_are_not_kept_meanwhile(
        tmp_path: Path, caplog: pytest.LogCaptureFixture, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(R, "LOCK_RETRY_S", 0.05)
    path = tmp_path / "nc1.retain"
    old_core = make_core()
    old = RetainKeeper(path, "nc1", old_core)  # the old active NC, frozen on the same host, same path
    old.load()
    core = make_core()
    ok(cmd(core, "SetActualPosition", 1, Position=7.0))
    core.step()
    k = following_keeper(path, core)
    caplog.set_level(logging.INFO, logger="nc_server.server")
    try:
        k.resume()
        wait_until(lambda: k.lock_waits >= 3, T, "three tries of the lock")
        assert not k.owner
        c = k.commit(core)
        wait_until(lambda: k.settled >= c, T, "the commit to be settled")
        assert k.durable < c  # (its reply goes out as 0x4002: not kept)
        warned = [r for r in caplog.records if "drives without its retain file" in r.getMessage()]
        assert len(warned) == 1 and "in use by another process" in warned[0].getMessage()
        old.suspend()  # (the old NC demoted: it releases the lock)
        old._own()
        wait_until(lambda: k.owner, T, "the lock once released")
        k.tick(core)
        wait_until(lambda: path.exists() and stored(path).axes[1].position == pytest.approx(7.0), T, "the state")
    finally:
        k.stop(core)
        old.stop()


def test_a_demotion_releases_the_lock_and_stops_writing(tmp_path: Path) -> None:
    path = tmp_path / "nc1.retain"
    core = make_core()
    k = following_keeper(path, core)
    try:
        k.resume()
        k.tick(core)
        wait_until(lambda: path.exists() and stored(path).axes[1].position == 0.0, T, "the first snapshot")
        written = path.read_bytes()
        k.suspend()
        wait_until(lambda: not k.owner, T, "the lock released")
        assert not locked_by_other(path)
        ok(cmd(core, "SetActualPosition", 1, Position=99.0))
        core.step()
        k.tick(core)  # (a standby's cycle does not tick; nothing would be written anyway)
        c = k.commit(core)
        wait_until(lambda: k.settled >= c, T, "the commit")
        assert k.durable < c and path.read_bytes() == written
    finally:
        k.stop(core)
    assert path.read_bytes() == written  # (no final write: the last complete snapshot stays)


# ---- the server: which start applies the file ---------------------------------------------------------------
def pair_server(tmp_path: Path, start: str) -> Any:
    from nc_server.server.app import NcServer
    conf = tmp_path / "nc.toml"
    conf.write_text(f'[nc]\nname = "nc1"\nrealtime = "off"\nretain_file = "{tmp_path / "nc1.retain"}"\n'
                    '[zenoh]\nlisten = ["tcp/127.0.0.1:9"]\n'
                    f'[redundancy]\nenabled = true\nstart = "{start}"\nnode = "a"\n'
                    '[[axis]]\nAxisId = 1\nName = "A1"\nAxisEnDataPersistence = true\n')
    cfg = load_config(conf)  # (the redundancy with a retain file is accepted; zenoh is never opened here)
    assert cfg.redundancy.enabled and cfg.retain_file
    core = NcCore(list(cfg.axes), cfg.cycle_time, drive=EncoderAt5000([a.params for a in cfg.axes], cfg.cycle_time))
    server = NcServer(cfg, core)
    assert server.retain is not None and server.ha is not None and server.retain.managed
    steps: list[int] = []
    server.ha.before_cycle = lambda now: server.ha.role != "active"  # type: ignore[method-assign]
    server.ha.after_step = lambda: steps.append(int(server.core.cycle))  # type: ignore[method-assign]
    server.ha.after_stall = lambda gap: False  # type: ignore[method-assign]
    server.steps = steps
    return server


@pytest.mark.parametrize("followed", [False, True])
def test_only_a_cold_takeover_applies_the_file(tmp_path: Path, followed: bool) -> None:
    save(tmp_path / "nc1.retain", RetainData("nc1", {1: AxisRetain("A1", 130.0, True, True, 0.0)}))
    server = pair_server(tmp_path, "standby")
    retain, ha, core = server.retain, server.ha, server.core
    retain.start()
    try:
        assert retain.status == "new" and not server._retain_pending  # (a standby: nothing loaded, no lock)
        ha.followed = followed  # (in step from a snapshot once, or never: a cold start of the pair)
        ha.role = "active"
        server.became_active(time.monotonic(), serve=False)
        server.cycle(time.monotonic_ns())
        assert server.steps == [1]  # (the log of the first active cycle goes to the standby either way)
        if followed:
            assert retain.status == "new" and core.act_pos[0] == pytest.approx(5000.0)  # its own state, not the file's
            wait_until(lambda: retain.owner, T, "the lock")
            server.cycle(time.monotonic_ns())
            wait_until(lambda: stored(tmp_path / "nc1.retain").axes[1].position == pytest.approx(5000.0), T,
                       "its state in the file")
        else:
            assert retain.status == "loaded" and retain.applied and retain.owner
            assert core.act_pos[0] == pytest.approx(130.0) and core.axes.homed[0]
        ha.role = "standby"
        server.became_standby()
        wait_until(lambda: not retain.owner, T, "the lock released at the demotion")
        assert not locked_by_other(tmp_path / "nc1.retain")
    finally:
        retain.stop()


def test_a_start_as_active_applies_the_file_in_its_first_cycle(tmp_path: Path) -> None:
    save(tmp_path / "nc1.retain", RetainData("nc1", {1: AxisRetain("A1", 130.0, True, True, 0.0)}))
    server = pair_server(tmp_path, "active")
    retain, ha, core = server.retain, server.ha, server.core
    try:
        server.load_retain()  # (start() does it for start = "active")
        ha.role = "active"
        server.became_active(time.monotonic(), serve=False)  # (HotStandby.open: the first start; the file stays pending)
        assert server._retain_pending and retain.owner
        server.cycle(time.monotonic_ns())
        assert server.steps == [1] and retain.applied and core.act_pos[0] == pytest.approx(130.0)
    finally:
        retain.stop()


def test_a_cold_takeover_whose_file_is_locked_drives_without_it(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                                caplog: pytest.LogCaptureFixture) -> None:
    monkeypatch.setattr(R, "LOCK_RETRY_S", 0.05)
    path = tmp_path / "nc1.retain"
    save(path, RetainData("nc1", {1: AxisRetain("A1", 130.0, True, True, 0.0)}))
    other = RetainKeeper(path, "nc1", make_core())  # (another process's NC on the same path, frozen)
    other._lock()
    server = pair_server(tmp_path, "standby")
    retain, ha, core = server.retain, server.ha, server.core
    retain.start()
    try:
        ha.role = "active"
        server.became_active(time.monotonic(), serve=False)  # (never followed: a cold start)
        assert not server._retain_pending and retain.status == "new" and retain.applied
        assert any("this NC drives without applying it" in r.getMessage() for r in caplog.records)
        server.cycle(time.monotonic_ns())
        assert core.act_pos[0] == pytest.approx(5000.0)  # (the file is not applied)
        wait_until(lambda: retain.lock_waits >= 2, T, "tries of the lock")
        other.close()
        wait_until(lambda: retain.owner, T, "the lock once released")
        # (the next snapshot, within SNAPSHOT_PERIOD of cycles, is written at once: the file held another state)
        wait_until(lambda: (server.cycle(time.monotonic_ns()), stored(path).axes[1].position)[1]
                   == pytest.approx(5000.0), T, "its state in the file", interval=0.001)
    finally:
        retain.stop()
        other.close()


def test_a_retake_after_a_cold_takeover_without_the_lock_never_applies_the_file(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # (review of h3) a cold takeover found its lock taken and drove without its file; demoted before it ever
    # followed, it retakes from its own core: the file (possibly stale) must not be applied in the middle of a run
    monkeypatch.setattr(R, "LOCK_RETRY_S", 0.05)
    path = tmp_path / "nc1.retain"
    save(path, RetainData("nc1", {1: AxisRetain("A1", 130.0, True, True, 0.0)}))
    other = RetainKeeper(path, "nc1", make_core())
    other._lock()
    server = pair_server(tmp_path, "standby")
    retain, ha, core = server.retain, server.ha, server.core
    assert retain is not None and ha is not None
    retain.start()
    try:
        ha.role = "active"
        server.became_active(time.monotonic(), serve=False)
        server.cycle(time.monotonic_ns())
        assert core.act_pos[0] == pytest.approx(5000.0)  # (driving without its file)
        other.close()
        ha.role = "standby"
        server.became_standby()  # demoted, never followed
        wait_until(lambda: not retain.owner, T, "the lock released")
        ha.role = "active"
        server.became_active(time.monotonic(), serve=False)  # a retake from its own core
        server.cycle(time.monotonic_ns())
        assert core.act_pos[0] == pytest.approx(5000.0), "a retake applied the file in the middle of a run"
        assert not bool(core.axes.homed[0])
    finally:
        retain.stop()
        other.close()
