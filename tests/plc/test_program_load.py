"""Loading a program file: the AXIS_REFs it declares are bound at load (valid without any block call),
and its arguments (plc-run --arg NAME=VALUE, program_args) are typed and checked."""
from __future__ import annotations

import textwrap
from pathlib import Path

import pytest

from nc_server.core import NcCore
from nc_server.core.params import AxisConfig
from nc_sim import InProcessPlc, run_cycles
from plc_client import AXIS_REF, ProgramArgsError, program_args
from plc_client.cli import main
from plc_client.program import load, parse_program_args


def write(tmp_path: Path, text: str, name: str = "prog.py") -> Path:
    p = tmp_path / name
    p.write_text(textwrap.dedent(text))
    return p


MONITOR = """
    from plc_client import AXIS_REF
    X = AXIS_REF(nc="nc1", axis_id=1)
    AXES = [AXIS_REF(nc="nc1", axis_id=2)]
    seen = []

    def cycle(plc):
        seen.append((X.Status.Valid, X.NcToPlc.AxisId, AXES[0].Status.Valid, AXES[0].NcToPlc.AxisId))
"""


def test_declared_axes_are_bound_at_load_and_valid_without_blocks(tmp_path: Path) -> None:
    loaded = load(str(write(tmp_path, MONITOR)))
    mod = loaded.module
    assert [a.axis_id for a in loaded.axes] == [1, 2]
    assert all(a.task is None for a in loaded.axes)
    core = NcCore([AxisConfig(AxisId=1), AxisConfig(AxisId=2)], cycle_time=0.001)
    plc = InProcessPlc(core, loaded.program, axes=loaded.axes)
    assert all(a.task is plc for a in loaded.axes)  # bound before the first cycle
    run_cycles(core, plc, 3)
    assert mod.seen[-1] == (True, 1, True, 2)  # NcToPlc filled and Valid, no MC_ReadStatus anywhere
    assert mod.X.Status.Disabled and mod.X.Status.NcCycleCounter == int(core.cycle) - 1


def test_without_binding_the_axis_stays_empty(tmp_path: Path) -> None:
    """The old behaviour (what binding at load fixes): an unused AXIS_REF stays all zeros."""
    loaded = load(str(write(tmp_path, MONITOR)))
    core = NcCore([AxisConfig(AxisId=1), AxisConfig(AxisId=2)], cycle_time=0.001)
    run_cycles(core, InProcessPlc(core, loaded.program), 3)
    assert loaded.module.seen[-1] == (False, 0, False, 0)


def test_axes_of_a_program_class_and_of_neighbour_modules(tmp_path: Path) -> None:
    write(tmp_path, "from plc_client import AXIS_REF\nCELL = {'a': AXIS_REF(nc='nc1', axis_id=3)}\n", "cell_axes.py")
    p = write(tmp_path, """
        from plc_client import AXIS_REF
        import cell_axes
        from cell_axes import CELL
        AXIS_REF(nc="nc1", axis_id=9)   # a temporary: not kept, not bound

        class Program:
            def __init__(self):
                self.x = AXIS_REF(nc="nc1", axis_id=1)
                self.pair = (AXIS_REF(nc="nc1", axis_id=2), 5)

            def cycle(self):
                pass
    """)
    import sys
    sys.modules.pop("cell_axes", None)
    ids = sorted(a.axis_id for a in load(str(p)).axes)
    assert ids == [1, 2, 3]


def test_already_bound_axes_are_left_alone() -> None:
    core = NcCore([AxisConfig(AxisId=1)], cycle_time=0.001)
    a = InProcessPlc(core)
    x = a.axis("nc1", 1)
    b = InProcessPlc(core, client_id="plc2", axes=[x, AXIS_REF(nc="nc1", axis_id=1)])
    assert x.task is a and len(b.axes) == 1


ARGS = """
    from plc_client import AXIS_REF, program_args
    args = program_args(speed=200.0, axis=1, verbose=False, label="cell", anything=None)
    X = AXIS_REF(nc="nc1", axis_id=args.axis)

    def cycle(plc):
        pass
"""


def test_program_args_are_typed_by_their_defaults(tmp_path: Path) -> None:
    p = str(write(tmp_path, ARGS))
    loaded = load(p, parse_program_args(["speed=300", "axis=02", "verbose=TRUE", "label=a=b", "anything=0x10"]))
    a = loaded.module.args
    assert a == {"speed": 300.0, "axis": 2, "verbose": True, "label": "a=b", "anything": 16}
    assert type(a.speed) is float and a["axis"] == 2 and loaded.args == a
    assert [x.axis_id for x in loaded.axes] == [2]  # an axis id from an argument
    assert dict(load(p).module.args) == {"speed": 200.0, "axis": 1, "verbose": False, "label": "cell",
                                         "anything": None}
    with pytest.raises(AttributeError):
        a.speed = 1.0


