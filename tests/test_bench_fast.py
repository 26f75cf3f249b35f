"""``smcpilot bench batch`` and ``bench fast``: their bad values are one-line errors, and they fly
what they say and print their tables. No speed is asserted (speed is measured, never tested); only
that the benches work and what they print."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from lab.cli import main
from smcpilot.jit import jit_enabled

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("argv", [["--seeds", "0"], ["--cpython", "0"], ["--repeat", "0"], ["--duration", "0"], ["--duration", "nan"]])
def test_bench_batch_bad_values_are_one_line_errors(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "batch", *argv]) == 2
    out, err = capsys.readouterr()
    assert out == ""
    assert err.strip() == "smcpilot bench: error: --seeds, --cpython and --repeat must be at least 1, --duration > 0"


@pytest.mark.slow
def test_bench_batch_flies_the_study_in_cpython_and_compiled(capsys: pytest.CaptureFixture[str]) -> None:
    """The study's 70 flights, short, compiled, against 3 of them in CPython: the table's rows,
    every flight ok or crashed, and the kernel's share of the ticks."""
    if not jit_enabled(say=False):
        assert main(["bench", "batch", "--duration", "0.3", "--cpython", "3", "--repeat", "1"]) == 1
        assert "the compiled path is off" in capsys.readouterr().out
        return
    assert main(["bench", "batch", "--duration", "0.3", "--cpython", "3", "--repeat", "1"]) == 0
    out = capsys.readouterr().out
    assert "70 flights of the robustness study (0.3 s each" in out
    rows = {m.group(1).strip(): (float(m.group(2).replace(",", "")), float(m.group(3)), float(m.group(4)))
            for m in re.finditer(r"^(CPython \(3 of the flights\)|compiled, batch of 70|  of which the kernel alone)\s+([\d,]+)\s+([\d.]+)\s+([\d.]+)x$",
                                 out, re.M)}  # fmt: skip
    assert set(rows) == {"CPython (3 of the flights)", "compiled, batch of 70", "of which the kernel alone"}, out
    ticks_s, us_tick, ratio = rows["compiled, batch of 70"]
    assert ticks_s > 0 and us_tick == pytest.approx(1e6 / ticks_s, rel=0.01, abs=0.01)
    assert rows["CPython (3 of the flights)"][2] == 1.0
    assert ratio == pytest.approx(ticks_s / rows["CPython (3 of the flights)"][0], rel=0.01)
    assert "flights not ok" not in out, out  # every flight ok or crashed, as the study's are
    share = re.search(r"([\d.]+)% of the ticks\)", out)
    assert share is not None and float(share.group(1)) > 90.0, out  # the kernel flies nearly all of them


def test_bench_fast_bad_repeat_is_a_one_line_error(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "fast", "--repeat", "0"]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.strip() == "smcpilot bench: error: --repeat must be at least 1"


@pytest.mark.slow
def test_bench_fast_flies_a_scenario_both_ways_with_and_without_the_log(capsys: pytest.CaptureFixture[str]) -> None:
    """One example scenario: its row in each table, the ratio the quotient of the two speeds."""
    argv = ["bench", "fast", str(ROOT / "examples" / "scenarios" / "hover.toml"), "--repeat", "1"]
    if not jit_enabled(say=False):
        assert main(argv) == 1
        assert "the compiled path is off" in capsys.readouterr().out
        return
    assert main(argv) == 0
    out = capsys.readouterr().out
    m = re.search(r"^hover\s+(\d+)\s+(\d+)\s+(\d+)\s+([\d.]+)\s+([\d.]+)\s+([\d.]+)x\s+(-?[\d.]+)$", out, re.M)
    assert m is not None, out
    ticks, py_us, fast_us, ratio = int(m.group(1)), float(m.group(4)), float(m.group(5)), float(m.group(6))
    assert ticks == 10001  # 20 s at 500 Hz, the first tick included
    assert ratio == pytest.approx(py_us / fast_us, rel=0.05)
    logged = re.search(r"^hover\s+(\d+)\s+(\d+)\s+([\d.]+)x$", out, re.M)
    assert logged is not None, out
    assert float(logged.group(3)) == pytest.approx(int(logged.group(2)) / int(logged.group(1)), rel=0.05)
