"""The parameter table (schema/params.json, nc_schema.PARAMETERS), its byte codecs and docs/parameters.md."""
from __future__ import annotations

import dataclasses
import math
import struct
from pathlib import Path

import pytest

import nc_schema as s
from nc_schema import PARAMETERS
from nc_schema.params import (
    ADS_GROUPS, ST_AXIS_COMPONENTS, ST_AXIS_PARAMETER_SET, decode_ads, encode_ads, pack_value, to_lreal, type_size,
    unpack_value,
)
from nc_schema.params_doc import render
from nc_server.core.params import AxisParams

ROOT = Path(__file__).resolve().parents[2]
KINDS = {f.name: f.metadata["kind"] for f in dataclasses.fields(AxisParams)}


def test_one_entry_per_mc_axispara_number_with_its_name():
    assert [e.number for e in PARAMETERS] == sorted(int(m) for m in s.MC_AxisPara)
    for e in PARAMETERS:
        assert s.MC_AxisPara(e.number).name == e.name
        assert PARAMETERS.by_number(e.number) is e and PARAMETERS.by_name(e.name) is e
    assert len(PARAMETERS) == 68  # 16 PLCopen + 49 Beckhoff + 3 status numbers of TcMC 6.1
    assert PARAMETERS.by_number(4711) is None and PARAMETERS.by_number(True) is None
    assert PARAMETERS.by_name("NoSuchParameter") is None


def test_entries_are_consistent():
    for e in PARAMETERS:
        assert e.type in ("LREAL", "BOOL", "UDINT") and e.unit in ("",) + tuple(s.params.UNITS), e
        assert e.source in ("param", "status", "fixed"), e
        assert e.writable == (e.source == "param"), e
        assert (e.when in ("always", "standstill", "disabled")) if e.writable else e.when is None, e
        if e.source == "param":
            # the stored field exists with the same kind of value, and its default lies in the range
            assert e.store in KINDS, e
            assert (KINDS[e.store] == "bool") == e.is_bool, e
            default = getattr(AxisParams(), e.store)
            assert e.is_bool or e.in_range(float(default)), e
        if e.source == "status":
            assert e.status, e
        if e.source == "fixed":
            assert e.fixed is not None and isinstance(e.fixed, bool) == e.is_bool, e
        if e.is_bool:
            assert e.min is None and e.max is None, e
        assert e.doc, e


def test_bad_value_codes_are_known_nc_errors_of_stored_parameters():
    coded = {e.name: e.code for e in PARAMETERS if e.code is not None}
    assert coded["AxisLoopingDistance"] == 0x4328 and coded["AxisOverrideType"] == 0x430D
    for e in PARAMETERS:
        if e.code is not None:
            assert e.source == "param" and e.code in s.ERRORS, e
            assert 0x4000 <= e.code <= 0x4FFF, e


def test_entries_of_one_store_share_type_and_range():
    for store, entries in PARAMETERS.stores().items():
        assert len({(e.type, e.min, e.max, e.min_exclusive, e.when) for e in entries}) == 1, store


def test_ads_addresses():
    assert PARAMETERS.ads("axis", 0x27).name == "AxisVeloMax"  # the Beckhoff entry of the shared address
    assert PARAMETERS.ads("encoder", 0x0E).name == "AxisMaxSoftPosLimit"
    assert PARAMETERS.ads("controller", 0x12).name == "AxisMaxPosLagValue"
    assert PARAMETERS.ads("axis", 0x101).name == "AxisAcc"
    assert PARAMETERS.ads_axis_offset(0x0001_000E).name == "AxisMaxSoftPosLimit"  # Tc2_MC2's notation
    assert PARAMETERS.ads_axis_offset(0x0000_0008).name == "AxisVeloManSlow"
    assert PARAMETERS.ads("axis", 0x7777) is None and PARAMETERS.ads_axis_offset(0x0009_0001) is None
    for e in PARAMETERS:
        if e.ads is None:
            continue
        assert e.ads.group in ADS_GROUPS and e.ads.type in ("REAL64", "UINT32", "UINT16"), e
        assert (e.ads.type == "UINT16") == e.is_bool or e.name in ("AxisId", "AxisEncoderEncoderMask"), e
        owner = PARAMETERS.ads(e.ads.group, e.ads.offset)
        # every number at an address is the same NC parameter
        assert owner is not None and (owner.store or owner.name) == (e.store or e.name), e


def test_fields_match_the_parameter_set():
    members = {f.name: f for f in ST_AXIS_PARAMETER_SET.fields}
    for e in PARAMETERS:
        if e.field is None:
            continue
        f = members[e.field]
        if e.ads is not None:
            assert f.ads == f"{e.ads.group}:0x{e.ads.offset:02X}", e
        if e.source == "param":
            assert f.value == f"param:{e.store}", e


