"""The docs stand on their own: the file-format examples load with the project's own loaders,
every relative link in README.md and docs/ points at a file of the repository, and nothing refers
to a place outside it (a sibling checkout, a machine path) or to the project's work history."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from ground.missions.schema import load_mission
from smcpilot.plan import load_plan
from smcpilot.scenario import Scenario
from smcpilot.vehicle import VehicleParams

ROOT = Path(__file__).resolve().parents[1]
FORMATS = ROOT / "docs" / "file-formats.md"
DOCS = sorted((ROOT / "docs").glob("*.md")) + [ROOT / "README.md"]
CODE = [p for d in ("smcpilot", "fc", "sim_bridge", "ground", "lab") for p in sorted((ROOT / d).rglob("*.py"))]

EXAMPLE = re.compile(r"<!-- example: (\w+) -->\s*```toml\n(.*?)```", re.S)


def examples() -> dict[str, str]:
    found = dict(EXAMPLE.findall(FORMATS.read_text(encoding="utf-8")))
    assert set(found) == {"vehicle", "plan", "scenario", "mission"}, sorted(found)
    return found


@pytest.fixture
def example_dir(tmp_path: Path) -> Path:
    for kind, text in examples().items():
        (tmp_path / f"{kind}.toml").write_text(text, encoding="utf-8")
    return tmp_path


def test_vehicle_example_loads(example_dir: Path) -> None:
    v = VehicleParams.from_toml(example_dir / "vehicle.toml")
    assert v.name == "heavy-quad" and v.mass_kg == 1.5
    assert v.thrust_to_weight == pytest.approx(2.0, rel=0.01)  # as its comment says
    assert v.gravity_mps2 == VehicleParams().gravity_mps2  # a key left out takes the default


def test_plan_example_loads(example_dir: Path) -> None:
    steps = load_plan(example_dir / "plan.toml")
    assert [s.action for s in steps] == ["takeoff", "goto", "land"]
    assert steps[1].north_m == 2.0 and steps[1].yaw_deg == 90.0


def test_scenario_example_loads_with_its_vehicle(example_dir: Path) -> None:
    sc = Scenario.from_toml(example_dir / "scenario.toml")
    assert sc.name == "windy-hop" and sc.duration_s == 30.0 and sc.seed == 3
    assert sc.vehicle == VehicleParams.from_toml(example_dir / "vehicle.toml")
    assert dict(sc.params) == {"SMC_CHI_DZ": 0.3}
    assert len(sc.faults) == 1 and len(sc.plan) == 2


def test_mission_example_loads(example_dir: Path) -> None:
    m = load_mission(example_dir / "mission.toml")
    assert [i.type for i in m.items] == ["takeoff", "waypoint", "land"]
    assert [e.kind for e in m.expectations] == ["reach", "landed"]
    assert m.sitl.vehicle == example_dir / "vehicle.toml"


def test_examples_with_a_broken_value_are_refused(example_dir: Path) -> None:
    """The loaders the page names are the ones that check: a bad value in each example fails."""
    from smcpilot.errors import ConfigError

    breakers = {
        "vehicle.toml": ("mass_kg = 1.5", "mass_kg = -1.5", lambda p: VehicleParams.from_toml(p)),
        "plan.toml": ('action = "land"', 'action = "hover"', load_plan),
        "scenario.toml": ("efficiency = 0.8", "efficiency = 1.8", Scenario.from_toml),
        "mission.toml": ("within_m = 0.3", "within_m = -0.3", load_mission),
    }
    for name, (old, new, load) in breakers.items():
        path = example_dir / name
        path.write_text(path.read_text(encoding="utf-8").replace(old, new), encoding="utf-8")
        with pytest.raises(ConfigError):
            load(path)


# ------------------------------------------------------------------------------- links, references
LINK = re.compile(r"\]\(([^)#\s]+)(?:#[^)]*)?\)")
#: Docs written on other branches at the same time; linked before they land.
PENDING = {ROOT / "docs" / "campaigns.md"}


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: p.name)
def test_relative_links_resolve_inside_the_repository(doc: Path) -> None:
    for target in LINK.findall(doc.read_text(encoding="utf-8")):
        if re.match(r"[a-z]+:", target):
            continue  # a URL
        path = (doc.parent / target).resolve()
        assert path.is_relative_to(ROOT), (doc.name, target)
        assert path.exists() or path in PENDING, (doc.name, target)


FORBIDDEN = [
    (re.compile(r"\.\./shared|/work/|/home/\w+|/root/|/tmp/"), "a path outside the repository"),
    (re.compile(r"\bissue\s*#?\d+", re.I), "an issue number"),
    (re.compile(r"\bcommit `?[0-9a-f]{7,40}\b"), "a commit id"),
    (re.compile(r"work in progress", re.I), "work in progress"),
]


@pytest.mark.parametrize("path", DOCS + CODE, ids=lambda p: str(p.relative_to(ROOT)))
def test_no_reference_outside_the_repository(path: Path) -> None:
    text = path.read_text(encoding="utf-8")
    for pattern, what in FORBIDDEN:
        m = pattern.search(text)
        assert m is None, f"{path.relative_to(ROOT)}: {what}: {m.group(0)!r}"


def test_readme_points_to_the_formats_and_the_equations() -> None:
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert "docs/file-formats.md" in readme and "docs/pid-smc.md" in readme
    assert "smcpilot log clean" in readme  # where logs go and how to clean them


def test_pid_smc_doc_matches_the_code() -> None:
    """Spot checks of docs/pid-smc.md against fc/control/pid_smc.py and the paper scenario."""
    from fc.control.gains import PAPER_GAINS
    from fc.control.pid_smc import AdaptationBounds

    doc = (ROOT / "docs" / "pid-smc.md").read_text(encoding="utf-8")
    g = PAPER_GAINS[0]
    assert f"c1 = {g.c1:g}, c2 = {g.c2:g}, kp = {g.kp:g}, ki = {g.ki:g}, kd = {g.kd:g}" in doc
    assert f"κ = {g.kappa:g}" in doc
    assert "[" + ", ".join(f"{x.chi:.1f}" for x in PAPER_GAINS) + "]" in doc  # the known bound χ
    b = AdaptationBounds()
    assert (b.dead_zone, b.leakage_per_s, b.chi_hat_min, b.chi_hat_max) == (0.0, 0.0, 0.0, float("inf"))
    assert "Θ max(|σ| − dead_zone, 0) − leakage (χ̂ − χ̂(0))" in doc
