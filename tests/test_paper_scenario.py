"""The paper scenario end to end: integrator accuracy, reaching time, convergence, metrics."""

from __future__ import annotations

import copy
import json
import math

import jsonschema
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from fc.control import PAPER_GAINS
from lab.closed_loop import simulate
from lab.paper.metrics import METRICS_SCHEMA, overshoot, settle_time
from lab.paper.run import PaperRunOptions, build_controller, run_paper
from lab.paper.scenario import PaperScenario
from sim_bridge.plants.paper import PaperPlant
from smcpilot.errors import ConfigError
from smcpilot.model import CHANNELS, PaperModel

SMC = ("pid_smc", "adaptive_pid_smc")
MODEL = PaperModel.from_vehicle()
SC = PaperScenario()


# -- shared runs (simulated time only; the 15 s runs take ~0.6 s each) --------------------------


@pytest.fixture(scope="module")
def model_run():
    """The paper scenario as specified: 15 s, all four controllers, model sigma, continuous time."""
    return run_paper(PaperRunOptions())


@pytest.fixture(scope="module")
def oracle_run():
    return run_paper(PaperRunOptions(controllers=SMC, sigma_source="oracle"))


@pytest.fixture(scope="module")
def sampled_run():
    return run_paper(PaperRunOptions(controllers=SMC, rate_hz=500.0))


# -- RK4 runner against scipy's adaptive integrators --------------------------------------------


def _closed_loop_rhs(ctrl, plant, ref):
    """The same closed loop as lab.closed_loop.simulate's continuous form, for solve_ivp."""
    n = len(plant.state_names)

    def rhs(t, y):
        yy = y.tolist()
        meas = yy[:8]
        cs = yy[n:]
        u = ctrl.command(meas, ref, cs)
        dp, acc, _w = plant.derivatives(t, yy[:n], u)
        dc, _diag = ctrl.derivatives(meas, ref, cs, acc)
        return list(dp) + list(dc)

    return rhs


def _compare_with_solve_ivp(name: str, duration: float, method: str, sigma_source: str = "model"):
    opts = PaperRunOptions(sigma_source=sigma_source)
    plant = PaperPlant(MODEL)
    ctrl = build_controller(name, MODEL, opts)
    tr = simulate(ctrl, plant, SC.reference, SC.plant_x0, duration)
    assert not tr.diverged
    y0 = list(SC.plant_x0) + list(ctrl.initial_state(SC.plant_x0[:8]))
    sol = solve_ivp(
        _closed_loop_rhs(ctrl, plant, SC.reference),
        (0.0, float(tr.t_s[-1])),
        y0,
        method=method,
        rtol=1e-10,
        atol=1e-10,
        t_eval=tr.t_s,
    )
    assert sol.success, sol.message
    return tr, sol


def test_rk4_matches_dop853_cascade_pid():
    tr, sol = _compare_with_solve_ivp("cascade_pid", 3.0, "DOP853")
    diff = np.abs(sol.y[:12].T - tr.x)
    assert diff.shape == (3001, 12)
    assert diff.max() <= 1e-8, dict(zip(PaperPlant.state_names, diff.max(axis=0)))


def test_rk4_matches_rk45_adaptive_pid_smc_reaching_phase():
    tr, sol = _compare_with_solve_ivp("adaptive_pid_smc", 0.25, "RK45")
    # precondition: no sigma has reached 0 yet, so sign(sigma) is constant and the ODE smooth
    assert np.all(np.sign(tr.sigma) == np.sign(tr.sigma[0]))
    assert np.all(np.abs(tr.sigma) > 1e-3)  # theta gets closest: 7e-3 at 0.25 s
    diff = np.abs(sol.y[:12].T - tr.x)
    assert diff.max() <= 1e-8, dict(zip(PaperPlant.state_names, diff.max(axis=0)))
    # the controller states agree as well (u, int S, chi_hat)
    ctrl_names = build_controller("adaptive_pid_smc", MODEL, PaperRunOptions()).state_names
    u_ivp = sol.y[12 + ctrl_names.index("u_phi") : 12 + ctrl_names.index("u_z") + 1].T
    assert np.abs(u_ivp - tr.u).max() <= 1e-8 * max(1.0, np.abs(tr.u).max())


