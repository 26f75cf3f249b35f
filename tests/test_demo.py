"""`smcpilot demo` — README's main job — flies, prints a summary, writes plots and its JSON."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

#: end-to-end: the quick tier (`pytest -m "not slow"`) leaves this module to the full suite.
pytestmark = pytest.mark.slow


def test_demo_flies_and_writes_results(tmp_path: Path) -> None:
    out = tmp_path / "plots"
    result_path = tmp_path / "demo.json"
    r = subprocess.run(
        [sys.executable, "-m", "lab.cli", "demo", "--json", str(result_path), "--out", str(out),
         "--log-dir", str(tmp_path / "logs")],  # fmt: skip
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert r.returncode == 0, r.stdout + r.stderr
    res = json.loads(result_path.read_text(encoding="utf-8"))
    for key in ("sim_seconds", "wall_seconds", "position_error_final_m", "max_tilt_deg", "chi_hat_final", "overruns", "tlog"):
        assert key in res, key
    assert res["sim_seconds"] == 55.0
    assert res["position_error_final_m"] < 0.05  # the last hold before landing, settled
    assert 5.0 < res["max_tilt_deg"] < 35.0  # it moved, within the tilt limit
    assert len(res["chi_hat_final"]) == 4 and all(0.0 <= c <= 5.0 for c in res["chi_hat_final"])
    assert res["overruns"] == 0  # lockstep
    assert Path(res["tlog"]).stat().st_size > 1_000_000
    assert [e["text"] for e in res["events"]][-1] == "Landed: disarmed"
    pngs = sorted(p.name for p in out.glob("*.png"))
    assert {"position.png", "attitude.png", "track.png"} <= set(pngs)
    assert "demo:" in r.stdout and "log:" in r.stdout
