"""Where nc_schema and its JSON live: the package in nc_schema/, the contract JSON in schema/.

The wheel itself is checked by hand (``pip wheel . --no-deps`` then listing it); these tests pin the
pieces that make it work so a rename does not silently drop the JSON from an installed wheel.
"""
import tomllib
from pathlib import Path

import nc_schema
from nc_schema.codec import CONTRACT_DIR

ROOT = Path(__file__).resolve().parents[2]
CONTRACT_FILES = ("structs.json", "bits.json", "enums.json", "errors.json", "protocol.json", "params.json")


def test_package_is_where_its_name_says():
    assert Path(nc_schema.__file__).resolve().parent == ROOT / "nc_schema"
    assert not list((ROOT / "schema").glob("*.py"))


def test_checkout_reads_the_json_from_schema():
    assert Path(str(CONTRACT_DIR)).resolve() == ROOT / "schema"
    assert sorted(p.name for p in (ROOT / "schema").glob("*.json")) == sorted(CONTRACT_FILES)


def test_wheel_ships_the_json_as_nc_schema_contract():
    tool = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["tool"]["setuptools"]
    assert "nc_schema.contract" in tool["packages"]
    assert tool["package-dir"] == {"nc_schema.contract": "schema"}  # data only: no module is mapped
    assert tool["package-data"]["nc_schema.contract"] == ["*.json"]
