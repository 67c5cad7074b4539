"""A status observer process for the namespace tests: ``observer.py ENDPOINT NC...``.

Runs a :class:`hostlib.StatusClient` (in the network namespace it was started in) and writes one
JSON line every 0.1 s to stdout: ``{"samples": [[nc, axis, t, cycle, state, error, act_pos,
set_velo], ...] (new since the last line), "info": {nc: Info value or null}}`` (Info every 0.5 s).
:class:`RemoteStatus` in test_netns.py reads it back. Ends on SIGTERM/SIGINT or stdin closing.
"""
from __future__ import annotations

import json
import signal
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/ (znc_testing)
from znc_testing.hostlib import StatusClient  # noqa: E402


def main(argv: list[str]) -> int:
    endpoint, ncs = argv[1], argv[2:]
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    st = StatusClient(endpoint, ncs, client_id="status")
    sent: dict[tuple[str, int], float] = {}
    next_info = 0.0
    try:
        while not stop.wait(0.1):
            rows = []
            for key in list(st.samples):
                for s in st.history(*key, since=sent.get(key, 0.0) + 1e-9):
                    rows.append([s.nc, s.axis, s.t, s.cycle, s.state, s.error, s.act_pos, s.set_velo])
                    sent[key] = s.t
            line: dict[str, object] = {"samples": rows}
            if time.monotonic() >= next_info:
                next_info = time.monotonic() + 0.5
                line["info"] = {nc: st.info(nc, timeout=1.0) for nc in ncs}
            sys.stdout.write(json.dumps(line) + "\n")
            sys.stdout.flush()
    finally:
        st.close()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