# -- reaching time of sigma against the Lyapunov bound (spec §3) ---------------------------------


def _reaching(sig: np.ndarray, t: np.ndarray, threshold: float) -> float:
    """First time |sigma| < threshold or sigma changes sign (a crossing between two samples)."""
    hit = (np.abs(sig) < threshold) | (np.sign(sig) != np.sign(sig[0]))
    idx = np.flatnonzero(hit)
    return float(t[idx[0]]) if idx.size else math.inf


def _bound(g, sigma0: float) -> tuple[float, float, float, float]:
    """(T, a, b, p): reaching-time bound of V = sigma^2/2 with V' <= -a V - b V^p."""
    v0 = 0.5 * sigma0 * sigma0
    a = 2.0 * g.nu
    b = 2.0 ** ((g.delta + 1.0) / 2.0) * g.kappa
    p = (g.delta + 1.0) / 2.0
    return math.log(1.0 + a * v0 ** (1.0 - p) / b) / (a * (1.0 - p)), a, b, p


def _comparison(v0: float, a: float, b: float, p: float, t: np.ndarray) -> np.ndarray:
    """Solution of v' = -a v - b v^p, v(0) = v0 (w = v^(1-p) obeys a linear ODE)."""
    w = (v0 ** (1.0 - p) + b / a) * np.exp(-(1.0 - p) * a * t) - b / a
    return np.where(w > 0.0, np.abs(w) ** (1.0 / (1.0 - p)), 0.0)


# Threshold 1e-3: sigma starts at 3-56, and near sigma = 0 it moves at least chi - |Lambda| ~ 1 per
# second or more, so 1e-3 is reached within about one 1 ms sample of the true crossing; the sign
# check catches a crossing that jumps over the band between samples.
REACH_THRESHOLD = 1e-3


@pytest.mark.parametrize("i", range(4), ids=CHANNELS)
def test_sigma_reaches_zero_before_lyapunov_bound(oracle_run, i):
    tr = oracle_run.trajectories["pid_smc"]
    g = PAPER_GAINS[i]
    T, _a, _b, _p = _bound(g, float(tr.sigma[0, i]))
    t_reach = _reaching(tr.sigma[:, i], tr.t_s, REACH_THRESHOLD)
    assert 0.0 < t_reach <= T + tr.dt_s, (CHANNELS[i], t_reach, T)
    # the bound is not vacuous: it is within a factor of 2 of the reaching time
    assert T < 2.0 * t_reach


@pytest.mark.parametrize(
    "i",
    [
        0,
        pytest.param(
            1,
            marks=pytest.mark.xfail(
                strict=True,
                reason="the law's f' holds Omega-bar constant (spec §2); in the reaching phase the neglected"
                " term kd c2 a6 Omega-bar' phi' reaches ~25 in the theta channel, far above chi_theta = 1,"
                " so Theorem 1's chi >= |Lambda| does not hold there and V_theta decays slower than the"
                " comparison solution for t in (0, 0.215 s]",
            ),
        ),
        2,
        3,
    ],
    ids=CHANNELS,
)
def test_lyapunov_function_below_comparison_solution(oracle_run, i):
    tr = oracle_run.trajectories["pid_smc"]
    g = PAPER_GAINS[i]
    sig = tr.sigma[:, i]
    T, a, b, p = _bound(g, float(sig[0]))
    t_reach = _reaching(sig, tr.t_s, REACH_THRESHOLD)
    reach = tr.t_s < t_reach
    V = 0.5 * sig[reach] ** 2
    v = _comparison(V[0], a, b, p, tr.t_s[reach])
    # relative 1e-12: floating-point rounding only (V(0) = v(0))
    bad = np.flatnonzero(V > v * (1.0 + 1e-12))
    assert bad.size == 0, (CHANNELS[i], tr.t_s[reach][bad[:3]], V[bad[:3]], v[bad[:3]])


def test_comparison_solution_reaches_zero_at_T():
    g = PAPER_GAINS[0]
    T, a, b, p = _bound(g, 5.0)
    t = np.array([0.0, 0.5 * T, 0.999 * T, 1.001 * T])
    v = _comparison(12.5, a, b, p, t)
    assert v[0] == pytest.approx(12.5)
    assert v[1] > 0 and v[2] > 0 and v[3] == 0.0
    # and it solves the ODE (finite-difference check at T/2)
    h = 1e-6
    vm, vp = _comparison(12.5, a, b, p, np.array([0.5 * T - h, 0.5 * T + h]))
    assert (vp - vm) / (2 * h) == pytest.approx(-a * v[1] - b * v[1] ** p, rel=1e-5)


