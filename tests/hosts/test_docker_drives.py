"""Drives in their own container (deploy/compose.drives.yaml over deploy/compose.yaml), end to end.

One compose project: router, nc1 (its axes 1 and 2 on remote CiA 402 drives, deploy/drives/nc1.toml),
nc-drives (``nc-drive-sim --host drives1``) and plc2, which powers nc1 axis 2 and shuttles it (ZNC_SHARE_S=0: it
leaves axis 1 alone). The test watches nc1's frames and the drive host's status key
``nc/nc1/drive/drives1/status`` through the router (as the observer ``status``, which the ACL lets read it).

The scenario: axis 2 moves on its remote drive; ``docker kill`` nc1: the drive container runs on, its drives
see the NC go silent, stop on their own quick-stop ramp with 0x8130 and keep their positions; ``docker start``
nc1: the NC reads the kept position, plc2's MC_Reset acknowledges the drive fault, and axis 2 moves again.

Uses the images the other Docker tests build (session fixture ``znc_image``); about 1-2 minutes on the 2-core VM.
"""
from __future__ import annotations

import threading
import time
from collections import deque
from pathlib import Path
from typing import Any, Iterator

import msgpack
import pytest
import zenoh

from znc_testing.hostlib import FIGURES, ROOT, StatusClient, cell_ok
from znc_testing import wait_until

from test_docker import COMPOSE_FILE, RECOVER_TIMEOUT, UP_TIMEOUT, ComposeSystem  # noqa: E402 (tests/hosts on sys.path)

pytestmark = [pytest.mark.timeout(1800)]  # the first test may build the images (minutes, cold)

DRIVES_FILE = ROOT / "deploy" / "compose.drives.yaml"
SERVICES = ("router", "nc1", "nc-drives", "plc2")
HOLDERS = {("nc1", 2): "plc2"}
STATUS_KEY = "nc/nc1/drive/drives1/status"
#: nc1's axis 2 on the drive host: slot 1 (deploy/drives/nc1.toml: AxisEncoderScalingFactor 1, so inc = u)
SLOT = 1
#: the drives' silence timeout [s] (ZNC_DRIVE_TIMEOUT_S; compose.drives.yaml's default 0.1 s): 0.3 s here, as the NC
#: in a container on the loaded 2-core VM (load ~20) went silent for over 100 ms about every 4 s
DRIVE_TIMEOUT = 0.3
#: the drive's stop after the NC's loss: the silence timeout at plc2's 300 u/s, then the quick-stop ramp (AxisDec
#: 5000 u/s^2: 9 u); what the status client saw last may be ~0.5 s older (10 Hz frames on a loaded machine): a
#: generous bound on how far the drive may go after the NC's last frame [u]
STOP_TRAVEL = 300.0 * (DRIVE_TIMEOUT + 0.6) + 9.0


