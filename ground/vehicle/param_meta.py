"""What each parameter means: units, range, description, named values, for people reading them.

Read from the ``apm.pdef.xml`` file shipped with the package (ArduPilot's parameter-metadata
format, the file MAVProxy's ``param help`` and QGroundControl read; generated from the flight
controller's parameter table by ``python -m fc.param_meta``). It is parsed here with
:mod:`xml.etree` to the same schema MAVProxy walks: ``paramfile/vehicles/parameters/param``
(names ``Vehicle:NAME``) and ``paramfile/libraries/parameters/param``; each ``param`` has
``humanName`` and ``documentation`` attributes, ``field`` children named ``Range`` ("lo hi"),
``Units``, ``RebootRequired``, and optional ``values/value[@code]``.
"""

from __future__ import annotations

import functools
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

from smcpilot.errors import ConfigError

__all__ = ["ParamMeta", "load_param_meta", "param_meta"]


@dataclass(frozen=True)
class ParamMeta:
    """One parameter's metadata (units as ArduPilot writes them: m, s, Hz, deg, m/s, 1/s ...)."""

    name: str
    human_name: str
    description: str
    unit: str = ""
    lo: float | None = None
    hi: float | None = None
    restart: bool = False
    values: dict[int, str] = field(default_factory=dict)

    def range_text(self) -> str:
        return "" if self.lo is None or self.hi is None else f"{self.lo:g} .. {self.hi:g}"


def load_param_meta(path: Path | None = None) -> dict[str, ParamMeta]:
    """Every parameter of an ``apm.pdef.xml`` file (default: the one shipped), by name."""
    try:
        text = path.read_bytes() if path is not None else (resources.files("smcpilot") / "data" / "apm.pdef.xml").read_bytes()
        root = ET.fromstring(text)
    except (OSError, ET.ParseError) as exc:
        raise ConfigError(f"parameter metadata {path or 'apm.pdef.xml'}: {exc}") from None
    out: dict[str, ParamMeta] = {}
    for block in root.findall("vehicles/parameters") + root.findall("libraries/parameters"):
        for p in block.findall("param"):
            name = (p.get("name") or "").split(":")[-1]
            fields = {f.get("name"): (f.text or "").strip() for f in p.findall("field")}
            lo = hi = None
            if "Range" in fields:
                parts = fields["Range"].split()
                if len(parts) == 2:
                    lo, hi = float(parts[0]), float(parts[1])
            values = {int(v.get("code", "0")): (v.text or "").strip() for v in p.findall("values/value")}
            out[name] = ParamMeta(name, p.get("humanName", ""), p.get("documentation", ""), fields.get("Units", ""), lo, hi,
                                  fields.get("RebootRequired") == "True", values)  # fmt: skip
    return out


@functools.cache
def param_meta() -> dict[str, ParamMeta]:
    """The shipped metadata, read once."""
    return load_param_meta()
