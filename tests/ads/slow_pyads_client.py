"""A pyads client with a slow notification callback, as a process of its own (tests/ads/test_nc_ads_abuse.py).

    python slow_pyads_client.py NETID HOST COUNT

Adds COUNT ServerCycle notifications (0x4101, 256 bytes, 1 ms) whose callback sleeps 20 ms, prints ``ready``
and keeps them until its standard input closes, then exits at once. It never deletes them: AdsLib can crash
(SIGSEGV) when a notification is deleted while its callback runs (ads-bridge-notes pitfall 8), and a crash
of the test peer must not take the test runner with it. nc-ads frees them when the connection closes.
"""
from __future__ import annotations

import os
import sys
import time
from typing import Any

import pyads


def main() -> None:
    netid, host, count = sys.argv[1], sys.argv[2], int(sys.argv[3])
    plc = pyads.Connection(netid, 501, host)
    plc.open()

    def slow(*_: Any) -> None:
        time.sleep(0.02)

    attr = pyads.NotificationAttrib(256, pyads.ADSTRANS_SERVERCYCLE, 0, 1)
    for _ in range(count):
        plc.add_device_notification((0x4101, 0), attr, slow)
    print("ready", flush=True)
    sys.stdin.read()  # until the test closes it (or dies)
    os._exit(0)  # no AdsLib teardown while callbacks may run: the kernel closes the socket


if __name__ == "__main__":
    main()
