"""The campaign file: a base scenario, the controllers, the seeds and the variations, validated.

A campaign TOML file (every path relative to the file; every key but ``scenario`` optional)::

    name = "mass-wind"
    description = "payload and wind spread, adaptive PID-SMC against the cascaded PID"
    seed = 1                       # the campaign seed: every unit's draws derive from it
    seeds = 20                     # flights per controller and scenario group
    scenario = "../scenarios/hover.toml"   # or an inline [scenario] table (the scenario TOML keys)
    duration_s = 12.0              # overrides the scenario's
    score_from_s = 6.0             # metrics from this simulated time on (after the take-off)
    timeout_s = 120.0              # wall-clock limit of one flight; over it: "timed out"
    controllers = ["adaptive_pid_smc", "cascade_pid"]   # FC laws (default: the scenario's)

    [[controller]]                 # or labelled variants with FC parameters of their own
    label = "adaptive-no-dob"
    controller = "adaptive_pid_smc"
    params = { DOB_MODE = 0 }

    [[vary]]                       # a distribution: one draw per seed
    field = "plant.mass_kg"        # the simulated vehicle only: the FC keeps its model
    dist = "uniform"               # uniform (low, high), normal (mean, std), log-uniform (low, high),
    low = 0.9                      # choice (values, optional weights)
    high = 1.3
    relative = true                # the draw multiplies the base value

    [[vary]]                       # a grid: one scenario group per value (groups multiply)
    field = "environment.wind_force_ned_n[0]"
    grid = [0.0, -0.5, -1.0]

Fields name scenario keys as the scenario file writes them: ``duration_s``, ``vehicle.KEY``
(FC model and plant), ``plant.KEY`` (plant only), ``environment.KEY`` (``[i]`` for an element
of a vector), ``fc.params.NAME`` (FC parameters, e.g. gains ``SMC_RLL_KP``), ``fc.rate_hz``,
``sim.physics_hz``, ``step[N].KEY`` and ``fault[N].KEY`` (the base scenario's N-th step or
fault, from 1: set-points, fault timing and size). Unknown fields, empty ranges and invalid
distribution parameters raise :class:`CampaignError` naming the problem (with the close match of
a misspelt name), before anything flies.
"""

from __future__ import annotations

import difflib
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from smcpilot.errors import ConfigError
from smcpilot.faults import KIND_FIELDS
from smcpilot.lawref import known_law_names, law_reference_problem
from smcpilot.scenario import Scenario
from smcpilot.tomlfile import read_toml
from smcpilot.vehicle import VehicleParams

DISTRIBUTIONS = ("uniform", "normal", "log-uniform", "choice")
_TOP = {"name", "description", "seed", "seeds", "scenario", "duration_s", "score_from_s", "timeout_s", "controllers", "controller", "vary"}
_VARY_KEYS = {"field", "dist", "low", "high", "mean", "std", "values", "weights", "grid", "relative"}
_VEHICLE_KEYS = tuple(f.name for f in fields(VehicleParams))
_ENV_KEYS = ("noise", "noise_scale", "wind_force_ned_n", "gust_std_n", "gust_tau_s", "paper_disturbance")
_STEP_KEYS = ("t_s", "north_m", "east_m", "alt_m", "yaw_deg")
_PATH = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)(?:\[(\d+)\])?$")


class CampaignError(ConfigError):
    """A campaign or tuning file is invalid (the message names the file and the key)."""


