"""Parameter metadata for people and ground stations, generated from the one parameter table.

:func:`pdef_xml` renders every parameter (:data:`fc.params.PARAMS`, then the simulator's
``SIM_*``) in ArduPilot's ``apm.pdef.xml`` format, the file MAVProxy's ``param help`` and
QGroundControl read for names, units, ranges and descriptions; :func:`parameters_markdown` the
same as a Markdown table (``docs/parameters.md``). Both are derived, never edited by hand::

    python -m fc.param_meta            # rewrite smcpilot/data/apm.pdef.xml and docs/parameters.md
    python -m fc.param_meta --check    # exit 1 if either is out of date (the test suite runs it)

The FC's parameters are a ``<parameters name="ArduCopter">`` vehicle block (names
``ArduCopter:NAME``, as ArduPilot's file has them: this FC presents itself as an ArduCopter),
the simulator's a library block ``SIM_``. MAVProxy: ``param set_xml_filepath smcpilot/data/apm.pdef.xml``
then ``param help SMC_Z_KP`` (or copy the file to ``~/.mavproxy/ArduCopter.xml``).
"""

from __future__ import annotations

import argparse
import re
import sys
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from pathlib import Path

from fc.config import FcConfig
from fc.params import PARAMS, FcOptions, ParamSpec
from smcpilot.faults import SIM_PARAMS, SimParam

__all__ = ["PDEF_PATH", "MARKDOWN_PATH", "pdef_xml", "parameters_markdown", "values_of", "main"]

_ROOT = Path(__file__).resolve().parent.parent
#: shipped with the package (the ground station reads it: ground.vehicle.param_meta).
PDEF_PATH = _ROOT / "smcpilot" / "data" / "apm.pdef.xml"
MARKDOWN_PATH = _ROOT / "docs" / "parameters.md"
_VALUE_RE = re.compile(r"(-?\d+) ([A-Za-z_][\w-]*)")


def values_of(is_int: bool, lo: float, hi: float, doc: str) -> dict[int, str]:
    """The named values of a whole-number parameter: ``0 off, 1 RTL, 2 LAND`` in its description,
    or Disabled/Enabled for a 0/1 switch; {} for a plain number."""
    if not is_int:
        return {}
    found = {int(code): name for code, name in _VALUE_RE.findall(doc.split(":", 1)[-1])}
    if found and set(found) == set(range(int(lo), int(hi) + 1)):
        return found
    if (lo, hi) == (0.0, 1.0):
        return {0: "Disabled", 1: "Enabled"}
    return {}


def _human_name(doc: str) -> str:
    """A short title from the description: its first clause, at most 60 characters."""
    first = re.split(r";| \(", doc, maxsplit=1)[0].strip().rstrip(":,")
    return first if len(first) <= 60 else first[:57].rstrip() + "..."


def _rows(specs: Sequence[ParamSpec] = PARAMS) -> list[tuple[str, str, float, float, float, bool, bool, str, str]]:
    """(name, unit, lo, hi, default, is_int, restart, doc, group) of every parameter, in order."""
    d, o = FcConfig(), FcOptions()
    out: list[tuple[str, str, float, float, float, bool, bool, str, str]] = []
    for p in specs:
        out.append((p.name, p.unit, p.lo, p.hi, _default(p, d, o), p.is_int, p.restart, p.doc, "fc"))
    for sp in SIM_PARAMS:
        out.append((sp.name, sp.unit, sp.lo, sp.hi, sp.default, sp.is_int, False, _sim_doc(sp), "sim"))
    return out


def _default(p: ParamSpec, d: FcConfig, o: FcOptions) -> float:
    return float(p.get(o if p.options else d))


def _sim_doc(sp: SimParam) -> str:
    return sp.doc + " (simulator; volatile: at its default at every start)"


def _num(v: float) -> str:
    return f"{v:g}"


