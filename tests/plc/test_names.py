"""Names as a TwinCAT programmer writes them (issue 17): Structured Text ignores case, so every declared
function block input and output answers in any case (``fb.ErrorId is fb.ErrorID``, ``fb(execute=True)``),
once in ``FunctionBlock``; ``MC_JOGMODE_CONTINUOUS`` beside Tc2_MC2's ``MC_JOGMODE_CONTINOUS``; the data
types the manual's blocks use are importable from ``plc_client``."""
from __future__ import annotations

import math
from typing import Any, ClassVar

import pytest

import plc_client
from nc_schema import E_JogMode
from plc_client import AXIS_REF, MC_GearIn, MC_MoveAbsolute, MC_MoveVelocity, MC_TouchProbe
from plc_client.fb.base import ExecuteBlock, FunctionBlock
from znc_testing.plc_rig import Rig, all_blocks, powered




def _instances() -> list[FunctionBlock]:
    """One instance of every concrete block (the abstract helpers that cannot be built are left out)."""
    out = []
    for c in all_blocks():
        try:
            out.append(c())
        except Exception:  # (an abstract base: built only through its subclasses)
            continue
    return out


BLOCKS = _instances()
#: the inputs whose change starts something (left alone by the generic write test)
TRIGGERS = {"Execute", "Enable", "START", "STOP", "JogForward", "JogBackward"}


def _spellings(name: str) -> set[str]:
    return {name.lower(), name.upper(), name.swapcase(), name[:1].lower() + name[1:]} - {name}


@pytest.mark.parametrize("fb", BLOCKS, ids=lambda fb: type(fb).__name__)
def test_every_declared_name_reads_in_any_case(fb: FunctionBlock) -> None:
    for name in {**fb._INPUTS, **fb._OUTPUTS}:
        value = getattr(fb, name)
        for other in _spellings(name):
            assert getattr(fb, other) is value, f"{type(fb).__name__}.{other} is not .{name}"


@pytest.mark.parametrize("fb", BLOCKS, ids=lambda fb: type(fb).__name__)
def test_every_input_is_a_call_keyword_in_any_case(fb: FunctionBlock) -> None:
    for name in fb._INPUTS:
        if name in TRIGGERS:
            continue
        marker = object()  # (no block raises for a bad input value: it reports it when it uses it)
        fb(**{name.lower(): marker})
        assert getattr(fb, name) is marker, f"{type(fb).__name__}({name.lower()}=...) did not set {name}"
        assert name.lower() == name or name.lower() not in vars(fb), "no second attribute"


def test_error_id_in_both_spellings() -> None:
    mv = MC_MoveAbsolute()
    mv.ErrorID = 0x4221
    assert mv.ErrorId is mv.ErrorID and mv.errorid == 0x4221
    of = plc_client.MC_OverrideFilter()  # TcMC spells this block's output ErrorId
    of.ErrorId = 0x4B06
    assert of.ErrorID == of.errorID == 0x4B06


