"""A campaign's units: one flight each, with its seeds and sampled values, derived reproducibly.

Order: scenario group (a point of the grids) × controller × seed index; a unit's index in that
order is its id (``smcpilot campaign replay DIR UNIT``).

Seeds: every draw of seed index ``s`` comes from ``numpy.random.SeedSequence(campaign_seed,
spawn_key=(s, j))``: ``j = 0`` gives the scenario seed (the simulator splits separate gust and
sensor-noise streams off it, and seeds the faults' streams from it by name), ``j = 1 + k`` the stream of the k-th ``[[vary]]`` table
(initial conditions, vehicle, wind, fault timing: whatever it varies). So a unit's draws depend only
on the campaign seed, its seed index and the variation, never on the number of workers or the order
units finish in; adding a variation leaves the others' draws as they were; and seed ``s`` is the
same perturbed vehicle, wind and noise for every controller and every grid group, a paired
comparison (the controller is the only difference between two units of one seed index and group).
"""

from __future__ import annotations

import functools
import itertools
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from lab.campaign.spec import CampaignError, CampaignSpec, FieldRef, Variant, Variation
from smcpilot.errors import ConfigError
from smcpilot.scenario import Scenario
from smcpilot.vehicle import VehicleParams


@dataclass(frozen=True)
class Unit:
    """One flight: the scenario as flown (controller, parameters, seed and sampled values applied),
    the plant's own vehicle when a variation changed only the plant, and how to score it."""

    index: int
    group: str
    controller: str
    seed_index: int
    scenario: Scenario
    #: the simulated vehicle when it differs from the FC's model (``plant.*`` fields), else None.
    plant_vehicle: VehicleParams | None = None
    #: (results column, value flown) of every sampled or grid field (a relative draw times the base value).
    values: tuple[tuple[str, Any], ...] = ()
    #: metrics from this simulated time on.
    score_from_s: float = 0.0
    #: wall-clock limit of the flight, s.
    timeout_s: float = 600.0
    #: fly as the two SITL processes over UDP instead of in-process.
    sitl: bool = False
    #: samples every this many ticks for the metrics.
    record_every: int = 5

    @property
    def seed(self) -> int:
        return self.scenario.seed

    @property
    def fault_starts_s(self) -> tuple[float, ...]:
        """Starts of the faults inside the scored window (recovery is timed from them; a fault on
        from before the window, such as gusts from t = 0, has no recovery)."""
        return tuple(sorted(f.start_s for f in self.scenario.faults if f.start_s >= self.score_from_s))


def scenario_seed(campaign_seed: int, seed_index: int) -> int:
    """The scenario (simulator) seed of seed index ``seed_index``: stream 0 of its SeedSequence."""
    return int(np.random.SeedSequence(campaign_seed, spawn_key=(seed_index, 0)).generate_state(1, np.uint32)[0])


def draw(v: Variation, campaign_seed: int, seed_index: int, k: int) -> Any:
    """The value of the k-th variation for seed index ``seed_index`` (its own stream)."""
    rng = np.random.default_rng(np.random.SeedSequence(campaign_seed, spawn_key=(seed_index, 1 + k)))
    if v.dist == "uniform":
        return float(rng.uniform(v.low, v.high))
    if v.dist == "log-uniform":
        return float(math.exp(rng.uniform(math.log(v.low), math.log(v.high))))
    if v.dist == "normal":
        return float(rng.normal(v.mean, v.std))
    if v.dist == "choice":
        p = None if not v.weights else np.asarray(v.weights, dtype=float) / sum(v.weights)
        return v.values[int(rng.choice(len(v.values), p=p))]
    raise CampaignError(f"{v.ref.text}: not a distribution: {v.dist}")


def _set(container: Any, key: Any, ref: FieldRef, value: Any, relative: bool) -> Any:
    """Set ``container[key]`` (element ``ref.index`` of a vector) to ``value`` (× the old value if
    relative); return the value set."""
    if ref.index is not None:
        vec = container.get(key) if isinstance(container, dict) else container[key]
        if not isinstance(vec, list) or ref.index >= len(vec):
            raise CampaignError(f"field {ref.text!r}: {key} is not a vector with an element {ref.index}")
        container, key = vec, ref.index
    if relative:
        old = container[key] if not isinstance(container, dict) else container.get(key)
        if isinstance(old, bool) or not isinstance(old, (int, float)) or isinstance(value, bool) or not isinstance(value, (int, float)):
            raise CampaignError(f"field {ref.text!r}: relative needs a number on a numeric field, got {value!r} on {old!r}")
        value = float(old) * float(value)
    container[key] = value
    return value


#: (controller, rate, parameters) already accepted by the FC's parameter table.
_CHECKED: set[tuple[Any, ...]] = set()


@functools.lru_cache(maxsize=64)
def _template(base: Scenario) -> str:
    """The scenario document of ``base`` with the vehicle inline, as JSON (copied per unit)."""
    doc = base.to_mapping()
    doc["vehicle"] = {"plant": base.plant, **base.vehicle.to_dict()}
    return json.dumps(doc)