def pdef_xml(specs: Sequence[ParamSpec] = PARAMS) -> str:
    """Every parameter in ArduPilot's ``apm.pdef.xml`` format (deterministic text); ``specs`` the
    FC's (default: the built-in table; ``fc.params.param_table().specs`` adds loaded plug-ins')."""
    root = ET.Element("paramfile")
    vehicles = ET.SubElement(root, "vehicles")
    fc_block = ET.SubElement(vehicles, "parameters", name="ArduCopter")
    libraries = ET.SubElement(root, "libraries")
    sim_block = ET.SubElement(libraries, "parameters", name="SIM_")
    for name, unit, lo, hi, default, is_int, restart, doc, group in _rows(specs):
        block, full = (fc_block, f"ArduCopter:{name}") if group == "fc" else (sim_block, name)
        documentation = f"{doc}. Default {_num(default)}{' ' + unit if unit else ''}."
        el = ET.SubElement(block, "param", humanName=_human_name(doc), name=full, documentation=documentation,
                           user="Advanced" if restart else "Standard")  # fmt: skip
        values = values_of(is_int, lo, hi, doc)
        if values:  # first child: MAVProxy's `param help` lists the values of the first child
            vs = ET.SubElement(el, "values")
            for code, label in values.items():
                ET.SubElement(vs, "value", code=str(code)).text = label
        ET.SubElement(el, "field", name="Range").text = f"{_num(lo)} {_num(hi)}"
        if unit:
            ET.SubElement(el, "field", name="Units").text = unit
        if is_int:
            ET.SubElement(el, "field", name="Increment").text = "1"
        if restart:
            ET.SubElement(el, "field", name="RebootRequired").text = "True"
    ET.indent(root, space="  ")
    # no encoding in the declaration: lxml (MAVProxy's loader) refuses one on text it reads as str
    return '<?xml version="1.0"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def parameters_markdown() -> str:
    """Every parameter as a Markdown table (``docs/parameters.md``)."""
    lines = [
        "# Parameters",
        "",
        "<!-- generated by `python -m fc.param_meta` from the parameter table (fc/params.py); do not edit -->",
        "",
        "Every parameter the flight controller serves over MAVLink (`smcpilot gcs param list` prints the same",
        "table with the values in force). *restart*: takes effect at the next start. The `SIM_*` parameters",
        "belong to the simulator: live, volatile (at their defaults at every start), never in a parameter file.",
        "The same metadata in ArduPilot's format, for MAVProxy (`param set_xml_filepath smcpilot/data/apm.pdef.xml`,",
        "then `param help NAME`) and QGroundControl: [apm.pdef.xml](../smcpilot/data/apm.pdef.xml).",
        "",
        "Parameter files: a run loads one only when `--param-file FILE` names it (kept across runs, saved",
        "to after every change); otherwise it starts from these defaults and writes its values to",
        "`NAME.parm` beside its log. Every run prints which file it loaded and how many values differ.",
        "",
        "| name | default | range | unit | description |",
        "|---|---|---|---|---|",
    ]
    for name, unit, lo, hi, default, is_int, restart, doc, _group in _rows():
        values = values_of(is_int, lo, hi, doc)
        extra = (" Values: " + ", ".join(f"{k} {v}" for k, v in values.items()) + ".") if values and ":" not in doc else ""
        desc = doc.replace("|", "\\|") + extra + (" *(restart)*" if restart else "")
        lines.append(f"| `{name}` | {_num(default)} | {_num(lo)} .. {_num(hi)} | {unit or '-'} | {desc} |")
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m fc.param_meta", description="Write (or --check) smcpilot/data/apm.pdef.xml and"
                                " docs/parameters.md from the parameter table.")  # fmt: skip
    p.add_argument("--check", action="store_true", help="exit 1 if a file is out of date; write nothing")
    args = p.parse_args(argv)
    stale = []
    for path, text in ((PDEF_PATH, pdef_xml()), (MARKDOWN_PATH, parameters_markdown())):
        current = path.read_text(encoding="utf-8") if path.exists() else None
        if current == text:
            continue
        if args.check:
            stale.append(path.name)
        else:
            path.write_text(text, encoding="utf-8")
            print(f"wrote {path.relative_to(_ROOT)}")
    if stale:
        print(f"out of date: {', '.join(stale)}; run: python -m fc.param_meta", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
