"""The ADS server's own cost: unmodified pyads against nc_ads.server.AdsServer with the in-memory
FakeDevice (no NC, no zenoh), in this process (server in its own thread), over loopback.

Measured one at a time (p50 / p99 / max, microseconds): read_state (worker pool), read of an LREAL
(0x4001/0x27), read of the 256-byte struct (0x4101/0), write of an LREAL (these three on the server's
loop: FakeDevice says they never block), the same LREAL read through the worker pool, a sum read of 500 LREALs by name
(read_list_by_name, one 0xF080 request), and the delivery delay of 256-byte ServerCycle notifications
(client receive time minus the sample's FILETIME, 10 ms cycle). Not a test: speed lives here.

    .venv/bin/python bench/ads_server.py [--n 2000] [--tick-ms 2]
"""
from __future__ import annotations

import argparse
import ctypes
import sys
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from bench.common import Busy, use_this_tree, verdict  # noqa: E402

use_this_tree()  # this checkout and its test helpers (znc_testing)
import pyads  # noqa: E402

from znc_testing.ads_testing import PyadsSession, netid_for, start_server_on_free_address  # noqa: E402
from nc_ads import ams  # noqa: E402
from nc_ads.server import AdsServer  # noqa: E402
from nc_ads.testing import FakeDevice  # noqa: E402


def stats(name: str, us: list[float]) -> str:
    a = np.asarray(us)
    return f"{name:<34} n={len(a):5d}  p50 {np.percentile(a, 50):8.1f}  p99 {np.percentile(a, 99):8.1f}  max {a.max():8.1f} us"


def timed(fn, n: int, warm: int = 100) -> list[float]:
    for _ in range(warm):
        fn()
    out = []
    for _ in range(n):
        t = time.perf_counter()
        fn()
        out.append((time.perf_counter() - t) * 1e6)
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=2000)
    ap.add_argument("--tick-ms", type=float, default=2.0)
    args = ap.parse_args()
    dev = FakeDevice()
    _, srv = start_server_on_free_address(
        lambda h: (s := AdsServer({500: dev, 501: dev}, netid_for(h), (h, 48898), tick_ms=args.tick_ms)).start() or s)
    session = PyadsSession(srv)
    busy = Busy()
    try:
        plc = session.open(501)
        L = pyads.PLCTYPE_LREAL
        print(stats("read_state", timed(plc.read_state, args.n)))
        print(stats("read LREAL 0x4001/0x27", timed(lambda: plc.read(0x4001, 0x27, L), args.n)))
        print(stats("read 256 B 0x4101/0", timed(lambda: plc.read(0x4101, 0, ctypes.c_ubyte * 256,
                                                                  return_ctypes=True), args.n)))
        print(stats("write LREAL 0x4001/0x27", timed(lambda: plc.write(0x4001, 0x27, 1.0, L), args.n)))
        dev.inline_off = True   # the same read through the worker pool (a device that may block)
        print(stats("read LREAL via the worker pool", timed(lambda: plc.read(0x4001, 0x27, L), args.n)))
        dev.inline_off = False
        names = [f"GVL.v{i}" for i in range(500)]
        plc.read_list_by_name(names)   # symbol infos cached
        print(stats("sum read 500 LREAL by name", timed(lambda: plc.read_list_by_name(names), max(50, args.n // 20), 10)))
        delays: list[float] = []
        lock = threading.Lock()

        def cb(notification, name) -> None:
            now = time.time()
            stamp = notification.contents.nTimeStamp
            with lock:
                delays.append((now - ams.unix_from_filetime(stamp)) * 1e6)
        attr = pyads.NotificationAttrib(256, pyads.constants.ADSTRANS_SERVERCYCLE, 0, 10)
        h = plc.add_device_notification((0x4101, 0), attr, cb)
        time.sleep(max(3.0, args.n * 0.01 / 4))
        plc.del_device_notification(*h)
        with lock:
            print(stats("notification delay 256 B @10 ms", delays[10:]))
    finally:
        session.close()
        srv.close()
    print(f"the machine during the measurements: {busy.text()}")
    verdict("ads_server", [], busy.text())


if __name__ == "__main__":
    main()