@pytest.mark.parametrize("items,message", [
    (["speed=fast"], "speed must be a finite number (default 200.0)"),
    (["speed=nan"], "speed must be a finite number"),
    (["axis=1.5"], "axis must be an integer (default 1)"),
    (["verbose=maybe"], "verbose must be true or false"),
    (["speeed=3"], "has no argument 'speeed' (it declares: anything, axis, label, speed, verbose)"),
])
def test_bad_program_args(tmp_path: Path, items: list[str], message: str) -> None:
    with pytest.raises(ProgramArgsError, match=message.replace("(", r"\(").replace(")", r"\)")):
        load(str(write(tmp_path, ARGS)), parse_program_args(items))


@pytest.mark.parametrize("items,message", [
    (["speed"], "expected NAME=VALUE"), (["1x=2"], "expected NAME=VALUE"), (["a=1", "a=2"], "given twice"),
])
def test_malformed_args(items: list[str], message: str) -> None:
    with pytest.raises(ProgramArgsError, match=message):
        parse_program_args(items)


def test_a_program_without_program_args_takes_none(tmp_path: Path) -> None:
    p = str(write(tmp_path, "def cycle(plc):\n    pass\n"))
    load(p)  # no arguments: fine
    with pytest.raises(ProgramArgsError, match="takes no arguments"):
        load(p, {"speed": "3"})


def test_open_ended_program_args(tmp_path: Path) -> None:
    p = str(write(tmp_path, "from plc_client import program_args\nargs = program_args()\ndef cycle(plc):\n    pass\n"))
    assert dict(load(p, parse_program_args(["a=1", "b=2.5", "c=x", "d=false"])).module.args) == \
        {"a": 1, "b": 2.5, "c": "x", "d": False}


def test_program_args_outside_plc_run_are_the_defaults() -> None:
    assert dict(program_args(speed=1.0)) == {"speed": 1.0}
    with pytest.raises(TypeError):
        program_args(speed=[1, 2])


def test_plc_run_bad_argument_exits_2_without_traceback(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    p = str(write(tmp_path, ARGS))
    assert main([p, "--arg", "speed=fast", "--nc", "nc1=tcp/127.0.0.1:1"]) == 2
    err = capsys.readouterr().err
    assert err.strip() == "plc-run: --arg speed=fast: speed must be a finite number (default 200.0)"
    assert main([p, "--arg", "nonsense"]) == 2
    assert "expected NAME=VALUE" in capsys.readouterr().err
    assert main([p, "--arg", "nope=1"]) == 2
    assert "has no argument 'nope'" in capsys.readouterr().err


LAZY = """
    from plc_client import AXIS_REF
    X = None
    seen = []

    def cycle(plc):
        global X
        if X is None:
            X = AXIS_REF(nc="nc1", axis_id=2)   # created on first use, in a cycle, no block ever called
        seen.append((X.Status.Valid, X.NcToPlc.AxisId))
"""


def test_an_axis_created_in_a_cycle_is_bound_at_creation(tmp_path: Path) -> None:
    loaded = load(str(write(tmp_path, LAZY)))
    assert loaded.axes == []
    core = NcCore([AxisConfig(AxisId=1), AxisConfig(AxisId=2)], cycle_time=0.001)
    plc = InProcessPlc(core, loaded.program)
    run_cycles(core, plc, 4)
    assert loaded.module.X.task is plc and plc.axes == [loaded.module.X]  # bound once, not per cycle
    assert loaded.module.seen[-1] == (True, 2)  # valid data without any block call
    # outside a cycle an AXIS_REF stays unbound until used
    assert AXIS_REF(nc="nc1", axis_id=1).task is None


def test_program_args_asked_only_in_a_cycle_is_named_at_load(tmp_path: Path) -> None:
    """program_args() in cycle() is not seen while the file loads: --arg is refused, saying where to call it."""
    p = write(tmp_path, """
        from plc_client import program_args
        def cycle(plc):
            args = program_args(speed=1.0)
    """)
    with pytest.raises(ProgramArgsError, match=r"takes no arguments .*module level or in Program.__init__"):
        load(str(p), {"speed": "2"})
