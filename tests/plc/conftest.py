"""Fixtures of the PLC-side unit tests (helpers in znc_testing.plc_rig)."""
from __future__ import annotations

import pytest

from znc_testing.plc_rig import Rig, ScriptNc


@pytest.fixture
def rig() -> Rig:
    return Rig()


@pytest.fixture
def nc() -> ScriptNc:
    """A scripted NC (one axis, id 1) after its first frame."""
    t = ScriptNc()
    t.cycle_once()
    return t
