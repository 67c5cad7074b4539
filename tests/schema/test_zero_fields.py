"""structs.json's ``zero`` key: the NCTOPLC_AXIS_REF fields this NC has no source for say why, and stay 0 however
the NC is driven (issue 17: every other field a servo axis fills is live)."""
from __future__ import annotations

from nc_schema.layout import STRUCTS
from znc_testing.nc_core import cmd, power, powered

#: the fields the NC leaves 0 (each with its reason in structs.json)
ZERO = {"AxisModeConfirmation", "ActiveControlLoopIndex", "ControlLoopIndex", "StateDWord2", "CamCouplingState",
        "CamCouplingTableID", "AbsPhasingPos", "UserData"}
#: the fields issue 17 made live (never written before)
LIVE = {"SvbEntries", "SafEntries", "SetTorque", "ActTorque", "ActTorqueDerivative", "SetTorqueDerivative",
        "TorqueOffset"}


def _fields() -> list[dict]:
    return STRUCTS["NCTOPLC_AXIS_REF"]["fields"]


def test_the_zero_fields_are_named_with_a_reason():
    marked = {f["name"]: f["zero"] for f in _fields() if "zero" in f}
    assert set(marked) == ZERO
    for name, why in marked.items():
        assert isinstance(why, str) and len(why) > 20, name
    assert not LIVE & set(marked)
    for s, spec in STRUCTS.items():  # only NCTOPLC fields can be marked
        if s != "NCTOPLC_AXIS_REF":
            assert not any("zero" in f for f in spec["fields"]), s


def test_zero_fields_stay_zero_and_the_live_ones_are_written():
    core = powered(2, SimLoadInertia=0.01)
    rec = core.plctonc[0].copy()
    rec["AxisModeRequest"] = 1
    rec["ExtTorque"] = 5.0
    core.set_plctonc(0, rec)
    assert cmd(core, "MoveAbsolute", axis=1, Position=50.0, Velocity=300.0)["error"] == 0
    assert cmd(core, "MoveAbsolute", axis=1, Position=0.0, Velocity=300.0, BufferMode=1)["error"] == 0
    assert cmd(core, "GearIn", axis=2, Master=1, RatioNumerator=1, RatioDenominator=1)["error"] == 0
    seen = {name: False for name in LIVE}
    for k in range(400):
        core.step()
        for name in ZERO:
            assert not core.nctoplc[name].any(), (name, k)
        for name in LIVE:
            seen[name] |= bool(core.nctoplc[name].any())
    power(core, 0, ctrl=0)
    core.step()
    assert all(seen.values()), seen
    for name in ZERO:
        assert not core.nctoplc[name].any(), name