class DriveStatus:
    """The drive host's status messages (msgpack, about every 100 ms), with their arrival time."""

    def __init__(self, session: zenoh.Session) -> None:
        self._lock = threading.Lock()
        self.items: deque[tuple[float, dict[str, Any]]] = deque(maxlen=10_000)
        self._sub = session.declare_subscriber(STATUS_KEY, self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        try:
            d = msgpack.unpackb(sample.payload.to_bytes(), raw=False, strict_map_key=False)
        except Exception:
            return
        if isinstance(d, dict):
            with self._lock:
                self.items.append((time.time(), d))

    def since(self, t: float) -> list[dict[str, Any]]:
        with self._lock:
            return [d for ts, d in self.items if ts >= t]

    def latest(self) -> dict[str, Any] | None:
        with self._lock:
            return self.items[-1][1] if self.items else None

    def close(self) -> None:
        try:
            self._sub.undeclare()
        except Exception:
            pass


@pytest.fixture(scope="module")
def drives_system(znc_image: str, tmp_path_factory: pytest.TempPathFactory) -> Iterator[ComposeSystem]:
    s = ComposeSystem(znc_image, tmp_path_factory.mktemp("compose-drives"), files=(COMPOSE_FILE, DRIVES_FILE),
                      services=SERVICES, plcs=("plc2",), identities=("nc1", "plc2", "status", "drives1"),
                      env={"ZNC_SHARE_S": "0", "ZNC_DRIVE_TIMEOUT_S": str(DRIVE_TIMEOUT)})
    try:
        t0 = time.monotonic()
        s.up()
        s.status = StatusClient(f"{s.transport}/127.0.0.1:{s.port}", ncs=("nc1",), tls_dir=s.status_tls())
        t_up = time.time()
        try:
            wait_until(lambda: cell_ok(s.status, HOLDERS, moved_since=t_up), UP_TIMEOUT,  # type: ignore[arg-type]
                       "plc2 holding nc1 axis 2 (a remote drive) and moving it", interval=0.25)
        except AssertionError as exc:
            raise AssertionError(f"{exc}; {s.diagnosis()}") from None
        FIGURES["scenarios"].append({"where": "docker", "scenario": "drives: compose up -> axis 2 moving",
                                     "react_s": None, "recover_s": round(time.monotonic() - t0, 2),
                                     "notes": f"project {s.project}, {s.transport}"})
        yield s
    finally:
        s.down()


def _axis(st: dict[str, Any]) -> dict[str, Any]:
    return st["axes"][SLOT]


def test_killing_the_nc_leaves_the_drives_stopped_in_place(drives_system: ComposeSystem) -> None:
    system = drives_system
    st = system.status
    assert st is not None
    drives = DriveStatus(st.session)
    try:
        # the drive host serves nc1's axes 1, 2; axis 2 enabled and on its way between 0 and 200 (plc2's shuttle)
        def driving() -> bool | str:
            d = drives.latest()
            if d is None:
                return "no drive status yet"
            a = _axis(d)
            return (d["connected"] and not d["nc_silent"] and a["AxisId"] == 2 and a["state"] == "OPERATION_ENABLED"
                    and abs(a["velocity"]) > 100 and 60 <= a["position"] <= 140) or f"drive status {a}"
        wait_until(driving, RECOVER_TIMEOUT, "axis 2's drive enabled and halfway", interval=0.02)
        drive_started = system.started("nc-drives")
        last_nc = st.latest("nc1", 2)
        assert last_nc is not None

        t_cut = time.time()
        system.docker("kill", system.cid("nc1"))

        # the drive container runs on; its drives stop on their own ramp with the communication fault
        def stopped() -> bool | str:
            got = drives.since(t_cut)
            if not got:
                return "no drive status since the kill"
            d = got[-1]
            bad = [a for a in d["axes"] if a["velocity"] != 0.0 or a["error_code"] != 0x8130 or a["state"] != "FAULT"]
            return (d["nc_silent"] and not bad) or f"nc_silent {d['nc_silent']}, axes {d['axes']}"
        wait_until(stopped, 60.0, "the drives stopped with 0x8130 after the NC's kill", interval=0.1)
        t_stop = time.time() - t_cut
        stop_pos = _axis(drives.latest() or {})["position"]
        # positions kept: unchanged over the next statuses (>= 1.5 s)
        t_hold = time.time()
        wait_until(lambda: len(drives.since(t_hold)) >= 10 and time.time() - t_hold >= 1.5, 30.0,
                   "ten drive statuses over 1.5 s", interval=0.1)
        held = [_axis(d)["position"] for d in drives.since(t_hold)]
        assert all(p == stop_pos for p in held), f"the stopped drive moved: {held}"
        # stopped near where the NC last saw it: no run-away. On its way (its quick stop, not at the shuttle's end)
        # when the NC's last frame (after the kill: a loaded docker kill took ~0.6 s once, the axis reached its target
        # meanwhile) still showed it moving between the ends
        final_nc = st.latest("nc1", 2) or last_nc
        if abs(final_nc.set_velo) > 0 and 1.0 < final_nc.act_pos < 199.0:
            assert 1.0 < stop_pos < 199.0, (stop_pos, final_nc)
        assert abs(stop_pos - final_nc.act_pos) <= STOP_TRAVEL + abs(final_nc.set_velo) * (t_cut - last_nc.t), \
            (stop_pos, last_nc, final_nc)
        assert system.docker("inspect", "-f", "{{.State.Running}}", system.cid("nc-drives")) == "true"
        assert system.started("nc-drives") == drive_started, "the drive container was restarted"
        assert "communication fault 0x8130, quick stop" in system.logs("nc-drives")

        # the NC back: it reads the kept position; plc2's MC_Reset acknowledges the drive fault; axis 2 moves again
        t_restore = time.time()
        system.docker("start", system.cid("nc1"))
        wait_until(lambda: (st.latest("nc1", 2) or last_nc).t > t_restore, RECOVER_TIMEOUT,
                   "nc1's frames again", interval=0.1)
        wait_until(lambda: cell_ok(st, HOLDERS, moved_since=t_restore), RECOVER_TIMEOUT,  # type: ignore[arg-type]
                   "axis 2 reset, enabled and moving again after nc1's restart", interval=0.25)
        # before it moved again (plc2 resets 0.5 s after the error), the restarted NC showed the kept position
        after = st.history("nc1", 2, t_restore)
        before_move = after[:next(i for i, x in enumerate(after) if x.moving)]
        assert any(abs(x.act_pos - stop_pos) < 1e-6 for x in before_move), \
            (stop_pos, [(x.act_pos, hex(x.error)) for x in before_move][-20:])
        t_rec = time.time() - t_restore
        d = drives.latest()
        assert d is not None and not d["nc_silent"] and _axis(d)["error_code"] == 0
        FIGURES["scenarios"].append({"where": "docker", "scenario": "drives: nc1 kill -> drives stop, kept",
                                     "react_s": round(t_stop, 2), "recover_s": round(t_rec, 2),
                                     "notes": f"stopped at {stop_pos:.3f} (NC last {last_nc.act_pos:.3f})"})
    except AssertionError as exc:
        raise AssertionError(f"{exc}\n{system.diagnosis()}") from None
    finally:
        drives.close()
