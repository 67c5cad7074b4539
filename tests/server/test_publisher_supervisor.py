"""The frame publisher's supervisor (nc_server/server/publisher.py PublisherProcess): process work off the I/O thread."""
from __future__ import annotations

import threading

import pytest

from nc_server.server.publisher import FrameOutput, PublisherProcess
from znc_testing import wait_until

pytestmark = pytest.mark.skipif(not hasattr(__import__("os"), "pidfd_open"), reason="needs Linux")


def test_the_io_threads_watch_never_forks_and_the_supervisor_does() -> None:
    """The NC's SCHED_FIFO I/O thread calls watch() every 0.1 s: it used to start the due child itself (fork and
    exec, and kill and wait), holding replies and stats back meanwhile. The supervisor thread does it now."""
    out = FrameOutput("nc1", 1)
    pp = PublisherProcess(out, "nc1", [1], settings=None)
    launched: list[str] = []

    def launch() -> None:  # (records who starts a child; starts none: the supervisor logs and goes on)
        launched.append(threading.current_thread().name)
        raise RuntimeError("no child in this test")

    pp._launch = launch  # type: ignore[method-assign]
    pp._restart_at, pp._first_standby = 0.0, False  # a restart is due
    try:
        pp.watch()  # (what the I/O thread does)
        assert launched == []
        pp._watcher = threading.Thread(target=pp._supervise, name="nc-publisher-watch", daemon=True)
        pp._watcher.start()
        wait_until(lambda: launched or None, 10.0, "the supervisor to start the due child")
        assert launched[0] == "nc-publisher-watch"
    finally:
        pp.stop(timeout=1.0)
        out.close()