@pytest.mark.parametrize("type_, value, raw", [
    ("LREAL", 1.5, b"\x00\x00\x00\x00\x00\x00\xf8\x3f"),
    ("LREAL", -0.0, b"\x00" * 7 + b"\x80"),
    ("LREAL", 1e300, struct.pack("<d", 1e300)),
    ("BOOL", True, b"\x01"),
    ("BOOL", False, b"\x00"),
    ("UDINT", 4294967295, b"\xff\xff\xff\xff"),
    ("UDINT", 0x12345678, b"\x78\x56\x34\x12"),
    ("DINT", -1, b"\xff\xff\xff\xff"),
    ("DINT", -2147483648, b"\x00\x00\x00\x80"),
    ("UINT", 0xBEEF, b"\xef\xbe"),
    ("WORD", 1, b"\x01\x00"),
    ("USINT", 255, b"\xff"),
    ("STRING(31)", "Axis 1", b"Axis 1" + b"\0" * 26),
    ("T_AmsNetId", "5.1.2.3.1.1", b"5.1.2.3.1.1" + b"\0" * 13),
])
def test_plc_values_round_trip_byte_for_byte(type_, value, raw):
    assert pack_value(type_, value) == raw and len(raw) == type_size(type_)
    back = unpack_value(type_, raw)
    assert back == value and type(back) is type(value)
    if type_ == "LREAL":
        assert math.copysign(1.0, back) == math.copysign(1.0, value)


def test_plc_value_errors():
    with pytest.raises(ValueError):
        pack_value("UDINT", -1)
    with pytest.raises(ValueError):
        pack_value("DINT", 2**31)
    with pytest.raises(ValueError):
        unpack_value("LREAL", b"\x00" * 4)
    assert unpack_value("BOOL", b"\x02") is True  # any non-zero byte is TRUE
    assert pack_value("STRING(3)", "abcdef") == b"abc\0"  # truncated, always terminated


def test_every_ads_parameter_round_trips():
    for e in PARAMETERS:
        if e.ads is None:
            continue
        value = True if e.is_bool else (4294967295 if e.ads.type == "UINT32" else -1234.5678)
        raw = encode_ads(e, value)
        assert len(raw) == e.ads.size
        assert decode_ads(e, raw) == to_lreal(e, value), e
        with pytest.raises(ValueError):
            decode_ads(e, raw + b"\0")
    velo = PARAMETERS.by_name("AxisVeloMax")
    assert encode_ads(velo, 250.0) == struct.pack("<d", 250.0)
    en = PARAMETERS.by_name("AxisEnMinSoftPosLimit")
    assert encode_ads(en, True) == b"\x01\x00" and decode_ads(en, b"\x00\x00") is False
    with pytest.raises(ValueError):
        encode_ads(PARAMETERS.by_name("AxisId"), -1)
    with pytest.raises(ValueError):
        encode_ads(PARAMETERS.by_name("AxisJogIncrementForward"), 1.0)  # no ADS address


def test_parameter_set_layout_and_round_trip():
    L = ST_AXIS_PARAMETER_SET
    assert L.size == 1024
    end = 0
    for f in L.fields:
        size = type_size(f.type)
        align = 1 if f.type.startswith("STRING") or f.type == "T_AmsNetId" else size
        assert f.offset >= end and f.offset % align == 0 and f.offset - end < align, f  # natural alignment, no gap
        end = f.offset + f.size
    assert end <= 1024
    values = {f.name: (1.25 * k if f.type == "LREAL" else ("n%d" % k if f.type.startswith("STRING") or
                                                           f.type == "T_AmsNetId" else k))
              for k, f in enumerate(L.fields)}
    raw = s.encode_parameter_set(values)
    assert len(raw) == 1024 and s.decode_parameter_set(raw) == values
    assert raw[:4] == struct.pack("<I", values["AxisId"])  # AxisId first
    with pytest.raises(ValueError):
        s.encode_parameter_set({"NoSuchMember": 1})
    with pytest.raises(ValueError):
        s.decode_parameter_set(raw[:-1])


def test_axis_components_layout():
    assert ST_AXIS_COMPONENTS.size == 108
    v = {"EncoderIDs": [1, 2] + [0] * 7, "ControllerIDs": [3] + [0] * 8, "DriveIDs": [0] * 8 + [9]}
    raw = s.encode_axis_components(v)
    assert len(raw) == 108 and raw[:8] == b"\x01\0\0\0\x02\0\0\0" and raw[72 + 32:] == b"\x09\0\0\0"
    assert s.decode_axis_components(raw) == v


def test_docs_are_up_to_date():
    """docs/parameters.md is generated: ``python -m nc_schema.params_doc > docs/parameters.md``."""
    text = (ROOT / "docs" / "parameters.md").read_text(encoding="utf-8")
    assert text == render(), "docs/parameters.md is stale: python -m nc_schema.params_doc > docs/parameters.md"
    for e in PARAMETERS:
        assert f"| {e.number} | {e.name} |" in text


def test_new_enums():
    assert s.E_ReadMode.ReadMode_Once == 1 and s.E_ReadMode.ReadMode_Cyclic == 2
    assert [int(m) for m in s.E_DestallMode] == [0, 1, 2, 3]
    assert s.E_DestallDetectMode.PwStDetectMode_Lagging == 2
