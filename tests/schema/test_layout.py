"""The generated codec matches the TwinCAT 3 layouts byte for byte.

Two independent sources: a table copied by hand from
shared/reference/twincat-nc-reference.md (sections 1 and 2), and, when the
shared/ folder sits beside the checkout (as in CI), that markdown itself.
"""
import re
from pathlib import Path

import numpy as np
import pytest

import nc_schema as s

NCTOPLC = [  # (offset, size, name)
    (0, 4, "StateDWord"), (4, 4, "ErrorCode"), (8, 4, "AxisState"), (12, 4, "AxisModeConfirmation"),
    (16, 4, "HomingState"), (20, 4, "CoupleState"), (24, 4, "SvbEntries"), (28, 4, "SafEntries"),
    (32, 4, "AxisId"), (36, 4, "OpModeDWord"), (40, 8, "ActPos"), (48, 8, "ModuloActPos"),
    (56, 2, "ActiveControlLoopIndex"), (58, 2, "ControlLoopIndex"), (60, 4, "ModuloActTurns"),
    (64, 8, "ActVelo"), (72, 8, "PosDiff"), (80, 8, "SetPos"), (88, 8, "SetVelo"), (96, 8, "SetAcc"),
    (104, 8, "TargetPos"), (112, 8, "ModuloSetPos"), (120, 4, "ModuloSetTurns"), (124, 2, "CmdNo"),
    (126, 2, "CmdState"), (128, 8, "SetJerk"), (136, 8, "SetTorque"), (144, 8, "ActTorque"),
    (152, 4, "StateDWord2"), (156, 4, "StateDWord3"), (160, 4, "TouchProbeState"), (164, 4, "TouchProbeCounter"),
    (168, 8, "CamCouplingState"), (176, 16, "CamCouplingTableID"), (192, 8, "ActTorqueDerivative"),
    (200, 8, "SetTorqueDerivative"), (208, 8, "AbsPhasingPos"), (216, 8, "TorqueOffset"),
    (224, 8, "ActPosWithoutPosCorrection"), (232, 8, "ActAcc"), (240, 4, "DcTimeStamp"), (244, 4, "_reserved2"),
    (248, 8, "UserData"),
]
PLCTONC = [
    (0, 4, "ControlDWord"), (4, 4, "Override"), (8, 4, "AxisModeRequest"), (12, 4, "AxisModeDWord"),
    (16, 8, "AxisModeLReal"), (24, 8, "PositionCorrection"), (32, 8, "ExtSetPos"), (40, 8, "ExtSetVelo"),
    (48, 8, "ExtSetAcc"), (56, 4, "ExtSetDirection"), (60, 4, "_reserved1"), (64, 8, "ExtControllerOutput"),
    (72, 8, "GearRatio1"), (80, 8, "GearRatio2"), (88, 8, "GearRatio3"), (96, 8, "GearRatio4"),
    (104, 1, "MapState"), (105, 1, "PlcCycleControl"), (106, 1, "PlcCycleCount"), (107, 5, "_reserved2"),
    (112, 8, "ExtTorque"), (120, 8, "_reserved3"),
]


def _check(dtype, table, size):
    assert dtype.itemsize == size
    assert list(dtype.names) == [n for _, _, n in table]
    for off, sz, name in table:
        fdt, foff = dtype.fields[name][:2]
        assert (foff, fdt.itemsize) == (off, sz), name
    # the fields tile the struct exactly: no gap, no overlap
    ends = [o + z for o, z, _ in table]
    assert [o for o, _, _ in table][1:] == ends[:-1] and ends[-1] == size


def test_nctoplc_layout():
    _check(s.NCTOPLC_DTYPE, NCTOPLC, 256)


def test_plctonc_layout():
    _check(s.PLCTONC_DTYPE, PLCTONC, 128)


REFERENCE = Path(__file__).resolve().parents[3] / "shared" / "reference" / "twincat-nc-reference.md"