# -- convergence, divergence of the literal b3 ---------------------------------------------------


@pytest.mark.parametrize("name", SMC)
def test_corrected_equations_converge(model_run, oracle_run, name):
    for run in (model_run, oracle_run):
        tr = run.trajectories[name]
        assert not tr.diverged, tr.reason
        assert tr.t_s[-1] == pytest.approx(SC.duration_s)
        err = tr.errors[-1]
        assert np.all(np.abs(err) < 0.01), err


def test_literal_b3_diverges_fast():
    run = run_paper(
        PaperRunOptions(controllers=("adaptive_pid_smc",), typos="b3", scenario=PaperScenario(duration_s=0.2))
    )
    tr = run.trajectories["adaptive_pid_smc"]
    assert tr.diverged is True
    assert tr.diverged_at_s is not None and tr.diverged_at_s < 0.05
    assert tr.reason
    m = run.metrics()["controllers"]["adaptive_pid_smc"]
    assert m["diverged"] is True and m["diverged_at_s"] == tr.diverged_at_s


# -- chattering, oracle vs model sigma, sampled data ---------------------------------------------


def test_sign_smc_chatters_far_more_than_pid_smc(model_run):
    tv = {n: np.sum(np.abs(np.diff(tr.u, axis=0)), axis=0) for n, tr in model_run.trajectories.items()}
    ratio = tv["sign_smc"] / tv["pid_smc"]
    assert np.all(ratio >= 20.0), dict(zip(CHANNELS, ratio))


@pytest.mark.parametrize("name", SMC)
def test_oracle_sigma_drives_error_far_below_model_sigma(model_run, oracle_run, name):
    e_model = np.abs(model_run.trajectories[name].errors[-1])
    e_oracle = np.abs(oracle_run.trajectories[name].errors[-1])
    # the model sigma leaves a residual error under the paper's disturbances (spec §2) ...
    assert np.all(e_model > 5e-4), e_model
    # ... the oracle removes it: at least 10x smaller on every channel (observed 15x-2800x)
    assert np.all(e_oracle * 10.0 < e_model), dict(zip(CHANNELS, e_model / e_oracle))


@pytest.mark.parametrize("name", SMC)
def test_sampled_500hz_close_to_continuous(model_run, sampled_run, name):
    cont = model_run.trajectories[name]
    samp = sampled_run.trajectories[name]
    assert samp.rate_hz == 500.0
    assert not samp.diverged, samp.reason
    assert len(samp.t_s) == len(cont.t_s)
    assert np.all(np.abs(samp.errors[-1]) < 0.01)
    assert np.all(np.abs(samp.errors[-1] - cont.errors[-1]) < 1e-3)
    # whole trajectory: angles and altitude within 2 cm / 0.02 rad of the continuous run (observed < 0.007)
    assert np.abs(samp.x[:, [0, 2, 4, 6]] - cont.x[:, [0, 2, 4, 6]]).max() < 0.02
    # u held for 2 ms: each value repeats in pairs of samples
    assert np.all(samp.u[0:-1:2] == samp.u[1::2])
    assert np.any(samp.u[1:-1:2] != samp.u[2::2])


@pytest.mark.parametrize("rate", [333.0, 300.0, 2000.0, 0.0, -500.0, math.nan])
def test_rate_not_dividing_physics_rate_raises(rate):
    ctrl = build_controller("pid_smc", MODEL, PaperRunOptions())
    with pytest.raises(ConfigError, match="rate"):
        simulate(ctrl, PaperPlant(MODEL), SC.reference, SC.plant_x0, 0.1, rate_hz=rate)


def test_rate_error_through_run_paper():
    with pytest.raises(ConfigError, match="333"):
        run_paper(PaperRunOptions(controllers=("pid_smc",), rate_hz=333.0, scenario=PaperScenario(duration_s=0.1)))


# -- metrics: unit tests on analytic arrays -------------------------------------------------------


T_GRID = np.linspace(0.0, 10.0, 10001)  # 1 ms


