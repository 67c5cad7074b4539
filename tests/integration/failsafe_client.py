"""A zenoh client process for the fail-safe tests (failsafe_support.ClientProcess): killed or frozen
by the test while it holds axes and/or has commanded motions.

Usage: python failsafe_client.py '{"port": P, "client": ID, "hold": [axes], "commands": [[cmd, axis, {args}]],
"lease_ms": 500, "nc": "nc1"}'

It claims and feeds the ``hold`` axes (Enable + feed enables every 10 ms), waits until they are
enabled, sends ``commands`` (each retried until accepted), prints ``{"ready": true, "replies": [...]}``
and idles until SIGTERM/SIGKILL.
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
    spec = json.loads(sys.argv[1])
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    cl = NcTestClient(int(spec["port"]), spec["client"], nc=spec.get("nc", "nc1"), lease_ms=int(spec.get("lease_ms", 500)))
    try:
        wait_until(lambda: cl.request("Info")["error"] == 0, 30, "the NC answers")
        hold = [int(a) for a in spec.get("hold", [])]
        for a in hold:
            cl.claim(a, timeout=30)
        if hold:
            cl.feed_plctonc(hold)
            for a in hold:
                wait_until(lambda a=a: (s := cl.nctoplc(a)) is not None and int(s["StateDWord"]) & BIT_CONTROL_LOOP_CLOSED,
                           30, f"axis {a} enabled")
        replies = []
        for cmd, axis, args in spec.get("commands", []):
            replies.append(wait_until(lambda: (r := cl.request(cmd, axis=axis, **args))["error"] == 0 and r, 30,
                                      f"{cmd} on axis {axis} accepted"))
        print(json.dumps({"ready": True, "replies": replies}), flush=True)
        stop.wait()
    finally:
        cl.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
