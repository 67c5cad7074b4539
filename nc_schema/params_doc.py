"""docs/parameters.md, generated from schema/params.json: ``python -m nc_schema.params_doc > docs/parameters.md``
(tests/schema/test_params.py checks that the file is up to date)."""
from __future__ import annotations

import sys

from .params import _DATA, PARAMETERS, PARAMS_DOC, ST_AXIS_COMPONENTS, ST_AXIS_PARAMETER_SET, UNITS, ParamEntry

HEADER = """# Axis parameters

<!-- Generated from schema/params.json by `python -m nc_schema.params_doc > docs/parameters.md`; do not edit. -->

Every MC_AxisPara number of the TcMC manual (section 6.1), as the NC serves it: `ReadParameter` /
`WriteParameter` (MC_ReadParameter, MC_ReadBoolParameter, MC_WriteParameter, MC_WriteBoolParameter), the
parameter set of MC_ReadParameterSet and the ADS door's index group 0x4000+ID. The one source is
`schema/params.json` (Python: `nc_schema.PARAMETERS.by_number(n)`, `.by_name(s)`, `.ads(group, offset)`).

* **Source**: *param* a stored parameter (configurable in the `[[axis]]` table under its AxisParams name);
  *status* read from the live axis state, read-only; *fixed*: TwinCAT defines the number but this NC has no
  such function: it reads the fixed value shown, writing that same value is accepted (nothing changes),
  another value is refused with 0x4251.
* **Writable / when**: *always*; *standstill*: refused with 0x4220 while the axis moves or is driven;
  *disabled*: refused with 0x4B42 while the controller is enabled. A write runs between two NC cycles (the
  reply's cycle is the first with the new value), never within one.
* **A running motion is never broken**: while the axis moves, AxisVeloMax below the running command's
  velocity or the set velocity is refused with 0x4221, AxisAcc and AxisDec both below the set acceleration
  with 0x422F, a software limit that the running command's target or the set position lies beyond with
  0x4222.
* **Errors**: a number TcMC does not define 0x703 (ADS "invalid index offset"), a write of a read-only
  number 0x704, a value of the wrong type or outside the range 0x70B (nothing changes; a bad value of a
  parameter whose table entry names TwinCAT's own code gets that code: see its *What*). The blocks add
  0x4B05 for a parameter of the other type (MC_ReadBoolParameter on an LREAL parameter, ...).
* **ADS**: the index offset in the axis's object (axis = index group 0x4000+ID; encoder, controller, drive
  are its sub-objects, which Tc2_MC2 addresses as offsets 0x0001_xxxx, 0x0002_xxxx, 0x0003_xxxx of the axis
  group) and the ADS data type; given only where Beckhoff's MC_AxisParameter / ST_AxisParameterSet comments,
  the NC ADS tables or twincat-nc-reference.md 5.4 give it.
"""


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def _ads(e: ParamEntry) -> str:
    if e.ads is None:
        return ""
    return f"{e.ads.group} 0x{e.ads.offset:02X} {e.ads.type}"


def _writable(e: ParamEntry) -> str:
    if e.writable:
        return f"yes ({e.when})"
    if e.source == "fixed":
        return "fixed"
    return "no"


def _value(e: ParamEntry) -> str:
    if e.source == "param":
        return f"`{e.store}`"
    if e.source == "status":
        return f"status: {e.status}"
    v = e.fixed
    if e.type == "BOOL":
        return f"fixed: {'TRUE' if v else 'FALSE'}"
    if e.type == "UDINT":
        return f"fixed: 0x{int(v):X}"
    return f"fixed: {float(v):g}"


def render() -> str:
    """The whole of docs/parameters.md."""
    out = [HEADER, "## MC_AxisPara\n",
           "| No. | Name | Type | Unit | Writable | Range | Value | ADS | ST_AxisParameterSet | What |",
           "|---:|---|---|---|---|---|---|---|---|---|"]
    for e in PARAMETERS:
        out.append(f"| {e.number} | {e.name} | {e.type} | {e.unit} | {_writable(e)} | {_cell(e.range_text())} | "
                   f"{_value(e)} | {_ads(e)} | {e.field or ''} | {_cell(e.doc)} |")
    out.append("\nUnits: " + "; ".join(f"`{k}` {v}" for k, v in UNITS.items()) + ".\n")
    out.append("Column meanings (schema/params.json `doc`): " + " ".join(
        f"**{k}**: {_cell(v)}." for k, v in PARAMS_DOC.items()) + "\n")
    for layout in (ST_AXIS_PARAMETER_SET, ST_AXIS_COMPONENTS):
        out.append(f"## {layout.name} ({layout.size} bytes)\n")
        out.append(_cell(layout.doc) + "\n")
        out.append("| Offset | Member | Type | ADS | Value here | Note |")
        out.append("|---:|---|---|---|---|---|")
        for f in layout.fields:
            t = f.type if f.count == 1 else f"ARRAY[1..{f.count}] OF {f.type}"
            out.append(f"| {f.offset} | {f.name} | {t} | {f.ads} | {_cell(f.value)} | {_cell(f.doc)} |")
        out.append("")
    st = _DATA["stepper_terminal"]
    out.append("## The stepper terminal (MC_PowerStepper, SimStepper)\n")
    out.append(_cell(st["doc"]) + "\n")
    out.append("| Input | Bit | Name | Axis error when reported |")
    out.append("|---|---|---|---|")
    for b in st["status_byte"]:
        bits = f"{b['bit']}..{b['bit'] + b['width'] - 1}" if b.get("width", 1) > 1 else str(b["bit"])
        out.append(f"| KL_Status | {bits} | {b['name']} | {_cell(b.get('doc', ''))} |")
    for b in st["status_word"]:
        out.append(f"| KL_Status2 | {b['bit']} | {b['name']} | {b['error']} |")
    out.append(f"\nA detected stall is reported as {st['stall_error']}. "
               + _cell(st["drive_status"]["doc"]) + ": "
               + ", ".join(f"bits {f['bit']}..{f['bit'] + f['width'] - 1} {f['name']}" if f["width"] > 1
                           else f"bit {f['bit']} {f['name']}" for f in st["drive_status"]["fields"]) + ".\n")
    return "\n".join(out)


def main() -> int:
    sys.stdout.write(render())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
