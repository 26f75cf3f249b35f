"""The import rules of the layers (docs/architecture.md), checked on every import statement.

``smcpilot`` imports none of the other packages; ``fc`` and ``sim_bridge`` import only
``smcpilot`` (never each other); ``ground`` imports only ``smcpilot`` (it talks to the FC through
MAVLink alone); ``lab`` may import any of them. Imports inside functions and ``TYPE_CHECKING``
blocks count, and so do ``importlib.import_module("...")``/``__import__("...")`` with a literal.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("smcpilot", "fc", "sim_bridge", "ground", "lab")
#: package -> the project packages it must not import
FORBIDDEN = {
    "smcpilot": {"fc", "sim_bridge", "ground", "lab"},
    "fc": {"sim_bridge", "ground", "lab"},
    "sim_bridge": {"fc", "ground", "lab"},
    "ground": {"fc", "sim_bridge", "lab"},
    "lab": set(),
}


def imported_packages(path: Path) -> list[tuple[int, str]]:
    """(line, top-level package) of every import in a file, relative imports resolved."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    rel = path.relative_to(ROOT).with_suffix("").parts
    out: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name.split(".")[0]) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative: resolve against this module's package
                base = rel[: len(rel) - node.level]
                out.append((node.lineno, (base + tuple((node.module or "").split(".")))[0]))
            elif node.module:
                out.append((node.lineno, node.module.split(".")[0]))
        elif isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant):
            fn = node.func
            name = fn.attr if isinstance(fn, ast.Attribute) else fn.id if isinstance(fn, ast.Name) else ""
            if name in ("import_module", "__import__") and isinstance(node.args[0].value, str):
                out.append((node.lineno, node.args[0].value.split(".")[0]))
    return out


def _files(package: str) -> list[Path]:
    return sorted((ROOT / package).rglob("*.py"))


@pytest.mark.parametrize("package", PACKAGES)
def test_layer_imports_only_what_it_may(package: str) -> None:
    files = _files(package)
    assert files, f"no Python files under {package}/"
    bad = [
        f"{f.relative_to(ROOT)}:{line} imports {name}"
        for f in files
        for line, name in imported_packages(f)
        if name in FORBIDDEN[package]
    ]
    assert not bad, "import rules broken:\n" + "\n".join(bad)


def test_the_checker_sees_every_kind_of_import(tmp_path: Path) -> None:
    """The rule test must be able to fail: each import form is found."""
    probe = ROOT / "ground" / "_probe_for_test.py"
    probe.write_text(
        "import fc.core\nfrom sim_bridge import build\ndef f():\n    from lab import run\n"
        "import importlib\nimportlib.import_module('fc.app')\nfrom .client import Vehicle\n",
        encoding="utf-8",
    )
    try:
        names = [n for _, n in imported_packages(probe)]
    finally:
        probe.unlink()
    assert names.count("fc") == 2 and "sim_bridge" in names and "lab" in names and "ground" in names


def test_the_control_tick_exists_once() -> None:
    """Only the flight core steps the pipeline: no runner calls FlightControl.step itself."""
    callers = []
    for package in PACKAGES:
        for f in _files(package):
            text = f.read_text(encoding="utf-8")
            if re.search(r"\bflight\.step\(|\.failsafe_step\(", text):
                callers.append(str(f.relative_to(ROOT)))
    assert callers == ["fc/core.py"], callers
