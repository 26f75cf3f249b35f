"""``smcpilot laws``: every control law the flight controller can fly, where it comes from, its parameters.

The built-in laws, every installed plug-in (entry points of the group ``smcpilot.laws``) and any
``--law path/to/file.py:NAME`` / ``package.module:NAME`` given, each loaded and validated: a plug-in
that fails to import or register is named in one line (exit 2). ``--pdef FILE`` writes the
``apm.pdef.xml`` of the FC's parameters with the plug-ins' included (for MAVProxy's ``param help``
and QGroundControl); ``--json`` prints the same as data.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from smcpilot.lawref import law_argument


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--law", action="append", default=[], type=law_argument, metavar="REF",
                   help="also load this law: path/to/file.py:NAME or package.module:NAME (repeatable)")  # fmt: skip
    p.add_argument("--params", action="store_true", help="list every law's MAVLink parameters (name, default, range, unit)")
    p.add_argument("--pdef", type=Path, metavar="FILE", help="write the FC's parameter metadata with the plug-ins' (apm.pdef.xml format)")
    p.add_argument("--json", action="store_true", help="print the laws and their parameters as JSON")


def law_rows() -> list[dict[str, Any]]:
    """Every law the FC can fly now (built-ins, then loaded plug-ins) with its parameters."""
    from fc.config import FcConfig
    from fc.control import registry
    from fc.control.purity import law_problems
    from fc.params import param_table

    d = FcConfig()
    table = param_table()
    rows = []
    for index, law in enumerate(registry.flight_laws()):
        style = law_problems(law)
        params = [
            {"name": p.name, "default": p.get(d), "min": p.lo, "max": p.hi, "unit": p.unit, "description": p.doc}
            for p in table.specs
            if law.name in p.laws
        ]
        rows.append({
            "name": law.name, "fc_controller": index, "stage": law.stage, "origin": law.origin, "prefix": law.prefix,
            "description": law.description, "state": list(law.state_names), "diagnostics": list(law.diagnostics),
            "observer_default": law.observer_default, "pure_style": not style, "style_problems": style[:5], "reference": law.reference, "parameters": params,
        })  # fmt: skip
    return rows


def main(args: argparse.Namespace) -> int:
    from fc.control import registry
    from fc.param_meta import pdef_xml
    from fc.params import param_table

    registry.load_installed()
    for ref in args.law:
        registry.resolve(ref)
    rows = law_rows()
    if args.pdef is not None:
        args.pdef.parent.mkdir(parents=True, exist_ok=True)
        args.pdef.write_text(pdef_xml(param_table().specs), encoding="utf-8")
        print(f"laws: wrote {args.pdef} ({len(param_table().specs)} FC parameters)", file=sys.stderr)
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    w = max(len(r["name"]) for r in rows)
    print(f"{'#':>2}  {'law':<{w}}  {'stage':<8}  {'prefix':<6}  origin / description")
    for r in rows:
        print(f"{r['fc_controller']:>2}  {r['name']:<{w}}  {r['stage']:<8}  {r['prefix']:<6}  {r['origin']}: {r['description']}")
        if r["style_problems"]:
            print(f"    {'':<{w}}  not in the pure style (flies in CPython only): {r['style_problems'][0]}")
        if args.params:
            for p in r["parameters"]:
                rng = f"[{p['min']:g}, {p['max']:g}]"
                print(f"      {p['name']:<16} {p['default']:>9g} {p['unit']:<7} {rng:<14} {p['description']}")
    print("\nfly one with --controller NAME (smcpilot run, sitl, demo; fc.controller in a scenario; FC_CONTROLLER on the wire);"
          " --params lists their parameters")  # fmt: skip
    return 0
