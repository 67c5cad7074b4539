"""Issue 19: a PLC client pays only for its own axes. It declares its view (a liveliness token
``nc/<nc>/select/<client>/<P>ms/<axes>``) and the NC's frame publisher puts the frame of those axes only on
``nc/<nc>/view/<client>``; the view follows the client's AXIS_REFs, ends with the token, and a malformed
token is ignored."""
from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Iterator

import pytest
import zenoh

from nc_schema import decode_frame, frame_header
from plc_client import AXIS_REF
from plc_client.runtime import PlcRuntime
from znc_testing import NcServerProcess, start_nc_server, wait_until, zenoh_client_config

T = 30.0

CONFIG = "[nc]\nname = \"nc1\"\ncycle_time = 0.001\nrealtime = \"off\"\n" + "".join(
    f"[[axis]]\nAxisId = {a}\nName = \"A{a}\"\n" for a in range(1, 9))


class ViewWatch:
    """A separate session that takes ``nc/nc1/view/<client>`` (AxisIds and Cycle of each frame)."""

    def __init__(self, port: int, client: str) -> None:
        self.session = zenoh.open(zenoh_client_config(port))
        self.frames: list[tuple[int, list[int]]] = []
        self.times: list[int] = []  # NcTimeNs of each frame
        self.attachments: list[bytes | None] = []  # the axes each frame was cut for
        self._lock = threading.Lock()
        self.sub = self.session.declare_subscriber(f"nc/nc1/view/{client}", self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        data = sample.payload.to_bytes()
        h, recs, _ = decode_frame(data)
        with self._lock:
            self.frames.append((int(h["Cycle"]), [int(a) for a in recs["AxisId"]]))
            self.times.append(int(h["NcTimeNs"]))
            self.attachments.append(None if sample.attachment is None else sample.attachment.to_bytes())

    def count(self) -> int:
        with self._lock:
            return len(self.frames)

    def last_ids(self) -> list[int] | None:
        with self._lock:
            return self.frames[-1][1] if self.frames else None

    def close(self) -> None:
        self.sub.undeclare()
        self.session.close()  # type: ignore[no-untyped-call]


@pytest.fixture
def nc(tmp_path: Path) -> Iterator[NcServerProcess]:
    proc = start_nc_server(tmp_path, CONFIG)
    try:
        yield proc
    finally:
        proc.stop()


def test_client_receives_only_its_axes_and_follows_new_ones(nc: NcServerProcess) -> None:
    watch = ViewWatch(nc.port, "viewplc")
    plc = PlcRuntime(None, {"nc1": nc.endpoint}, client_id="viewplc",
                     axes=[AXIS_REF("nc1", 5), AXIS_REF("nc1", 2)])
    try:
        assert plc.links["nc1"].view_period == 10  # (the PLC's 10 ms cycle: nc_schema.view_period_ms)
        plc.start()
        wait_until(lambda: watch.last_ids() == [2, 5], T, "view frames of axes 2 and 5")
        assert watch.attachments[-1] == b"2,5"  # the axes the frame was cut for
        ax2 = plc.axes[1] if plc.axes[1].axis_id == 2 else plc.axes[0]
        wait_until(lambda: ax2.NcToPlc["AxisId"] == 2 and ax2.Status.Disabled, T, "axis 2's data in the task")
        # once per 10 ms of NC time, not every cycle: no two frames in one 10-ms window of NcTimeNs
        n0 = watch.count()
        wait_until(lambda: watch.count() - n0 >= 40, T, "40 more view frames")
        windows = [t // 10_000_000 for t in watch.times[n0:]]
        assert all(b > a for a, b in zip(windows, windows[1:])), windows
        # an AXIS_REF bound later joins the view; the task reads it
        ax7 = plc.axis("nc1", 7)
        wait_until(lambda: watch.last_ids() == [2, 5, 7], T, "the view with axis 7")
        wait_until(lambda: ax7.NcToPlc["AxisId"] == 7, T, "axis 7's data in the task")
    finally:
        plc.stop()
        watch.close()


def test_view_ends_with_its_token_and_bad_tokens_are_ignored(nc: NcServerProcess) -> None:
    watch = ViewWatch(nc.port, "tok")
    bad = ViewWatch(nc.port, "bad")
    s = zenoh.open(zenoh_client_config(nc.port))
    try:
        for key in ("nc/nc1/select/bad/3ms/1", "nc/nc1/select/bad/5ms/2,1", "nc/nc1/select/bad/5ms/01",
                    "nc/nc1/select/bad/5ms/x", "nc/nc1/select/bad/5ms/1/2"):
            s.liveliness().declare_token(key)
        token = s.liveliness().declare_token("nc/nc1/select/tok/0ms/3,99")  # 99: not on this NC
        wait_until(lambda: watch.count() >= 100, T, "view frames of tok")
        assert watch.last_ids() == [3]
        assert watch.attachments[-1] == b"3,99"  # asked for, though the NC has no axis 99
        # every NC cycle (0 ms): frames of consecutive cycles (the publisher puts the newest frame: a loaded
        # machine may skip some, never all)
        cycles = [c for c, _ in watch.frames[-100:]]
        assert any(b - a == 1 for a, b in zip(cycles, cycles[1:])), cycles
        token.undeclare()
        # the view ends: no frame for 0.5 s (within the deadline)
        state = {"n": watch.count(), "since": 0.0}

        def quiet() -> bool:
            n = watch.count()
            now = time.monotonic()
            if n != state["n"] or not state["since"]:
                state["n"], state["since"] = n, now
                return False
            return now - state["since"] >= 0.5
        wait_until(quiet, T, "the view to stop after its token went")
        assert bad.count() == 0, "a malformed view token must be ignored"
        assert nc.proc.poll() is None
    finally:
        s.close()  # type: ignore[no-untyped-call]
        watch.close()
        bad.close()


def test_a_block_on_an_axis_bound_while_running_waits_for_its_view(nc: NcServerProcess) -> None:
    """An AXIS_REF made in a cycle and used at once: the NC sends its data a few ms later (its view token
    must reach the NC first); the block's call waits for it, so the command goes through; an axis the NC
    lacks ends with 0x4012 (the view frames list it as asked for), never 0x4B0F."""
    from plc_client import MC_ReadParameter

    got: dict[int, tuple[bool, bool, int, float]] = {}
    blocks: dict[int, tuple[AXIS_REF, MC_ReadParameter]] = {}
    plc = PlcRuntime(None, {"nc1": nc.endpoint}, client_id="lateplc", axes=[AXIS_REF("nc1", 2)])

    def program(task: object) -> None:
        if plc.axes[0].valid:  # the first view is there: bind two more axes and use them in the same cycle
            for a in (6, 99):
                if a not in blocks:
                    blocks[a] = (AXIS_REF("nc1", a), MC_ReadParameter())
        for a, (ax, fb) in blocks.items():
            fb(Axis=ax, Enable=True, ParameterNumber=1003)  # (MaxVelocity)
            if a not in got and (fb.Done or fb.Error):
                got[a] = (fb.Done, fb.Error, fb.ErrorID, float(fb.Value))

    plc.program = program
    try:
        plc.start()
        wait_until(lambda: len(got) == 2, T, "both reads to end")
        assert got[6][:3] == (True, False, 0) and got[6][3] > 0, got
        assert got[99][:3] == (False, True, 0x4012), got
    finally:
        plc.stop()


def test_a_client_without_axes_takes_a_view_of_none_at_the_slowest_period(nc: NcServerProcess) -> None:
    """A client with no axis on an NC (an idle plc-run) declares a view of none at IDLE_VIEW_PERIOD_MS: its
    frames hold no record, one per 100 ms of NC time (the NC is there: its cycle counter); an AXIS_REF bound
    later brings the client's own period (10 ms at a 10 ms cycle)."""
    watch = ViewWatch(nc.port, "idleplc")
    plc = PlcRuntime(None, {"nc1": nc.endpoint}, client_id="idleplc")
    try:
        plc.start()
        wait_until(lambda: watch.count() >= 4, T, "4 view frames of none")
        assert watch.attachments[-1] == b"none" and watch.last_ids() == []
        windows = [t // 100_000_000 for t in watch.times]
        assert all(b > a for a, b in zip(windows, windows[1:])), windows
        wait_until(lambda: "nc1" in plc._frames, T, "the task to take a frame of the NC")
        ax = plc.axis("nc1", 3)
        wait_until(lambda: watch.last_ids() == [3], T, "the view with axis 3")
        wait_until(lambda: ax.NcToPlc["AxisId"] == 3, T, "axis 3's data in the task")
        n0 = watch.count()
        wait_until(lambda: watch.count() - n0 >= 20, T, "20 more view frames")
        times = watch.times[n0:]
        assert all(b // 10_000_000 > a // 10_000_000 for a, b in zip(times, times[1:])), times
        assert min(b - a for a, b in zip(times, times[1:])) < 100_000_000, times  # no longer the idle period
    finally:
        plc.stop()
        watch.close()
