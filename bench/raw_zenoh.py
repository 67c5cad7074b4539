"""The raw zenoh baseline the benchmarks compare against: a trivial queryable in a router process.

Same topology as a client talking to nc-server (client session -> router process on 127.0.0.1),
so a ratio against it isolates what zenoh-nc adds.
"""
from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
from typing import Iterator

RAW_KEY = "bench/raw"

RAW_SERVER = r"""
import json, sys, zenoh
port = int(sys.argv[1])
c = zenoh.Config()
c.insert_json5("mode", '"router"')
c.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
c.insert_json5("scouting/multicast/enabled", "false")
c.insert_json5("scouting/gossip/enabled", "false")
with zenoh.open(c) as s:
    def on_query(q):
        with q:
            q.reply(q.key_expr, b"ok")
    qbl = s.declare_queryable("bench/raw", on_query)
    print("ready", flush=True)
    sys.stdin.read()
"""


@contextlib.contextmanager
def raw_queryable(port: int) -> Iterator[int]:
    """Run the raw queryable router on tcp/127.0.0.1:``port``; yields the port, kills it on exit.

    Raises:
        RuntimeError: it did not start.
    """
    proc = subprocess.Popen([sys.executable, "-c", RAW_SERVER, str(port)], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True, start_new_session=True)
    try:
        assert proc.stdout is not None
        if proc.stdout.readline().strip() != "ready":
            raise RuntimeError("raw queryable did not start")
        yield port
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(10)
