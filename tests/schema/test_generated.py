"""nc_schema/generated.py is what ``python -m nc_schema.generate`` writes from schema/*.json, and the names
built from it are the contract's."""
from pathlib import Path

import nc_schema as s
from nc_schema import generate, generated
from nc_schema.layout import load_json


def test_regenerating_gives_no_diff() -> None:
    assert generate.render() == Path(generated.__file__).read_text(encoding="utf-8"), \
        "nc_schema/generated.py is out of date: run python -m nc_schema.generate"
    assert generate.main(["--check"]) == 0


def test_enums_and_bitsets_carry_the_json_values() -> None:
    for name, spec in load_json("enums.json")["enums"].items():
        assert {m: int(getattr(generated, name)[m]) for m in spec["values"]} == spec["values"]
    for json_name, bits in load_json("bits.json")["bitsets"].items():
        cls = getattr(generated, generate.BITSET_NAMES.get(json_name, json_name))
        assert {n: int(cls[n]) for n in bits.values()} == {n: 1 << int(k) for k, n in bits.items()}
    assert s.StateDWord is generated.StateDWord and s.E_ReadMode is generated.E_ReadMode


def test_error_codes_and_texts() -> None:
    for e in load_json("errors.json")["errors"]:
        assert getattr(s.ErrorCodes, e["name"]) == e["code"]
        assert s.ERRORS[e["code"]] == (e["name"], e["class"], e["text"])
        assert s.error_text(e["code"]) == e["text"]


def test_package_all_is_static_and_complete() -> None:
    import types
    public = {n for n in dir(s) if not n.startswith("_") and not isinstance(getattr(s, n), types.ModuleType)}
    assert set(s.__all__) == public
