"""The paper's ODE runner compiled (lab/fast/paper.py) gives the CPython loop's trajectories, bit for bit.

Each case flies the same controller on the same plant twice: ``simulate(...)`` (compiled: the
whole RK4 loop in one numba call) and ``simulate(..., compiled=False)`` (today's CPython loop over
the classes, which call the same pure functions uncompiled: what ``SMCPILOT_JIT=0`` flies). Every
recorded array is compared whole, by its bytes: no tolerance. numba's ``cos``, ``sin``, ``sqrt``
and ``pow`` are the C library's, as CPython's are, and numba contracts nothing into fused
multiply-adds, so nothing here needs one; a change that makes the two differ in the last bit fails.

Divergence (the loop stops before the step the check rejects and CPython flies the rest) gives
the same time, reason and rows, an arithmetic failure CPython raises included. Nothing is timed.
Runs are short (1-2 s of simulated time) but one full 15 s paper run.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from fc.control import CONTROLLER_NAMES
from fc.control.purity import pure_closure
from lab.closed_loop import Trajectory, divergence_code, simulate
from lab.paper.run import PaperRunOptions, build_controller
from lab.paper.scenario import PaperScenario
from sim_bridge.plants.paper import PaperPlant
from smcpilot.model import PaperModel
from smcpilot.typos import CONTROLLER_TYPOS, MODEL_TYPOS, TYPOS

pytest.importorskip("numba")

from lab.fast import paper as fast_paper  # noqa: E402

SMC = ("pid_smc", "adaptive_pid_smc")
SC = PaperScenario()
ARRAYS = ("t_s", "x", "x_ref", "u", "w_sq", "s", "sigma", "chi_hat")


@pytest.fixture(autouse=True)
def _jit_on(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("SMCPILOT_JIT", raising=False)
    monkeypatch.delenv("NUMBA_DISABLE_JIT", raising=False)


@pytest.fixture
def spy(monkeypatch: pytest.MonkeyPatch) -> list:
    """What each ``fly_compiled`` call returned (None: it did not fly)."""
    got: list = []
    real = fast_paper.fly_compiled

    def wrapped(*args, **kw):  # type: ignore[no-untyped-def]
        part = real(*args, **kw)
        got.append(part)
        return part

    monkeypatch.setattr(fast_paper, "fly_compiled", wrapped)
    return got


def assert_same(a: Trajectory, b: Trajectory) -> None:
    """Every array equal bit for bit (NaN and the sign of zero included), the rest equal."""
    for name in ARRAYS:
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None), name
        if x is None:
            continue
        assert x.dtype == y.dtype and x.shape == y.shape, (name, x.shape, y.shape)
        if x.tobytes() != y.tobytes():
            bad = np.argwhere(x.view(np.uint64) != y.view(np.uint64))
            raise AssertionError(f"{name}: {len(bad)} values differ, first at {bad[0].tolist()}: {x[tuple(bad[0])]!r} vs {y[tuple(bad[0])]!r}")
    assert (a.diverged, a.diverged_at_s, a.reason) == (b.diverged, b.diverged_at_s, b.reason)
    assert (a.controller, a.dt_s, a.rate_hz) == (b.controller, b.dt_s, b.rate_hz)


def fly_both(name: str, spy: list, *, duration: float = 1.0, x0=None, rate_hz: float | None = None, disturbance: bool = True,
             **opts) -> tuple[Trajectory, Trajectory]:  # fmt: skip
    options = PaperRunOptions(**opts)
    model = PaperModel.from_vehicle(options.vehicle, options.typos & MODEL_TYPOS)
    plant = PaperPlant(model, disturbance=disturbance)
    ctrl = build_controller(name, model, options)
    x0 = SC.plant_x0 if x0 is None else x0
    compiled = simulate(ctrl, plant, SC.reference, x0, duration, rate_hz=rate_hz)
    assert spy and spy[-1] is not None, "the compiled runner did not fly"
    cpython = simulate(build_controller(name, model, options), PaperPlant(model, disturbance=disturbance), SC.reference, x0, duration,
                       rate_hz=rate_hz, compiled=False)  # fmt: skip
    assert len(spy) == 1
    assert_same(compiled, cpython)
    return compiled, cpython


# -- the same trajectories -----------------------------------------------------------------------------
@pytest.mark.parametrize("name", CONTROLLER_NAMES)
def test_default_options(name: str, spy: list) -> None:
    tr, _ = fly_both(name, spy, duration=2.0)
    assert not tr.diverged and len(tr.t_s) == 2001 and spy[0].done


@pytest.mark.parametrize("name", CONTROLLER_NAMES)
def test_sampled_control(name: str, spy: list) -> None:
    tr, _ = fly_both(name, spy, rate_hz=250.0)
    assert not tr.diverged and len(tr.t_s) == 1001


@pytest.mark.parametrize("name", CONTROLLER_NAMES)
def test_no_disturbance(name: str, spy: list) -> None:
    fly_both(name, spy, disturbance=False)


@pytest.mark.parametrize("name", SMC)
@pytest.mark.parametrize("rate_hz", [None, 500.0])
def test_oracle_sigma(name: str, rate_hz: float | None, spy: list) -> None:
    fly_both(name, spy, sigma_source="oracle", rate_hz=rate_hz)


@pytest.mark.parametrize("name", CONTROLLER_NAMES)
def test_every_typo(name: str, spy: list) -> None:
    """The paper's printed equations, every typo at once (model and controller)."""
    fly_both(name, spy, typos=frozenset(TYPOS), chi_hat0=0.0)


