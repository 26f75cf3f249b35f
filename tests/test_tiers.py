"""The quick tier (``pytest -m "not slow"``) still covers every package: every module of every
package imports, and the tier keeps one flight in-process, one in SITL and one ground-station
exchange."""

from __future__ import annotations

import ast
import importlib
import pkgutil
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TESTS = ROOT / "tests"
PACKAGES = ("smcpilot", "fc", "sim_bridge", "ground", "lab")


def _modules() -> list[str]:
    out = []
    for package in PACKAGES:
        pkg = importlib.import_module(package)
        out.append(package)
        for info in pkgutil.walk_packages(pkg.__path__, prefix=f"{package}."):
            if not info.name.endswith(".__main__"):  # `python -m fc` runs the process
                out.append(info.name)
    return out


MODULES = _modules()


def test_every_package_has_its_modules_found() -> None:
    for package in PACKAGES:
        files = [p for p in (ROOT / package).rglob("*.py") if p.name != "__main__.py"]
        assert len([m for m in MODULES if m == package or m.startswith(package + ".")]) == len(files), package


@pytest.mark.parametrize("module", MODULES)
def test_every_module_imports(module: str) -> None:
    importlib.import_module(module)


def _functions(path: Path) -> dict[str, ast.FunctionDef]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    return {n.name: n for n in tree.body if isinstance(n, ast.FunctionDef)}


def _module_is_slow(path: Path) -> bool:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    return any(isinstance(n, ast.Assign) and any(getattr(t, "id", "") == "pytestmark" for t in n.targets) and "slow" in ast.unparse(n.value)
               for n in tree.body)  # fmt: skip


#: what the quick tier must keep, whatever else is marked slow.
QUICK_TIER_KEEPS = {
    ("test_run_outputs", "test_a_second_run_into_the_same_out_leaves_only_its_own_files"): "flights in-process (`smcpilot run`)",
    ("test_scenario", "test_in_process_runs_are_deterministic_and_seeded"): "a flight in-process on the flight core",
    ("test_sitl_e2e", "test_smcpilot_sitl_lockstep_duration_exits_0_and_names_the_log"): "a flight in SITL (two processes over UDP)",
    ("test_cli_errors", "test_log_summary_into_head"): "a SITL flight's log read back",
    ("test_gcs_cli", "test_status_json"): "a ground-station exchange with a running FC",
    ("test_cli_usage", "test_an_unknown_option_is_one_line_naming_the_subcommand"): "every subcommand's parser",
}


@pytest.mark.parametrize(("module", "name"), sorted(QUICK_TIER_KEEPS), ids=[f"{m}::{n}" for m, n in sorted(QUICK_TIER_KEEPS)])
def test_the_quick_tier_keeps_a_flight_in_process_one_in_sitl_and_a_ground_station_exchange(module: str, name: str) -> None:
    path = TESTS / f"{module}.py"
    fn = _functions(path).get(name)
    assert fn is not None, f"{module}::{name} is gone: the quick tier needs {QUICK_TIER_KEEPS[(module, name)]}"
    assert not _module_is_slow(path), module
    assert not any("slow" in ast.unparse(d) for d in fn.decorator_list), f"{module}::{name} is marked slow"
