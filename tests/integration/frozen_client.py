"""A controlling PLC client run as its own process (for the watchdog test).

It claims an axis, publishes enabling PLCTONC frames every 10 ms, starts MoveVelocity and prints
one JSON line ``{"moving": true, ...}``; then it idles until killed. The test freezes it with
SIGSTOP and expects the NC to stop the axis.

Usage: python frozen_client.py PORT CLIENT_ID AXIS VELOCITY
"""
from __future__ import annotations

import json
import signal
import sys
import threading
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/ (znc_testing)

from znc_testing import BIT_CONTROL_LOOP_CLOSED, NcTestClient, wait_until  # noqa: E402


def main() -> int:
    port, client_id, axis, velocity = int(sys.argv[1]), sys.argv[2], int(sys.argv[3]), float(sys.argv[4])
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    cl = NcTestClient(port, client_id)
    try:
        cl.claim(axis, timeout=30)
        cl.feed_plctonc([axis])
        wait_until(lambda: (s := cl.nctoplc(axis)) is not None and int(s["StateDWord"]) & BIT_CONTROL_LOOP_CLOSED,
                   30, "axis enabled")
        r = wait_until(lambda: (x := cl.request("MoveVelocity", axis=axis, Velocity=velocity))["error"] == 0 and x,
                       30, "MoveVelocity accepted")
        print(json.dumps({"moving": True, "CmdNo": r["CmdNo"]}), flush=True)
        stop.wait()
    finally:
        cl.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
