"""The type declarations of attributes the code makes at run time (issue 16: mypy must see them) match
what it makes: every function block input/output of ``_INPUTS``/``_OUTPUTS``, every NCTOPLC/PLCTONC
member (properties made from the layout), every ST_AxisStatus flag (set from the flag tables)."""
from __future__ import annotations

from typing import Any

import pytest

import plc_client.fb  # noqa: F401  (imports every block module)
from plc_client.axis_ref import _BIT_FIELDS, _STATE_FLAGS, ST_AxisStatus
from plc_client.fb.base import FunctionBlock
from znc_testing.plc_rig import all_blocks
from plc_client.records import (
    _NC_MEMBERS, _PLC_MEMBERS, NCTOPLC_AXIS_REF, NCTOPLC_FIELDS, PLCTONC_AXIS_REF, PLCTONC_FIELDS,
)


def _annotations(cls: type) -> dict[str, str]:
    """Name -> annotation (a string: the modules use ``from __future__ import annotations``) over the MRO."""
    out: dict[str, str] = {}
    for c in reversed(cls.__mro__):
        out.update(c.__dict__.get("__annotations__", {}))
    return out




def _type_name(default: Any) -> str | None:
    """The annotation a default value asks for (None: any)."""
    for t in (bool, float, int):  # (bool first: it is an int; an IntEnum default is an int)
        if isinstance(default, t):
            return t.__name__
    return None


@pytest.mark.parametrize("block", all_blocks(), ids=lambda c: c.__qualname__)
def test_every_input_and_output_is_declared(block: type[FunctionBlock]) -> None:
    ann = _annotations(block)
    for table in ("_INPUTS", "_OUTPUTS"):
        for name, default in getattr(block, table).items():
            assert name in ann, f"{block.__qualname__}.{name} ({table}) has no annotation"
            want = _type_name(default)
            if want is not None:
                assert ann[name].split("|")[0].strip() == want, f"{block.__qualname__}.{name}: {ann[name]}"


def test_the_blocks_are_found() -> None:
    names = {c.__name__ for c in all_blocks()}
    assert {"MC_Power", "MC_MoveAbsolute", "MC_GearOut", "AXACT", "MC_OverrideFilter", "MC_PowerStepper"} <= names


def _member_type(code: str, array_len: int) -> str:
    return "tuple[int, ...]" if array_len else "float" if code in "fd" else "int"


def test_nctoplc_members_are_declared() -> None:
    ann = {k: v for k, v in _annotations(NCTOPLC_AXIS_REF).items() if not k.startswith("_") and k != "dtype"}
    assert set(ann) == set(NCTOPLC_FIELDS)
    for m in _NC_MEMBERS:
        if m.name in ann:
            assert ann[m.name] == _member_type(m.code, m.array_len), m.name


def test_plctonc_members_are_declared() -> None:
    ann = {k: v for k, v in _annotations(PLCTONC_AXIS_REF).items() if not k.startswith("_") and k != "dtype"}
    assert set(ann) == set(PLCTONC_FIELDS)
    for m in _PLC_MEMBERS:
        if m.name in ann:
            assert ann[m.name] == f"_Writable[{_member_type(m.code, m.array_len)}]", m.name


def test_axis_status_flags_are_declared() -> None:
    ann = _annotations(ST_AxisStatus)
    for name in (*_STATE_FLAGS.values(), *_BIT_FIELDS):
        assert ann.get(name) == "bool", name
    s = ST_AxisStatus()
    assert all(hasattr(s, name) for name in ST_AxisStatus._FIELDS)