def test_a_move_driven_in_other_spellings(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    mv = rig.watch(MC_MoveAbsolute())
    calls["body"] = lambda p: mv(Axis=ax, EXECUTE=True, position=5.0, VELOCITY=100.0)
    rig.run_until(lambda: mv.DONE, 200)
    assert mv.Done and mv.done and not mv.error and mv.errorid == 0
    assert math.isclose(ax.ActPos, 5.0, abs_tol=0.02)


def test_a_write_in_another_case_takes_effect_at_the_next_call(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    mv = rig.watch(MC_MoveVelocity())
    mv.velocity = 20.0  # written between calls, as ST's ``mv.velocity := 20.0;``
    mv.Execute = False
    assert mv.Velocity == 0.0, "not before the next call (zenoh-nc: checking every write costs too much)"
    calls["body"] = lambda p: mv(Axis=ax)
    rig.run(1)
    assert mv.Velocity == 20.0 and mv.velocity == 20.0 and "velocity" not in vars(mv)
    mv.execute = True
    rig.run_until(lambda: mv.InVelocity, 100)
    assert math.isclose(float(ax.NcToPlc["SetVelo"]), 20.0)


def test_the_exact_spelling_is_a_plain_attribute() -> None:
    """No cost for the exact spelling: the declared names are ordinary instance attributes (the case
    fold runs only when a lookup misses)."""
    mv = MC_MoveAbsolute()
    assert {"Execute", "Position", "Done", "ErrorID"} <= set(vars(mv))
    assert "__getattr__" not in vars(ExecuteBlock) and "__setattr__" not in vars(FunctionBlock)


def test_unknown_names_are_still_refused() -> None:
    mv = MC_MoveAbsolute()
    with pytest.raises(TypeError, match="no input 'Positon'"):
        mv(Positon=1.0)
    with pytest.raises(TypeError, match="given twice"):
        mv(Position=1.0, position=2.0)
    with pytest.raises(TypeError, match="no input 'done'"):
        mv(done=True)  # an output is no input, in any case
    with pytest.raises(AttributeError):
        mv.Positon  # noqa: B018
    assert not hasattr(mv, "InVelocity") and getattr(mv, "bufferMode") == 0


def test_axis_master_slave_stay_case_sensitive() -> None:
    ax = AXIS_REF(nc="nc1", axis_id=1)
    with pytest.raises(TypeError):
        MC_MoveAbsolute()(axis=ax)
    with pytest.raises(TypeError):
        MC_GearIn()(master=ax, Slave=ax)
    with pytest.raises(TypeError):
        MC_TouchProbe()(Axis=ax, triggerinput=None)
    with pytest.raises(AttributeError):
        MC_MoveAbsolute().axis  # noqa: B018


def test_two_names_differing_only_in_case_are_refused_at_class_definition() -> None:
    with pytest.raises(TypeError, match="differ only in case"):
        class _Bad(ExecuteBlock):
            _INPUTS: ClassVar[dict[str, Any]] = {"Execute": False, "Position": 0.0, "POSITION": 0.0}
    with pytest.raises(TypeError, match="differ only in case"):
        class _BadOut(ExecuteBlock):  # an output against an input
            _OUTPUTS: ClassVar[dict[str, Any]] = {**ExecuteBlock._OUTPUTS, "execute": False}


def test_jogmode_continuous_in_both_spellings() -> None:
    assert E_JogMode.MC_JOGMODE_CONTINUOUS is E_JogMode.MC_JOGMODE_CONTINOUS
    assert int(plc_client.E_JogMode.MC_JOGMODE_CONTINUOUS) == 2
    assert E_JogMode(2).name == "MC_JOGMODE_CONTINOUS", "Tc2_MC2's spelling stays the name of the value"


#: every data type the declarations of the manual's blocks use (TcMC manual, VAR_INPUT/OUTPUT/IN_OUT of
#: chapters 3-6), and the enums the issue names beside them
MANUAL_TYPES = [
    "NCTOPLC_AXLESTRUCT", "PLCTONC_AXLESTRUCT", "ST_AxisParameterSet", "ST_AxisComponents", "ST_PowerStepperStruct",
    "MC_InputRef", "MC_Direction", "MC_AxisPara", "E_ReadMode", "E_TouchProbeState", "E_TouchProbe", "E_TargPosType",
    "E_SuperpositionMode", "E_SignalEdge", "E_JogMode", "E_DestallMode", "E_DestallDetectMode", "E_DecoupleMode",
    "E_CmdTypeNewTargPosAndVelo", "MC_HomingMode", "E_StartPosType", "E_NcAxisType", "E_NcEncoderType",
    "E_NcDriveType", "MC_BufferMode", "MC_AxisStates", "ST_AxisStatus", "AXIS_REF",
]


@pytest.mark.parametrize("name", MANUAL_TYPES)
def test_the_manuals_data_types_are_importable_from_plc_client(name: str) -> None:
    assert name in plc_client.__all__
    assert getattr(plc_client, name) is not None


def test_the_axle_structs_are_the_axis_records() -> None:
    ax = AXIS_REF(nc="nc1", axis_id=1)
    assert isinstance(ax.NcToPlc, plc_client.NCTOPLC_AXLESTRUCT)
    assert isinstance(ax.PlcToNc, plc_client.PLCTONC_AXLESTRUCT)
