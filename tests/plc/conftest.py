"""Fixtures of the PLC-side unit tests (helpers in plc_rig.py)."""
from __future__ import annotations

import pytest

from plc_rig import Rig


@pytest.fixture
def rig() -> Rig:
    return Rig()
