"""How much of one motor's thrust can a law lose and stay up: bisected in flight, beside the physics.

The question a fault-tolerance reviewer asks first. Two numbers per law and flight condition:

- **survived**: the largest loss of motor 1's efficiency (its thrust and drag torque scale by
  1 - loss, :mod:`sim_bridge.faults`) at which every seed's flight ends neither crashed nor diverged,
  bisected to ``tol`` on the study's cases (``motor30-hover``, ``motor30-step`` of
  :mod:`lab.compare` with the efficiency changed);
- **physical limit**: the loss beyond which no trim exists -- no rotor speeds within the motors'
  range [w_idle, w_max] give the weight, zero roll and pitch torque and (with the heading held)
  zero yaw torque. With rotor i's efficiency e_i, S_i = e_i w_i^2 (rad/s)^2 and the ``plus`` layout
  (:mod:`smcpilot.model`): roll needs S1 = S3, pitch S2 = S4, yaw S1 + S3 = S2 + S4, thrust
  Kp (S1 + S2 + S3 + S4) = m g, so every S_i = m g / (4 Kp) = S_h, and rotor 1 must turn at
  w1^2 = S_h / e_1 <= w_max^2: e_1 >= S_h / w_max^2. For the default vehicle hover takes half the
  rotors' maximum thrust, so the limit is a 50 % loss. Without the heading (the vehicle may spin)
  only S1 = S3, S2 = S4 and the thrust remain, and the limit moves to
  e_1 >= max(w_idle^2, m g / (2 Kp) - w_max^2) / w_max^2 (:func:`trim_efficiency_min`).

``tests/test_loss_limit.py`` checks the closed form against a linear-programming feasibility
oracle (scipy's ``linprog``) on random vehicles.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

from lab.campaign.engine import ClusterOptions, Engine
from lab.campaign.units import Unit as CampaignUnit
from lab.compare import Case, Variant, study_cases, study_unit
from smcpilot.faults import FaultSpec
from smcpilot.vehicle import VehicleParams

#: the flight conditions: the study's motor-fault cases.
CONDITIONS = {"hover": "motor30-hover", "step": "motor30-step"}


def trim_efficiency_min(vehicle: VehicleParams, *, yaw_held: bool = True) -> float:
    """The smallest efficiency of one rotor at which a hover trim exists within the motors' range
    (see the module doc); 1 - this is the physical limit of the loss."""
    v = vehicle
    s_max = v.rotor_speed_max_radps**2
    s_idle = v.rotor_speed_idle_radps**2
    weight = v.mass_kg * v.gravity_mps2
    if yaw_held:
        s_needed = weight / (4.0 * v.thrust_coeff_n_s2)
    else:
        s_needed = max(s_idle, weight / (2.0 * v.thrust_coeff_n_s2) - s_max)
    return min(1.0, s_needed / s_max)


def loss_case(condition: str, loss: float, duration_s: float = 20.0) -> Case:
    """The study's motor-fault case of ``condition`` with motor 1 losing ``loss`` of its thrust."""
    name = CONDITIONS[condition]
    case = next(c for c in study_cases(duration_s) if c.name == name)
    sc = case.scenario
    faults = tuple(replace(f, efficiency=1.0 - loss) if f.kind == "motor" else f for f in sc.faults)
    assert any(isinstance(f, FaultSpec) and f.kind == "motor" for f in faults)
    label = f"{condition}-{loss:.4f}"
    return replace(case, name=label, scenario=sc.with_changes(name=label, faults=faults))


@dataclass
class Bracket:
    """The bisection of one law in one condition: survives at ``lo``, not at ``hi`` (losses)."""

    variant: Variant
    condition: str
    lo: float = 0.0
    hi: float = 1.0
    #: what happened to the flights at ``hi`` (the first seed's that did not end ok: its status and message).
    why: str = ""

    @property
    def mid(self) -> float:
        return 0.5 * (self.lo + self.hi)


def bisect_loss_limits(
    variants: Sequence[Variant],
    *,
    seeds: int = 3,
    conditions: Sequence[str] = ("hover", "step"),
    tol: float = 0.025,
    duration_s: float = 20.0,
    cluster: ClusterOptions | None = None,
    progress: Callable[[str], None] | None = None,
) -> list[Bracket]:
    """Bisect every variant × condition at once (each round's flights in parallel on the engine):
    a loss counts as survived when every seed's flight ends ok (not crashed, not diverged)."""
    brackets = [Bracket(v, c) for v in variants for c in conditions]
    with Engine(cluster or ClusterOptions(workers=1), tag="loss-limit") as engine:
        rounds = 0
        while any(b.hi - b.lo > tol for b in brackets):
            rounds += 1
            open_ = [b for b in brackets if b.hi - b.lo > tol]
            units: list[CampaignUnit] = []
            owner: list[Bracket] = []
            for b in open_:
                case = loss_case(b.condition, b.mid, duration_s)
                for s in range(seeds):
                    units.append(study_unit(case, b.variant, s, len(units)))
                    owner.append(b)
            results: list[dict[str, Any] | None] = [None] * len(units)

            def take(unit: CampaignUnit, row: dict[str, Any], results: list[dict[str, Any] | None] = results) -> None:
                results[unit.index] = row

            engine.run(units, take)
            lost: dict[int, str] = {}
            for b, row in zip(owner, results):
                status = row["status"] if row is not None else "error"
                if status != "ok" and id(b) not in lost:
                    lost[id(b)] = f"{status}: {row.get('message', '') if row is not None else 'no result'}"
            for b in open_:
                if id(b) in lost:
                    b.hi, b.why = b.mid, lost[id(b)]
                else:
                    b.lo = b.mid
            if progress is not None:
                progress(f"loss-limit: round {rounds}: {len(units)} flights; " + ", ".join(
                    f"{b.variant.label}/{b.condition} [{b.lo:.3f}, {b.hi:.3f}]" for b in brackets))  # fmt: skip
    return brackets


def limits_table(brackets: Sequence[Bracket], vehicle: VehicleParams, seeds: int, tol: float) -> str:
    """Markdown: per law, the largest loss survived in each condition, and the physical limits."""
    held = 1.0 - trim_efficiency_min(vehicle, yaw_held=True)
    free = 1.0 - trim_efficiency_min(vehicle, yaw_held=False)
    conditions = list(dict.fromkeys(b.condition for b in brackets))
    lines = [
        f"Largest loss of motor 1's thrust survived by every one of {seeds} seeds (bisected to {tol:.1%});"
        f" physical limit of a trim: {held:.1%} with the heading held, {free:.1%} without.",
        "",
        "| controller | " + " | ".join(f"survived, {c}" for c in conditions) + " | what ended the first flight not survived (hover) |",
        "|---|" + "---|" * len(conditions) + "---|",
    ]
    for label in dict.fromkeys(b.variant.label for b in brackets):
        row = {b.condition: b for b in brackets if b.variant.label == label}
        why = row[conditions[0]].why.replace("|", "/")
        lines.append(f"| {label} | " + " | ".join(f"{row[c].lo:.1%}" for c in conditions) + f" | {why} |")
    return "\n".join(lines) + "\n"