def _reference_rows(section_title: str) -> list[tuple[int, int, str]]:
    text = REFERENCE.read_text(encoding="utf-8")
    start = text.index(section_title)
    rows = []
    for line in text[start:].splitlines()[2:]:
        m = re.match(r"\|\s*(\d+)\s*\|\s*0x[0-9A-F]+\s*\|\s*(\d+)\s*\|[^|]*\|\s*(\w+)\s*\|", line)
        if m:
            rows.append((int(m.group(1)), int(m.group(2)), m.group(3)))
        elif rows and line.startswith("| 256") or rows and line.startswith("| 128"):
            break
        elif rows and not line.startswith("|"):
            break
    return rows


@pytest.mark.skipif(not REFERENCE.exists(), reason="shared/reference not beside this checkout")
@pytest.mark.parametrize("title,dtype", [("## 1. NCTOPLC_AXIS_REF", s.NCTOPLC_DTYPE), ("## 2. PLCTONC_AXIS_REF", s.PLCTONC_DTYPE)])
def test_layout_against_reference_markdown(title, dtype):
    rows = _reference_rows(title)
    assert len(rows) == len(dtype.names)
    for off, size, name in rows:
        assert name in dtype.fields, name
        fdt, foff = dtype.fields[name][:2]
        assert (foff, fdt.itemsize) == (off, size), name


def test_bits_and_enums_match_reference():
    assert int(s.StateDWord.HasJob) == 1 << 8 and int(s.StateDWord.Error) == 1 << 31
    assert int(s.StateDWord.MotionCommandsLocked) == 1 << 29 and int(s.StateDWord.ControlLoopClosed) == 1 << 20
    assert int(s.ControlDWord.Enable) == 1 and int(s.ControlDWord.FeedEnablePlus) == 2 and int(s.ControlDWord.FeedEnableMinus) == 4
    assert int(s.OpModeDWord.OpModeModulo) == 1 << 7 and int(s.OpModeDWord.OpModeSoftLimitMaxMonitoring) == 1 << 19
    assert int(s.MC_BufferMode.MC_BlendingLow) == 0x12
    assert int(s.MC_Direction.MC_Negative_Direction) == 3
    assert int(s.MC_AxisStates.MC_AXISSTATE_CONTINOUSMOTION) == 7
    assert int(s.MC_AxisPara.AxisVeloMax) == 1003 and int(s.MC_AxisPara.AxisUnitInterpretation) == 1048
    assert int(s.MC_AxisPara.AxisRemainingDistanceToGo) == 2002


def test_error_codes_unique_and_named():
    codes = [e for e in s.ERRORS]
    assert len(codes) == len(set(codes))
    assert s.ErrorCodes.NC_NO_ENABLE == 0x4223 and s.ErrorCodes.NC_AXIS_LOCKED_BY_STOP == 0x42EF
    assert s.ErrorCodes.MC_NO_NC_CYCLE_UPDATE == 0x4B0F and s.ErrorCodes.ADSERR_CLIENT_SYNCTIMEOUT == 0x745
    assert "0x4550" in str(s.NcError(0x4550))


def test_frames_round_trip():
    recs = np.zeros(3, s.NCTOPLC_DTYPE)
    recs["AxisId"] = [1, 2, 3]
    recs["SetPos"] = [1.5, -2.0, 3.25]
    data = s.encode_frame(42, 123456789, recs)
    assert len(data) == 40 + 3 * 256  # (the header: 40 bytes since protocol 5)
    h, back, jobs = s.decode_frame(data)
    assert jobs is None
    assert int(h["Cycle"]) == 42 and int(h["NcTimeNs"]) == 123456789
    assert back.tobytes() == recs.tobytes()
    with pytest.raises(ValueError):
        s.decode_frame(data[:-1])
    with pytest.raises(ValueError):
        s.decode_frame(b"XXXX" + data[4:])
    pt = np.zeros(2, s.PLCTONC_DTYPE)
    pt["ControlDWord"] = [1, 7]
    h, back = s.decode_plc_frame(s.encode_plc_frame(9, [4, 2], pt))
    assert int(h["PlcCycle"]) == 9 and back["AxisId"].tolist() == [4, 2] and back["PlcToNc"]["ControlDWord"].tolist() == [1, 7]
    assert s.decode_stamp(s.encode_stamp(7, 99)) == (7, 99)