def apply_values(
    base: Scenario, variant: Variant, values: Sequence[tuple[Variation, Any]], seed: int
) -> tuple[Scenario, VehicleParams | None, dict[str, Any]]:
    """The scenario of ``variant`` with ``values`` applied and ``seed``, the plant's own vehicle
    (None if no ``plant.*`` field was set), and the value each field got (a relative draw times the
    base value). Raises :class:`~smcpilot.errors.ConfigError` (a
    :class:`~smcpilot.scenario.ScenarioError` for a value the scenario refuses)."""
    from fc.params import config_for, spec

    doc = json.loads(_template(base))
    doc["fc"]["controller"] = variant.controller
    params = {**dict(base.params), **dict(variant.params)}
    plant: dict[str, Any] | None = None
    config = None
    applied: dict[str, Any] = {}
    for v, value in values:
        ref = v.ref
        if ref.section == "top":
            applied[ref.text] = _set(doc, ref.key, ref, value, v.relative)
        elif ref.section in ("vehicle", "environment", "sim", "fc"):
            applied[ref.text] = _set(doc[ref.section], ref.key, ref, value, v.relative)
        elif ref.section == "plant":
            if plant is None:
                plant = {}
            plant[ref.text] = (ref, value, v.relative)
        elif ref.section == "params":
            if v.relative and ref.key not in params:
                if config is None:
                    config = config_for(base.with_changes(controller=variant.controller, params=tuple(params.items())))
                params[ref.key] = float(spec(ref.key).get(config))
            applied[ref.text] = _set(params, ref.key, ref, value, v.relative)
        elif ref.section in ("step", "fault"):
            assert ref.item is not None
            applied[ref.text] = _set(doc[ref.section][ref.item], ref.key, ref, value, v.relative)
    doc["fc"]["params"] = params
    if not params:
        del doc["fc"]["params"]
    doc["seed"] = seed
    scenario = Scenario.from_mapping(doc, source=base.name)
    if scenario.vehicle_file is None and base.vehicle_file is not None and scenario.vehicle == base.vehicle:
        scenario = scenario.with_changes(vehicle_file=base.vehicle_file)
    plant_vehicle = None
    if plant is not None:
        pdoc = scenario.vehicle.to_dict()
        for ref, value, rel in plant.values():
            applied[ref.text] = _set(pdoc, ref.key, ref, value, rel)
        plant_vehicle = VehicleParams.from_mapping(pdoc, source="plant")
    key = (scenario.controller, scenario.rate_hz, scenario.params)
    if key not in _CHECKED:  # unknown or out-of-range FC parameters: an error now, not in a worker
        config_for(scenario)
        if len(_CHECKED) > 10_000:
            _CHECKED.clear()
        _CHECKED.add(key)
    return scenario, plant_vehicle, applied


def _fmt(value: Any) -> str:
    return f"{value:g}" if isinstance(value, float) else str(value)


def groups(spec: CampaignSpec) -> list[tuple[str, tuple[tuple[Variation, Any], ...]]]:
    """The scenario groups: (label, grid values) for every point of the grids (one "base" group without)."""
    grids = spec.grids
    if not grids:
        return [("base", ())]
    out = []
    for combo in itertools.product(*(v.values for v in grids)):
        label = ", ".join(f"{v.ref.text}={_fmt(x)}" for v, x in zip(grids, combo))
        out.append((label, tuple(zip(grids, combo))))
    return out


def expand(spec: CampaignSpec, *, sitl: bool = False, extra_params: Sequence[tuple[str, float]] = (), first_index: int = 0) -> list[Unit]:
    """Every unit of the campaign, validated (a sampled value the scenario refuses raises
    :class:`CampaignError` naming the unit and the values). ``extra_params`` override every
    variant's FC parameters (a tuning trial's gains)."""
    draws = spec.draws
    k_of = {id(v): k for k, v in enumerate(spec.variations)}
    sampled = [[(v, draw(v, spec.seed, s, k_of[id(v)])) for v in draws] for s in range(spec.seeds)]
    seeds = [scenario_seed(spec.seed, s) for s in range(spec.seeds)]
    if sitl and any(v.ref.section == "plant" for v in spec.variations):
        raise CampaignError(f"{spec.source}: plant.* fields (a plant the FC is not told of) fly in-process only, not with --sitl")
    units: list[Unit] = []
    i = first_index
    for label, grid_values in groups(spec):
        for variant in spec.variants:
            if extra_params:
                variant = Variant(variant.label, variant.controller, (*variant.params, *extra_params), variant.description)
            for s in range(spec.seeds):
                values = (*grid_values, *sampled[s])
                try:
                    scenario, plant_vehicle, applied = apply_values(spec.base, variant, values, seeds[s])
                except ConfigError as exc:
                    shown = ", ".join(f"{v.ref.text} = {_fmt(x)}" for v, x in values)
                    raise CampaignError(f"{spec.source}: unit {i} ({variant.label}, seed index {s}{'; ' + shown if shown else ''}): {exc}") from None
                units.append(Unit(i, label, variant.label, s, scenario, plant_vehicle, tuple((v.ref.column(), applied[v.ref.text]) for v, _ in values),
                                  spec.score_from_s, spec.timeout_s, sitl))  # fmt: skip
                i += 1
    return units