def test_settle_time_exponential():
    t_expected = math.log(100.0)  # exp(-t) < 0.01 from t = ln 100 on
    got = settle_time(T_GRID, np.exp(-T_GRID))
    assert t_expected <= got <= t_expected + 1e-3


def test_settle_time_last_entry_counts():
    v = np.exp(-T_GRID) + np.where((T_GRID > 6.0) & (T_GRID < 7.0), 0.5, 0.0)
    got = settle_time(T_GRID, v)
    assert 7.0 <= got <= 7.0 + 1e-3


def test_settle_time_never_settles():
    assert settle_time(T_GRID, np.sin(T_GRID)) is None  # ends outside (sin 10 = -0.54)
    assert settle_time(T_GRID, np.ones_like(T_GRID)) is None
    assert settle_time(T_GRID, np.full_like(T_GRID, 0.01)) is None  # band is open: |v| < 0.01


def test_settle_time_always_inside():
    assert settle_time(T_GRID, np.zeros_like(T_GRID)) == 0.0
    assert settle_time(T_GRID + 2.0, 1e-3 * np.cos(T_GRID)) == 2.0


def test_settle_time_nan_counts_as_outside():
    v = np.exp(-T_GRID)
    v_end = v.copy()
    v_end[-1] = np.nan
    assert settle_time(T_GRID, v_end) is None
    v_mid = v.copy()
    v_mid[8000] = np.nan
    assert settle_time(T_GRID, v_mid) == pytest.approx(T_GRID[8001])


def test_settle_time_band():
    got = settle_time(T_GRID, np.exp(-T_GRID), band=0.1)
    assert math.log(10.0) <= got <= math.log(10.0) + 1e-3


@pytest.mark.parametrize("zeta", [0.2, 0.5, 0.7])
def test_overshoot_second_order_step(zeta):
    """Unit step response of a second-order system: overshoot exp(-pi zeta / sqrt(1 - zeta^2))."""
    wn = 3.0
    wd = wn * math.sqrt(1.0 - zeta * zeta)
    t = T_GRID
    x = 1.0 - np.exp(-zeta * wn * t) * (np.cos(wd * t) + zeta / math.sqrt(1.0 - zeta * zeta) * np.sin(wd * t))
    expected = math.exp(-math.pi * zeta / math.sqrt(1.0 - zeta * zeta))
    assert overshoot(x, 1.0) == pytest.approx(expected, rel=1e-4)
    # from above: mirror image, same overshoot
    assert overshoot(2.0 - x, 1.0) == pytest.approx(expected, rel=1e-4)
    # scaled and shifted target
    assert overshoot(3.0 + 2.0 * x, 5.0) == pytest.approx(2.0 * expected, rel=1e-4)


def test_overshoot_cases():
    assert overshoot(np.array([0.0, 0.5, 1.2, 0.9, 1.0]), 1.0) == pytest.approx(0.2)
    assert overshoot(np.array([2.0, 1.5, 0.7, 1.1, 1.0]), 1.0) == pytest.approx(0.3)
    assert overshoot(1.0 - np.exp(-T_GRID), 1.0) == 0.0  # monotone approach
    assert overshoot(np.array([1.0, 1.3, 0.6, 1.0]), 1.0) == pytest.approx(0.4)  # starts on target
    assert overshoot(np.array([0.0, np.nan, 1.3, 1.0]), 1.0) == pytest.approx(0.3)  # NaN ignored
    assert overshoot(np.array([0.0, 0.4, np.nan]), 1.0) == 0.0


# -- metrics document and its schema ------------------------------------------------------------


@pytest.fixture(scope="module")
def short_metrics():
    run = run_paper(PaperRunOptions(scenario=PaperScenario(duration_s=0.5)))
    doc = run.metrics()
    # what the CLI writes: strict JSON (no NaN/inf)
    return json.loads(json.dumps(doc, allow_nan=False))


def _validator():
    jsonschema.Draft202012Validator.check_schema(METRICS_SCHEMA)
    return jsonschema.Draft202012Validator(METRICS_SCHEMA)