@pytest.mark.parametrize("typos", [frozenset({"pitch-moment", "fdot"}), CONTROLLER_TYPOS])
def test_typo_sets_sampled(typos: frozenset, spy: list) -> None:
    fly_both("adaptive_pid_smc", spy, typos=typos, rate_hz=1000.0)


def test_changed_gains_and_chi_hat0(spy: list) -> None:
    from dataclasses import replace

    from fc.control import PAPER_GAINS

    gains = (replace(PAPER_GAINS[0], kappa=2.0, delta=0.3), *PAPER_GAINS[1:])
    fly_both("adaptive_pid_smc", spy, gains=gains, chi_hat0=2.0)  # type: ignore[arg-type]


def test_the_full_paper_run(spy: list) -> None:
    """15 s, the paper scenario as ``smcpilot paper`` flies it."""
    tr, _ = fly_both("adaptive_pid_smc", spy, duration=SC.duration_s)
    assert len(tr.t_s) == 15001 and not tr.diverged


# -- divergence: the same time, reason and rows ---------------------------------------------------------
def _x0(**changes: float) -> list[float]:
    x0 = list(SC.plant_x0)
    for i, v in changes.items():
        x0[int(i[1:])] = v
    return x0


@pytest.mark.parametrize("name", CONTROLLER_NAMES)
@pytest.mark.parametrize("rate_hz", [None, 200.0])
@pytest.mark.parametrize(
    "x0, reason",
    [
        (_x0(i1=5.0e3), "angular rate above 1000 rad/s"),  # at the start: one sample kept
        (_x0(i7=math.nan), "non-finite state or input"),
        (_x0(i4=math.inf), "arithmetic failure (math domain error)"),  # CPython raises on sin(inf)
        (_x0(i6=9999.0, i7=2000.0), "altitude or climb rate out of range"),  # climbs past the limit in the first step
    ],
    ids=["rate", "nan", "inf", "climb"],
)
def test_divergence(name: str, rate_hz: float | None, x0: list[float], reason: str, spy: list) -> None:
    tr, _ = fly_both(name, spy, x0=x0, rate_hz=rate_hz, duration=1.5)
    assert tr.diverged and tr.reason == reason and tr.diverged_at_s is not None
    # a failure in the first step leaves no sample (as ever); a check that fails keeps the first one
    assert len(tr.t_s) == (0 if reason.startswith("arithmetic") else max(1, round(tr.diverged_at_s / tr.dt_s)))


@pytest.mark.parametrize("rate_hz", [None, 200.0])
@pytest.mark.parametrize(
    "name, x0, opts, at",
    [
        ("pid_smc", _x0(i5=995.0), {}, 0.021),
        ("adaptive_pid_smc", _x0(i6=9995.0, i7=500.0), {}, 0.011),
        ("cascade_pid", _x0(i6=9995.0, i7=500.0), {}, 0.14),
        ("sign_smc", None, {"typos": frozenset(TYPOS)}, 0.001),
    ],
    ids=["pid_smc", "adaptive_pid_smc", "cascade_pid", "sign_smc"],
)
def test_divergence_part_way(name: str, x0: list[float] | None, opts: dict, at: float, rate_hz: float | None, spy: list) -> None:
    """A run that diverges after flying a while compiled: the compiled rows, then CPython's."""
    tr, _ = fly_both(name, spy, x0=x0, duration=1.0, rate_hz=rate_hz, **opts)
    assert tr.diverged and tr.diverged_at_s is not None and tr.diverged_at_s >= at - 0.01
    assert 0 < spy[0].n < len(tr.t_s) + 1 and not spy[0].done