def did_you_mean(name: str, known: Sequence[str]) -> str:
    """`` (did you mean 'x'?)`` for the close match of ``name`` among ``known``, or ``""``."""
    close = difflib.get_close_matches(name, list(known), n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


@dataclass(frozen=True)
class Variant:
    """A controller as a campaign flies it: an FC law and parameter overrides, under a label."""

    label: str
    controller: str
    params: tuple[tuple[str, float], ...] = ()
    description: str = ""


@dataclass(frozen=True)
class FieldRef:
    """A scenario field a variation sets: ``section`` (top, vehicle, plant, environment, params,
    fc, sim, step, fault), its ``key``, the list ``item`` (step/fault, from 0) and vector ``index``."""

    text: str
    section: str
    key: str
    item: int | None = None
    index: int | None = None

    def column(self) -> str:
        """The results column of the sampled value (the field as written)."""
        return self.text


@dataclass(frozen=True)
class Variation:
    """One ``[[vary]]`` table: a distribution (one draw per seed) or a grid (one group per value)."""

    ref: FieldRef
    dist: str  # uniform, normal, log-uniform, choice, grid
    low: float = math.nan
    high: float = math.nan
    mean: float = math.nan
    std: float = math.nan
    values: tuple[Any, ...] = ()
    weights: tuple[float, ...] = ()
    relative: bool = False

    @property
    def is_grid(self) -> bool:
        return self.dist == "grid"


@dataclass(frozen=True)
class CampaignSpec:
    """A parsed campaign file (see the module docstring)."""

    name: str
    base: Scenario
    variants: tuple[Variant, ...]
    seeds: int = 10
    seed: int = 0
    variations: tuple[Variation, ...] = ()
    description: str = ""
    score_from_s: float = 0.0
    timeout_s: float = 600.0
    source: str = "campaign"
    #: the parsed document, kept so a results directory can re-create the campaign (replay).
    doc: Mapping[str, Any] = field(default_factory=dict, compare=False, repr=False)
    base_dir: Path | None = field(default=None, compare=False, repr=False)

    @property
    def grids(self) -> tuple[Variation, ...]:
        return tuple(v for v in self.variations if v.is_grid)

    @property
    def draws(self) -> tuple[Variation, ...]:
        return tuple(v for v in self.variations if not v.is_grid)

    @property
    def n_groups(self) -> int:
        return math.prod(len(v.values) for v in self.grids)

    @property
    def n_units(self) -> int:
        return self.n_groups * len(self.variants) * self.seeds


# -- parsing -----------------------------------------------------------------------------------------
def _num(value: Any, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise CampaignError(f"{where} must be a finite number, got {value!r}")
    return float(value)


def parse_field(text: Any, base: Scenario, where: str) -> FieldRef:
    """The :class:`FieldRef` of a field name, checked against ``base`` (unknown names suggest the
    close match)."""
    from fc.params import param_table

    if not isinstance(text, str) or not text:
        raise CampaignError(f"{where}.field must be a scenario field name such as 'vehicle.mass_kg', got {text!r}")
    parts = text.split(".")
    head = _PATH.match(parts[0])
    if head is None:
        raise CampaignError(f"{where}: cannot read field {text!r}")
    name, idx = head.group(1), head.group(2)
    sections = ["duration_s", "vehicle", "plant", "environment", "fc", "sim", "step", "fault"]

    def vector_index(key_part: str, allowed: Sequence[str], sec: str) -> tuple[str, int | None]:
        m = _PATH.match(key_part)
        if m is None:
            raise CampaignError(f"{where}: cannot read field {text!r}")
        key, i = m.group(1), m.group(2)
        if key not in allowed:
            raise CampaignError(f"{where}: unknown field {text!r}: {sec} has no key {key!r}{did_you_mean(key, allowed)}")
        return key, None if i is None else int(i)

    if name == "duration_s" and len(parts) == 1 and idx is None:
        return FieldRef(text, "top", "duration_s")
    if name in ("seed", "name", "description"):
        raise CampaignError(f"{where}: {text!r} cannot vary (the campaign derives every unit's seed from its own)")
    if name not in sections:
        raise CampaignError(f"{where}: unknown field {text!r}{did_you_mean(name, sections)}")
    if name in ("vehicle", "plant", "environment", "sim") and (len(parts) != 2 or idx is not None):
        raise CampaignError(f"{where}: field {text!r} must be {name}.KEY")
    if name in ("vehicle", "plant"):
        key, i = vector_index(parts[1], _VEHICLE_KEYS, name)
        return FieldRef(text, name, key, None, i)
    if name == "environment":
        key, i = vector_index(parts[1], _ENV_KEYS, "environment")
        if (key == "wind_force_ned_n") != (i is not None) or (i is not None and i > 2):
            raise CampaignError(f"{where}: field {text!r}: wind_force_ned_n takes an index [0..2] (north, east, down); the others none")
        return FieldRef(text, "environment", key, None, i)
    if name == "sim":
        key, _ = vector_index(parts[1], ("physics_hz",), "sim")
        return FieldRef(text, "sim", key)
    if name == "fc":
        if len(parts) == 3 and parts[1] == "params":
            pname = parts[2]
            index = param_table().index
            if pname not in index:
                raise CampaignError(f"{where}: unknown FC parameter {pname!r} in {text!r}{did_you_mean(pname, sorted(index))}")
            return FieldRef(text, "params", pname)
        if len(parts) == 2:
            key, _ = vector_index(parts[1], ("rate_hz",), "fc")
            return FieldRef(text, "fc", key)
        raise CampaignError(f"{where}: field {text!r} must be fc.params.NAME or fc.rate_hz (controllers are the campaign's own list)")
    # step[N].KEY / fault[N].KEY
    items = base.plan if name == "step" else base.faults
    if idx is None or len(parts) != 2:
        raise CampaignError(f"{where}: field {text!r} must be {name}[N].KEY, N counting from 1")
    n = int(idx)
    if not 1 <= n <= len(items):
        raise CampaignError(f"{where}: field {text!r}: the base scenario has {len(items)} {name} table(s)")
    if name == "step":
        allowed: Sequence[str] = _STEP_KEYS
    else:
        allowed = ("start_s", "stop_s", *KIND_FIELDS[base.faults[n - 1].kind])
    key, i = vector_index(parts[1], allowed, f"{name}[{n}]")
    return FieldRef(text, name, key, n - 1, i)


def _variation(t: Any, base: Scenario, where: str) -> Variation:
    if not isinstance(t, dict):
        raise CampaignError(f"{where} must be a table, got {t!r}")
    unknown = sorted(set(t) - _VARY_KEYS)
    if unknown:
        raise CampaignError(f"{where}: unknown key {unknown[0]!r}{did_you_mean(unknown[0], sorted(_VARY_KEYS))}")
    ref = parse_field(t.get("field"), base, where)
    where = f"{where} ({ref.text})"
    relative = t.get("relative", False)
    if not isinstance(relative, bool):
        raise CampaignError(f"{where}: relative must be true or false, got {relative!r}")
    if "grid" in t:
        if "dist" in t:
            raise CampaignError(f"{where}: give either dist or grid, not both")
        values = t["grid"]
        if not isinstance(values, list) or not values:
            raise CampaignError(f"{where}: grid must be a non-empty list of values, got {values!r}")
        return Variation(ref, "grid", values=tuple(values), relative=relative)
    dist = t.get("dist")
    if dist not in DISTRIBUTIONS:
        raise CampaignError(f"{where}: dist must be one of {', '.join(DISTRIBUTIONS)} (or give grid = [...]), got {dist!r}"
                            + (did_you_mean(dist, DISTRIBUTIONS) if isinstance(dist, str) else ""))  # fmt: skip
    need = {"uniform": ("low", "high"), "log-uniform": ("low", "high"), "normal": ("mean", "std"), "choice": ("values",)}[dist]
    extra = sorted(set(t) - {"field", "dist", "relative", "weights" if dist == "choice" else "", *need})
    if extra:
        raise CampaignError(f"{where}: {dist} takes {', '.join(need)}, not {extra[0]!r}")
    for k in need:
        if k not in t:
            raise CampaignError(f"{where}: {dist} needs {' and '.join(need)}; {k} is missing")
    if dist in ("uniform", "log-uniform"):
        low, high = _num(t["low"], f"{where}: low"), _num(t["high"], f"{where}: high")
        if not low < high:
            raise CampaignError(f"{where}: empty range: low ({low:g}) must be below high ({high:g})")
        if dist == "log-uniform" and low <= 0.0:
            raise CampaignError(f"{where}: log-uniform needs 0 < low < high, got low = {low:g}")
        return Variation(ref, dist, low=low, high=high, relative=relative)
    if dist == "normal":
        mean, std = _num(t["mean"], f"{where}: mean"), _num(t["std"], f"{where}: std")
        if not std > 0.0:
            raise CampaignError(f"{where}: normal needs std > 0, got {std:g}")
        return Variation(ref, dist, mean=mean, std=std, relative=relative)
    values = t["values"]
    if not isinstance(values, list) or not values:
        raise CampaignError(f"{where}: choice needs a non-empty list of values, got {values!r}")
    weights: tuple[float, ...] = ()
    if "weights" in t:
        w = t["weights"]
        if not isinstance(w, list) or len(w) != len(values):
            raise CampaignError(f"{where}: weights must be a list as long as values ({len(values)}), got {w!r}")
        weights = tuple(_num(x, f"{where}: weights") for x in w)
        if any(x < 0 for x in weights) or not sum(weights) > 0:
            raise CampaignError(f"{where}: weights must be >= 0 with a positive sum, got {w!r}")
    return Variation(ref, "choice", values=tuple(values), weights=weights, relative=relative)


def _law(ref: Any, where: str, base_dir: Path | None) -> str:
    """A controller reference checked and loaded (a file path made absolute against ``base_dir``):
    its parameters are then known to ``fc.params.NAME`` fields and ``[[gain]]`` tables."""
    from fc.control import registry

    problem = law_reference_problem(ref)
    if problem:
        raise CampaignError(f"{where}: {problem}")
    ref = registry.normalise_reference(ref, base_dir)
    try:
        registry.resolve(ref)
    except ConfigError as exc:
        raise CampaignError(f"{where}: {exc}") from None
    return ref


def _variants(doc: Mapping[str, Any], base: Scenario, source: str, base_dir: Path | None = None) -> tuple[Variant, ...]:
    if "controllers" in doc and "controller" in doc:
        raise CampaignError(f"{source}: give either controllers = [...] or [[controller]] tables, not both")
    if "controller" in doc:
        tables = doc["controller"]
        if not isinstance(tables, list) or not tables:
            raise CampaignError(f"{source}: controller must be [[controller]] tables")
        out = []
        for i, t in enumerate(tables, start=1):
            where = f"{source}: controller[{i}]"
            if not isinstance(t, dict):
                raise CampaignError(f"{where} must be a table")
            unknown = sorted(set(t) - {"label", "controller", "params", "description"})
            if unknown:
                raise CampaignError(f"{where}: unknown key {unknown[0]!r}{did_you_mean(unknown[0], ['label', 'controller', 'params', 'description'])}")
            law = _law(t.get("controller", base.controller), where, base_dir)
            params = t.get("params", {})
            if not isinstance(params, dict):
                raise CampaignError(f"{where}: params must be a table of NAME = value")
            label = t.get("label", law)
            if not isinstance(label, str) or not label:
                raise CampaignError(f"{where}: label must be a non-empty string")
            out.append(Variant(label, law, tuple((str(k), _num(v, f"{where}: params.{k}")) for k, v in params.items()), str(t.get("description", ""))))
    else:
        names = doc.get("controllers", [base.controller])
        if not isinstance(names, list) or not names:
            raise CampaignError(f"{source}: controllers must be a non-empty list of law names ({', '.join(known_law_names())})")
        out = []
        for n in names:
            if isinstance(n, str) and law_reference_problem(n) and ":" not in n:
                raise CampaignError(f"{source}: {law_reference_problem(n)}" + did_you_mean(n, known_law_names()))
            law = _law(n, source, base_dir)
            out.append(Variant(n, law))
    labels = [v.label for v in out]
    if len(set(labels)) != len(labels):
        raise CampaignError(f"{source}: controller labels must differ, got {labels}")
    return tuple(out)


def load_base_scenario(doc: Mapping[str, Any], source: str, base_dir: Path | None) -> Scenario:
    """The ``scenario`` of a campaign or tuning document: a file (relative to ``base_dir``) or an
    inline table."""
    sc = doc.get("scenario")
    if isinstance(sc, str):
        p = Path(sc)
        if base_dir is not None and not p.is_absolute():
            p = base_dir / p
        return Scenario.from_toml(p)
    if isinstance(sc, dict):
        return Scenario.from_mapping(sc, source=f"{source} [scenario]", base_dir=base_dir)
    raise CampaignError(f"{source}: scenario must be a scenario file path or an inline [scenario] table, got {sc!r}")


def parse_campaign(doc: Mapping[str, Any], *, source: str = "campaign", base_dir: Path | None = None) -> CampaignSpec:
    """A :class:`CampaignSpec` of a parsed campaign document; errors name ``source`` and the key."""
    unknown = sorted(set(doc) - _TOP)
    if unknown:
        raise CampaignError(f"{source}: unknown key {unknown[0]!r}{did_you_mean(unknown[0], sorted(_TOP))}")
    if "scenario" not in doc:
        raise CampaignError(f"{source}: scenario is missing (a scenario file path or an inline [scenario] table)")
    base = load_base_scenario(doc, source, base_dir)
    if "duration_s" in doc:
        d = _num(doc["duration_s"], f"{source}: duration_s")
        if d <= 0:
            raise CampaignError(f"{source}: duration_s must be > 0 simulated seconds, got {d:g}")
        base = base.with_changes(duration_s=d)
    seeds = doc.get("seeds", 10)
    if isinstance(seeds, bool) or not isinstance(seeds, int) or seeds < 1:
        raise CampaignError(f"{source}: seeds must be a whole number >= 1, got {seeds!r}")
    seed = doc.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise CampaignError(f"{source}: seed must be a whole number >= 0, got {seed!r}")
    score_from_s = _num(doc.get("score_from_s", 0.0), f"{source}: score_from_s")
    if not 0.0 <= score_from_s < base.duration_s:
        raise CampaignError(f"{source}: score_from_s must lie in [0, duration_s = {base.duration_s:g}), got {score_from_s:g}")
    timeout_s = _num(doc.get("timeout_s", 600.0), f"{source}: timeout_s")
    if timeout_s <= 0:
        raise CampaignError(f"{source}: timeout_s must be > 0 s, got {timeout_s:g}")
    variants = _variants(doc, base, source, base_dir)  # first: a plug-in law's parameters become known
    vary = doc.get("vary", [])
    if not isinstance(vary, list):
        raise CampaignError(f"{source}: vary must be [[vary]] tables")
    variations = tuple(_variation(t, base, f"{source}: vary[{i}]") for i, t in enumerate(vary, start=1))
    cols = [v.ref.text for v in variations]
    if len(set(cols)) != len(cols):
        raise CampaignError(f"{source}: a field varies twice: {sorted(c for c in cols if cols.count(c) > 1)[0]!r}")
    name = doc.get("name", Path(source).stem if source != "campaign" else "campaign")
    if not isinstance(name, str) or not name:
        raise CampaignError(f"{source}: name must be a non-empty string")
    spec = CampaignSpec(name=name, base=base, variants=variants, seeds=seeds, seed=seed, variations=variations,
                        description=str(doc.get("description", "")), score_from_s=score_from_s, timeout_s=timeout_s,
                        source=source, doc=dict(doc), base_dir=base_dir)  # fmt: skip
    return spec


def load_campaign(path: str | Path) -> CampaignSpec:
    """Read and validate a campaign file (relative paths resolve against its folder)."""
    p = Path(path)
    doc = read_toml(p, CampaignError, "campaign file")
    return parse_campaign(doc, source=str(p), base_dir=p.parent.resolve())
