"""The PLC task's command sets come from the contract's command properties (nc_schema.COMMAND_SPECS)
and are what they were as literals before (issue 16: one description per command)."""
from __future__ import annotations

from plc_client import task


def test_the_derived_sets_equal_the_old_literals() -> None:
    assert task._SLOT_COMMANDS == frozenset({"MoveSuperImposed"})
    assert task._AMENDS == frozenset({"NewPos", "NewPosAndVelo", "ChangeDynParam"})
    assert task._STOPS == frozenset({"Stop", "Halt"})
    assert task._UNDO == {"GearIn": ("GearOut",), "GearInFloat": ("GearOut",), "GearInDyn": ("GearOut",),
                          "Home": ("Stop", "StopRelease"), "MoveSuperImposed": ("AbortSuperposition",)}
