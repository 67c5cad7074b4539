"""Example 10 run as its docstring says: ``nc-server --config examples/10_canopen_axes.toml --listen
tcp/127.0.0.1:PORT`` (four axes on CANopen drives of python-can's virtual bus, simulated slaves in the NC's
process) and ``plc-run examples/10_canopen_axes.py --nc nc1=tcp/127.0.0.1:PORT``, ending by itself with exit code
0 after two round trips of every axis. Real processes, a real zenoh session on a free port; generous deadlines
(loaded 2-core machine); every process is killed with its process group."""
from __future__ import annotations

import re
from typing import Callable

from znc_testing import NcServerProcess
from znc_testing.plc_harness import EXAMPLES, run_example


def test_example_10_canopen_axes(start_nc: Callable[..., NcServerProcess]) -> None:
    nc = start_nc(extra_args=("--config", str(EXAMPLES / "10_canopen_axes.toml")))
    assert "4 axes" in (nc.ready_line() or ""), nc.ready_line()
    rc, out = run_example("10_canopen_axes.py", nc.endpoint, timeout=150.0)
    assert rc == 0, f"example 10 exited {rc}:\n{out[-3000:]}\nnc-server stderr:\n{nc.stderr()[-2000:]}"
    assert "demo motion on CANopen drives done" in out, out
    for name in ("X", "Y", "Z", "C"):
        assert re.search(rf"^{name}: leg 4 done at ", out, re.M), out
    assert "error 0x" not in out, out
