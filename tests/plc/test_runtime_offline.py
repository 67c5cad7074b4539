"""PlcRuntime and plc-run without an NC: nothing to connect to must not crash anything."""
from __future__ import annotations

import socket
import textwrap
from pathlib import Path

import pytest

from plc_client import AXIS_REF, MC_MoveAbsolute, MC_Power
from plc_client.cli import load_program, main, parse_ncs
from plc_client.runtime import PlcRuntime, client_config, default_client_id


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_runtime_without_nc_reports_4b0f_and_stops_cleanly() -> None:
    ax = AXIS_REF("nc1", 1)
    pw, mv = MC_Power(), MC_MoveAbsolute()
    seen: list[tuple[bool, int, bool, int]] = []

    def cycle(plc):
        pw(Axis=ax, Enable=True)
        mv(Axis=ax, Execute=True, Position=1.0, Velocity=1.0)
        seen.append((pw.Error, pw.ErrorID, mv.Error, mv.ErrorID))

    rt = PlcRuntime(cycle, {"nc1": f"tcp/127.0.0.1:{free_port()}"}, cycle_time=0.005, client_id="offline-test",
                    reconnect_period=0.05)
    assert rt.open() is False
    rt.run_for(0.2)
    assert len(seen) >= 10
    assert all(s == (True, 0x4B0F, True, 0x4B0F) for s in seen)
    assert not rt.connected("nc1") and rt.error is None
    rt.stop()  # idempotent


def test_runtime_program_exception_stops_the_runtime() -> None:
    def cycle(plc):
        if plc.cycle == 3:
            raise RuntimeError("boom")

    rt = PlcRuntime(cycle, {"nc1": f"tcp/127.0.0.1:{free_port()}"}, cycle_time=0.005, client_id="offline-test2")
    assert rt.run(5.0) == 1
    assert isinstance(rt.error, RuntimeError) and rt.cycle >= 3


def test_start_stop_in_a_thread() -> None:
    rt = PlcRuntime(lambda plc: None, {"nc1": f"tcp/127.0.0.1:{free_port()}"}, cycle_time=0.005,
                    client_id="offline-test3")
    t = rt.start()
    with pytest.raises(RuntimeError):
        rt.start()
    rt.stop()
    assert not t.is_alive() and rt.cycle > 0


def test_config_is_explicit() -> None:
    c = client_config("tcp/127.0.0.1:7447", 1000)
    assert c.get_json("mode") == '"client"'
    assert c.get_json("scouting/multicast/enabled") == "false"
    assert c.get_json("connect/endpoints") == '["tcp/127.0.0.1:7447"]'
    assert c.get_json("transport/link/tx/lease") == "1000"
    assert default_client_id().startswith("plc-")


def test_cli_arguments_and_program_loading(tmp_path: Path) -> None:
    assert parse_ncs(None) == {"nc1": "tcp/127.0.0.1:7447"}
    assert parse_ncs(["a=tcp/1.2.3.4:1", "b=tcp/1.2.3.4:2"]) == {"a": "tcp/1.2.3.4:1", "b": "tcp/1.2.3.4:2"}
    for bad in (["nc1"], ["=tcp/x:1"], ["a=x", "a=y"]):
        with pytest.raises(ValueError):
            parse_ncs(bad)
    prog = tmp_path / "prog.py"
    prog.write_text(textwrap.dedent("""
        class Program:
            def __init__(self):
                self.n = 0
            def cycle(self):
                self.n += 1
    """))
    assert type(load_program(str(prog))).__name__ == "Program"
    empty = tmp_path / "empty.py"
    empty.write_text("x = 1\n")
    assert main([str(empty)]) == 2
    broken = tmp_path / "broken.py"
    broken.write_text("def cycle(plc):\n  return (\n")
    assert main([str(broken)]) == 2
    assert main([str(prog), "--nc", "nc1"]) == 2
    assert main([str(prog), "--nc", f"nc1=tcp/127.0.0.1:{free_port()}", "--duration", "0.1",
                 "--client-id", "cli-test"]) == 0
    assert main([str(prog), "--client-id", "bad id!", "--duration", "0.1"]) == 2
