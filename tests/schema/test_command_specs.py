"""nc_schema.COMMAND_SPECS: the typed view of protocol.json's commands, checked as it is built."""
from __future__ import annotations

import dataclasses
from typing import Any

import pytest

import nc_schema as s
from nc_schema import commands


def test_specs_carry_the_contract() -> None:
    assert list(s.COMMAND_SPECS) == list(s.COMMANDS)
    for name, spec in s.COMMAND_SPECS.items():
        raw = s.COMMANDS[name]
        assert spec.name == name and spec.cls == s.COMMAND_CLASS[name] == raw["class"]
        assert spec.scope == raw.get("scope", "axis") and spec.args == tuple(raw["args"])
        assert spec.motion == (name in s.MOTION_COMMANDS) and spec.doc == raw.get("doc", "")
        assert set(raw) - {"args", "doc"} <= commands.PROPERTIES
        if spec.motion and not spec.stop:
            assert spec.undo and all(u in s.COMMAND_SPECS for u in spec.undo)
        else:
            assert spec.undo == ()
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.COMMAND_SPECS["Halt"].stop = False  # type: ignore[misc]
    with pytest.raises(TypeError):
        s.COMMAND_SPECS["Halt"] = s.COMMAND_SPECS["Stop"]  # type: ignore[index]


def test_every_property_is_documented() -> None:
    documented = set(s.PROTOCOL["command_properties"]) - {"doc"}
    used = {k for c in s.COMMANDS.values() for k in c} - {"args", "doc"}
    assert used <= documented == commands.PROPERTIES
    assert documented == {"scope", "class", "motion", "amends", "stop", "slot", "undo", "layer"}


def test_the_properties_of_the_commands() -> None:
    def named(**want: Any) -> set[str]:
        return {n for n, c in s.COMMAND_SPECS.items() if all(getattr(c, k) == v for k, v in want.items())}

    assert named(amends=True) == {"NewPos", "NewPosAndVelo", "ChangeDynParam"}
    assert named(stop=True) == {"Stop", "Halt"}
    assert named(layer="server") == {"Claim", "Release", "HandOver", "Info"}
    assert named(slot="Super") == {"MoveSuperImposed"} and named(slot="Probe") == {"TouchProbe"}


@pytest.mark.parametrize("bad, match", [
    ({"X": {"class": "op", "args": {}, "colour": "red"}}, "not documented"),
    ({"X": {"class": "admin", "args": {}}}, "class"),
    ({"X": {"class": "op", "scope": "plc", "args": {}}}, "scope"),
    ({"X": {"class": "op", "layer": "door", "args": {}}}, "layer"),
    ({"X": {"class": "op", "motion": "yes", "args": {}}}, "boolean"),
    ({"X": {"class": "op", "motion": True, "amends": True, "args": {}}}, "amendment"),
    ({"X": {"class": "op", "stop": True, "args": {}}}, "stop"),
    ({"X": {"class": "op", "slot": "Jobs", "args": {}}}, "slot"),
    ({"X": {"class": "op", "motion": True, "undo": ["Nothing"], "args": {}}}, "undo"),
    ({"X": {"class": "op", "undo": ["X"], "args": {}}}, "undo"),
])
def test_a_broken_contract_fails_to_load(bad: dict[str, Any], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        commands._load(bad)