def test_metrics_document_validates(short_metrics):
    _validator().validate(short_metrics)
    assert short_metrics["scenario"] == "paper"
    assert set(short_metrics["controllers"]) == {"pid_smc", "adaptive_pid_smc", "sign_smc", "cascade_pid"}
    for name, entry in short_metrics["controllers"].items():
        assert set(entry["channels"]) == set(CHANNELS), name
        for c in CHANNELS:
            m = entry["channels"][c]
            if name == "adaptive_pid_smc":
                assert m["chi_hat_final"] is not None and m["chi_hat_final"] >= 0.5
            else:
                assert m["chi_hat_final"] is None
            assert m["max_abs_u"] >= 0 and m["total_variation_u"] >= 0 and m["overshoot"] >= 0
    # sigma settle times exist only where there is a sigma
    assert short_metrics["controllers"]["cascade_pid"]["channels"]["phi"]["t_sigma_below_0p01_s"] is None


def test_metrics_values_match_trajectory():
    run = run_paper(PaperRunOptions(controllers=("adaptive_pid_smc",), scenario=PaperScenario(duration_s=0.3)))
    tr = run.trajectories["adaptive_pid_smc"]
    m = run.metrics()["controllers"]["adaptive_pid_smc"]
    for i, c in enumerate(CHANNELS):
        ch = m["channels"][c]
        assert ch["err_final"] == pytest.approx(tr.x[-1, 2 * i] - SC.targets[i])
        assert ch["max_abs_u"] == pytest.approx(np.abs(tr.u[:, i]).max())
        assert ch["chi_hat_final"] == pytest.approx(tr.chi_hat[-1, i])
    assert m["min_omega_sq_over_hover"] == pytest.approx(tr.w_sq.min() / MODEL.hover_omega_sq)


def _mutations():
    def neg_overshoot(d):
        d["controllers"]["pid_smc"]["channels"]["phi"]["overshoot"] = -0.1

    def missing_err_final(d):
        del d["controllers"]["sign_smc"]["channels"]["z"]["err_final"]

    def missing_channel(d):
        del d["controllers"]["cascade_pid"]["channels"]["psi"]

    def extra_channel(d):
        d["controllers"]["pid_smc"]["channels"]["x"] = d["controllers"]["pid_smc"]["channels"]["phi"]

    def unknown_controller(d):
        d["controllers"]["lqr"] = d["controllers"]["pid_smc"]

    def wrong_scenario(d):
        d["scenario"] = "hover"

    def diverged_not_bool(d):
        d["controllers"]["pid_smc"]["diverged"] = "no"

    def no_controllers(d):
        d["controllers"] = {}

    def string_number(d):
        d["controllers"]["adaptive_pid_smc"]["channels"]["theta"]["max_abs_u"] = "1.0"

    def negative_settle_time(d):
        d["controllers"]["pid_smc"]["channels"]["z"]["t_err_below_0p01_s"] = -1.0

    return [
        neg_overshoot,
        missing_err_final,
        missing_channel,
        extra_channel,
        unknown_controller,
        wrong_scenario,
        diverged_not_bool,
        no_controllers,
        string_number,
        negative_settle_time,
    ]


@pytest.mark.parametrize("mutate", _mutations(), ids=lambda f: f.__name__)
def test_schema_rejects_violations(short_metrics, mutate):
    v = _validator()
    doc = copy.deepcopy(short_metrics)
    assert v.is_valid(doc)
    mutate(doc)
    assert not v.is_valid(doc)


def test_run_diverged_at_start_still_has_metrics():
    from lab.paper.metrics import trajectory_metrics

    x0 = list(SC.plant_x0)
    x0[1] = 5.0e3  # roll rate above the divergence limit from the start
    ctrl = build_controller("pid_smc", MODEL, PaperRunOptions())
    tr = simulate(ctrl, PaperPlant(MODEL), SC.reference, x0, 0.1)
    assert tr.diverged and tr.diverged_at_s == 0.0
    m = trajectory_metrics(tr, MODEL.hover_omega_sq)
    assert m["diverged"] is True
    assert set(m["channels"]) == set(CHANNELS)


def test_shipped_schema_file_matches_code():
    """docs/paper-metrics.schema.json (what README points others to) is the schema the code uses."""
    import json
    from pathlib import Path

    shipped = json.loads((Path(__file__).resolve().parents[1] / "docs" / "paper-metrics.schema.json").read_text())
    assert shipped == METRICS_SCHEMA