# -- what falls back -----------------------------------------------------------------------------------
def test_jit_off_flies_the_same_code_in_cpython(monkeypatch: pytest.MonkeyPatch, spy: list) -> None:
    monkeypatch.setenv("SMCPILOT_JIT", "0")
    model = PaperModel.from_vehicle()
    ctrl = build_controller("pid_smc", model, PaperRunOptions())
    off = simulate(ctrl, PaperPlant(model), SC.reference, SC.plant_x0, 0.5)
    assert spy == [None]
    monkeypatch.delenv("SMCPILOT_JIT")
    on = simulate(ctrl, PaperPlant(model), SC.reference, SC.plant_x0, 0.5)
    assert spy[-1] is not None
    assert_same(on, off)


def test_a_reference_of_time_flies_in_cpython(spy: list) -> None:
    model = PaperModel.from_vehicle()
    ctrl = build_controller("sign_smc", model, PaperRunOptions())
    tr = simulate(ctrl, PaperPlant(model), lambda t: SC.reference, SC.plant_x0, 0.2)
    assert spy == [] and len(tr.t_s) == 201
    assert_same(tr, simulate(ctrl, PaperPlant(model), SC.reference, SC.plant_x0, 0.2, compiled=False))


def test_another_plant_or_controller_flies_in_cpython() -> None:
    class OtherPlant(PaperPlant):
        pass

    model = PaperModel.from_vehicle()
    ctrl = build_controller("cascade_pid", model, PaperRunOptions())
    assert fast_paper.unsupported(ctrl, OtherPlant(model), SC.reference) == "the plant is OtherPlant, not the paper's plant"
    assert "has no compiled form" in (fast_paper.unsupported(object(), PaperPlant(model), SC.reference) or "")
    assert fast_paper.unsupported(ctrl, PaperPlant(model), SC.reference) is None


# -- one source -----------------------------------------------------------------------------------------
def test_the_runner_and_what_it_calls_are_in_the_pure_style() -> None:
    """The math (the laws' continuous and sampled forms, the plant, the divergence check) is in the
    pure style; the runner's loops differ only by looping over the arrays they own (as the flight
    kernel's do)."""
    from fc.control.cascade_pid import cascade_pid_derivatives, cascade_pid_initial_state, cascade_pid_output, cascade_pid_step
    from fc.control.pid_smc import pid_smc_command, pid_smc_derivatives, pid_smc_initial_state, pid_smc_step, pid_smc_step_measured
    from fc.control.sign_smc import sign_smc_output, sign_smc_step
    from sim_bridge.plants.paper import paper_plant_derivatives

    math_fns = (pid_smc_command, pid_smc_derivatives, pid_smc_initial_state, pid_smc_step, pid_smc_step_measured,
                sign_smc_output, sign_smc_step, cascade_pid_output, cascade_pid_derivatives, cascade_pid_initial_state,
                cascade_pid_step, paper_plant_derivatives, divergence_code)  # fmt: skip
    assert pure_closure(math_fns)[1] == []
    for family in fast_paper._FAMILIES.values():
        _fns, problems = pure_closure((*fast_paper.RUNNER_FUNCTIONS, family[1], family[2]))
        assert problems and all(p.endswith("calls range = <class 'range'>, not a pure function") for p in problems), problems


def test_divergence_check_names_the_reason() -> None:
    ok = (0.1,) * 12
    u = (0.0, 0.0, 0.0, 10.0)
    assert divergence_code(ok, u) == 0
    assert divergence_code((0.1, 1e3) + ok[2:], u) == 2
    assert divergence_code(ok[:7] + (-1e4,) + ok[8:], u) == 3
    assert divergence_code(ok, (0.0, 0.0, 2e6, 0.0)) == 4
    assert divergence_code(ok[:11] + (math.inf,), u) == 1  # any state, not only the checked ones


def test_plant_constants_follow_its_disturbance_switch() -> None:
    model = PaperModel.from_vehicle()
    plant = PaperPlant(model, disturbance=False)
    y = list(SC.plant_x0)
    u = model.hover_inputs()
    calm = plant.derivatives(0.7, y, u)
    plant.disturbance = True
    assert plant.consts.disturbance and plant.derivatives(0.7, y, u) != calm
    plant.disturbance = False
    assert plant.derivatives(0.7, y, u) == calm
