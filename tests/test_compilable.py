"""The hot path stays pure and compilable.

Without numba: the rules, checked on the code and on the data — every function of
:data:`fc.pipeline.PURE_FUNCTIONS` (and of the rigid-body plant's step,
:data:`sim_bridge.plants.rigid_body.PURE_FUNCTIONS`, and of the FC's estimate,
:data:`fc.estimate.PURE_FUNCTIONS`) is a module-level function with no closure whose body has no
lists, dicts, sets, comprehensions, strings, f-strings, exceptions, lambdas, nested functions,
``getattr``/``isinstance`` or method calls, and calls only pure functions (by plain name), ``math`` functions,
``abs``/``min``/``max`` and NamedTuple classes; the parameters, state and inputs it takes (built
from real configurations) are tuples and NamedTuples whose leaves are all floats, ints or bools,
with the same types on every tick.

With numba (``pytest.importorskip``): the same functions, unchanged, compiled by ``numba.njit``
give the same bits as CPython over a closed-loop take-off, ALT_HOLD and landing of each FC
controller; the law steps do on random inputs, and the plant step over a flight with gusts and the
paper's disturbances.
"""

from __future__ import annotations

import contextlib
import math
import random
import time
import types

import pytest
from bits_helpers import bits

from fc import estimate
from fc.config import FcConfig
from fc.control import LAW_FUNCTIONS, PidSmc, PidSmcParams
from fc.control.builtin import BUILTIN_LAWS
from fc.control.cascade_pid import CascadePid
from fc.control.law import Law, LawFunctions
from fc.control.pid_smc import AdaptationBounds, ChannelConsts
from fc.control.purity import function_problems, law_problems
from fc.control.sign_smc import SignSmc
from fc.flight import FlightControl
from fc.pipeline import (
    PURE_FUNCTIONS,
    PipelineInputs,
    PipelineParams,
    PipelineState,
    VehicleState,
    pipeline_reset,
    pipeline_reset_full,
    pipeline_step,
    pipeline_step_full,
)
from lab.runner import wire_state
from sim_bridge.environment import Environment, EnvironmentParams
from sim_bridge.plants import rigid_body
from sim_bridge.plants.rigid_body import NOMINAL_INPUT, RigidBodyPlant, StepInput, rigid_body_params, rigid_body_step
from smcpilot.model import ModelConsts, PaperModel
from smcpilot.typos import TYPOS
from smcpilot.vehicle import DEFAULT_VEHICLE

FC_CONTROLLERS = ("adaptive_pid_smc", "pid_smc", "cascade_pid", "sign_smc", "se3_geometric", "indi")
PLANT_FUNCTIONS = rigid_body.PURE_FUNCTIONS
_OTHER_PURE = PLANT_FUNCTIONS + estimate.PURE_FUNCTIONS
ALL_PURE = PURE_FUNCTIONS + tuple(f for i, f in enumerate(_OTHER_PURE) if f not in PURE_FUNCTIONS and f not in _OTHER_PURE[:i])


# -- the rules, on the code ---------------------------------------------------------------------------
def test_the_pure_functions_are_listed_once_and_cover_the_law() -> None:
    assert len(set(PURE_FUNCTIONS)) == len(PURE_FUNCTIONS)
    assert set(LAW_FUNCTIONS) <= set(PURE_FUNCTIONS)


@pytest.mark.parametrize("fn", ALL_PURE, ids=lambda f: f"{f.__module__}.{f.__name__}")
def test_pure_function_follows_the_rules(fn: types.FunctionType) -> None:
    problems = function_problems(fn, ALL_PURE)
    assert not problems, "\n".join(problems)


@pytest.mark.parametrize("law", BUILTIN_LAWS, ids=lambda law: law.name)
def test_every_built_in_law_is_in_the_pure_style_all_the_way_down(law: Law) -> None:
    assert law_problems(law) == []


def test_the_checker_names_what_breaks_the_rules() -> None:
    def closure_maker():
        k = 2.0

        def step(meas, ref, state, dt_s, kk, d_hat, u_prev):
            return k

        return step

    assert function_problems(closure_maker()) == ["step: not a module-level function (test_the_checker_names_what_breaks_the_rules.<locals>.closure_maker.<locals>.step)"]
    assert any("Raise" in p for p in function_problems(_raising_helper))
    assert any("string constant" in p for p in function_problems(_raising_helper))
    assert any("calls print" in p for p in function_problems(_printing_helper))


def _raising_helper(x: float) -> float:
    if x < 0.0:
        raise ValueError("negative")
    return x


def _printing_helper(x: float) -> float:
    print(x)
    return x


# -- the rules, on the data ---------------------------------------------------------------------------
def leaf_types(x: object, path: str = "") -> list[tuple[str, type]]:
    """(path, type) of every leaf; containers must be tuples (NamedTuples included)."""
    if isinstance(x, tuple):
        names = getattr(type(x), "_fields", None) or [str(i) for i in range(len(x))]
        return [lt for name, v in zip(names, x) for lt in leaf_types(v, f"{path}.{name}")]
    assert type(x) in (float, int, bool), f"{path}: {type(x).__name__} leaf {x!r}"
    return [(path, type(x))]


def _configs() -> list[FcConfig]:
    return [FcConfig(controller=c) for c in FC_CONTROLLERS] + [
        FcConfig(speed_max_xy_mps=2, land_detect_s=1, chi_hat0=0, rate_hz=250)  # ints where floats are meant
    ]


def test_plant_parameters_and_state_are_flat_tuples_of_floats() -> None:
    for env in (Environment(), Environment(EnvironmentParams(paper_disturbance=True))):
        plant = RigidBodyPlant(DEFAULT_VEHICLE, env)
        assert [path for path, t in leaf_types(plant.params) if t is not float] == [".ground_contact"]
        for u in (NOMINAL_INPUT, plant._input, StepInput((0.7, 1.0, 0.0, 1.0), True, -1.0)):
            assert [t for _, t in leaf_types(u)] == [float] * 4 + [bool, float]
        plant.step(0.0, 0.001, (0.5, 0.5, 0.5, 0.5), True)
        assert {t for _, t in leaf_types(plant.state)} == {float} and len(plant.state) == 17


def test_parameters_state_and_inputs_are_flat_tuples_of_numbers() -> None:
    signatures = set()
    for cfg in _configs():
        fl = FlightControl(cfg, DEFAULT_VEHICLE)
        p = fl.params
        assert isinstance(p, PipelineParams)
        sig = tuple(leaf_types(p))
        # Numbers meant as floats are floats even where the configuration gave ints; the only ints
        # are the observer's mode and how the PID-SMC uses the estimate.
        ints = [path for path, t in sig if t is int]
        assert ints == [".observer.mode", ".law.dob_mode"] if cfg.controller in ("adaptive_pid_smc", "pid_smc") else [".observer.mode"], sig
        signatures.add((cfg.controller, tuple(t for _, t in sig)))
    # One layout and one set of leaf types per law (ints given for floats change nothing): one
    # compiled specialisation per law.
    assert len(signatures) == len(FC_CONTROLLERS)
    for name, ctrl in (("pid_smc", PidSmc(PaperModel.from_vehicle(), PidSmcParams(typos=frozenset(TYPOS)))),
                       ("cascade", CascadePid(PaperModel.from_vehicle())), ("sign", SignSmc(PaperModel.from_vehicle()))):  # fmt: skip
        assert [path for path, t in leaf_types(ctrl.consts, name) if t is int] == (["pid_smc.dob_mode"] if name == "pid_smc" else [])
    assert len(PidSmc(PaperModel.from_vehicle()).consts.model) == len(ModelConsts._fields)
    assert all(len(k) == len(ChannelConsts._fields) for k in PidSmc(PaperModel.from_vehicle()).consts.k)


@pytest.mark.parametrize("controller", FC_CONTROLLERS)
def test_state_keeps_its_types_from_tick_to_tick(controller: str) -> None:
    fl = FlightControl(FcConfig(controller=controller), DEFAULT_VEHICLE)
    st = VehicleState(*(0.0,) * 12)
    law = fl.law_functions
    reset, step = (pipeline_reset_full, pipeline_step_full) if fl.law.full_stack else (pipeline_reset, pipeline_step)
    ps = reset(st, fl.params, law)
    first = tuple(t for _, t in leaf_types(ps))
    cmd = PipelineInputs(0.0, 0.0, 2.0, 0.5, True, False, True, 3.0)
    assert tuple(t for _, t in leaf_types(cmd)) == (float,) * 4 + (bool,) * 3 + (float,)
    out0 = None
    for k in range(50):
        ps, out = step(ps, st, cmd._replace(landing=k > 25), fl.params, 0.002, law)
        assert isinstance(ps, PipelineState) and tuple(t for _, t in leaf_types(ps)) == first
        sig = tuple(t for _, t in leaf_types(out))
        assert out0 is None or sig == out0
        out0 = sig
    # The law state not yet there (after a change of controller while armed) is filled in the same types.
    ps, _ = step(ps._replace(law_init=True), st, cmd, fl.params, 0.002, law)
    assert tuple(t for _, t in leaf_types(ps)) == first


# -- numba: the same functions, compiled ---------------------------------------------------------------
_DISPATCHERS: dict = {}


@contextlib.contextmanager
def compiled():
    """Every pure function compiled, as the product compiles them: :func:`smcpilot.jit.compile_pure`'s
    twins (the same code calling each other's twins; the originals stay plain Python)."""
    pytest.importorskip("numba")
    if not _DISPATCHERS:
        from fc.control.purity import pure_closure
        from smcpilot.jit import compile_pure

        fns, _ = pure_closure(ALL_PURE)
        _DISPATCHERS.update(compile_pure(fns, cache=False))
    yield _DISPATCHERS


def _closed_loop(controller: str) -> list[tuple]:
    """Interpreted: (state, vehicle state, inputs, params) of every tick of a take-off to 3 m with a
    heading change, 100 ticks of ALT_HOLD, then landing; and what the pipeline returned."""
    cfg = FcConfig(controller=controller)
    fl = FlightControl(cfg, DEFAULT_VEHICLE)
    p = fl.params
    law = fl.law_functions
    reset, step = (pipeline_reset_full, pipeline_step_full) if fl.law.full_stack else (pipeline_reset, pipeline_step)
    plant = RigidBodyPlant(DEFAULT_VEHICLE)
    st = wire_state(plant.observe())
    ps = reset(st, p, law)
    rows = []
    t = 0.0
    for k in range(700):
        st = wire_state(plant.observe())
        cmd = PipelineInputs(0.5, -0.3, 3.0, 1.2, True, k >= 500, not 400 <= k < 500, cfg.speed_max_xy_mps)
        new, out = step(ps, st, cmd, p, 0.002, law)
        rows.append((ps, st, cmd, p, new, out, law, step))
        ps = new
        for _ in range(2):
            plant.step(t, 0.001, out[0], True)
            t += 0.001
    assert rows[399][0].z_r > 0.3, "took off"
    return rows


@pytest.mark.slow
def test_compiled_pipeline_step_gives_the_same_bits() -> None:
    pytest.importorskip("numba")
    flights = {c: _closed_loop(c) for c in FC_CONTROLLERS}
    # and a touchdown on the ground
    fl = FlightControl(FcConfig(), DEFAULT_VEHICLE)
    ground = VehicleState(*(0.0,) * 12)
    ps = pipeline_reset(ground, fl.params, fl.law_functions)
    cmd = PipelineInputs(0.0, 0.0, 0.0, 0.0, True, True, True, 3.0)
    rows = []
    for _ in range(300):
        new, out = pipeline_step(ps, ground, cmd, fl.params, 0.002, fl.law_functions)
        rows.append((ps, ground, cmd, fl.params, new, out, fl.law_functions, pipeline_step))
        ps = new
    assert any(r[5][9] for r in rows), "touched down"
    flights["touchdown"] = rows
    with compiled() as jit:
        def compiled_law(law: LawFunctions) -> LawFunctions:
            return LawFunctions(*(jit[f] for f in law))

        t0 = time.perf_counter()
        jit[pipeline_step](*rows[0][:4], 0.002, compiled_law(rows[0][6]))
        compile_s = time.perf_counter() - t0
        for name, rows in flights.items():
            law = compiled_law(rows[0][6])
            step = jit[rows[0][7]]
            for k, (ps, st, cmd, p, new, out, _law, _step) in enumerate(rows):
                got = step(ps, st, cmd, p, 0.002, law)
                assert bits(got) == bits((new, out)), f"{name}: tick {k} differs"
                assert type(got[0]) is PipelineState
        # one specialisation per law's functions (the two PID-SMC flavours share theirs)
        attitude_laws = {rows[0][6] for rows in flights.values() if rows[0][7] is pipeline_step}
        assert len(jit[pipeline_step].signatures) == len(attitude_laws) == 4 and len(jit[pipeline_step_full].signatures) == 1
    print(f"\nnumba compiled pipeline_step (with everything it calls) in {compile_s:.1f} s")


def test_compiled_law_steps_give_the_same_bits() -> None:
    pytest.importorskip("numba")
    from fc.config import FC_CASCADE
    from fc.control.cascade_pid import CascadePidParams, cascade_pid_anti_windup, cascade_pid_step
    from fc.control.pid_smc import pid_smc_anti_windup, pid_smc_step, pid_smc_step_measured
    from fc.control.sign_smc import sign_smc_step

    r = random.Random(5)
    model = PaperModel.from_vehicle()
    consts = [
        PidSmc(model, PidSmcParams()).consts,
        PidSmc(model, PidSmcParams(adaptive=False)).consts,
        PidSmc(model, PidSmcParams(sigma_source="oracle", typos=frozenset(TYPOS))).consts,
        PidSmc(PaperModel.from_vehicle(typos=frozenset(TYPOS)), PidSmcParams(
            adaptation=AdaptationBounds(0.2, 0.3, 0.1, 2.0), u_min=(-0.1, -0.1, -0.005, 4.0), u_max=(0.1, 0.1, 0.005, 10.0))).consts,
    ]  # fmt: skip
    cps = (CascadePid(model).consts, CascadePid(model, FC_CASCADE).consts,
           CascadePid(model, CascadePidParams(kd_rate=(0.3, 0.1, 0.2), i_max=(0.5, 1.0, 0.2, 0.3), d_filter_hz=30.0)).consts)  # fmt: skip
    ss = SignSmc(model).consts
    cases = []
    for k in range(300):
        meas = tuple(r.uniform(-1.0, 1.0) for _ in range(8))
        ref = tuple(r.uniform(-1.0, 1.0) for _ in range(16))
        state = tuple(r.uniform(-1.0, 1.0) for _ in range(7)) + (r.uniform(4.0, 10.0),) + tuple(r.uniform(0.0, 3.0) for _ in range(4))
        accel = tuple(r.uniform(-5.0, 5.0) for _ in range(4))
        limited = tuple(r.random() < 0.3 for _ in range(4))
        c = consts[k % len(consts)]
        cp = cps[k % len(cps)]
        cases.append((meas, ref, state, accel, limited, c, cp, (
            pid_smc_step(meas, ref, state, 0.002, c),
            pid_smc_step_measured(meas, ref, state, 0.002, c, accel),
            pid_smc_anti_windup(state, state[::-1], accel, limited),
            cascade_pid_step(meas, ref, state[:10], 0.002, cp),
            cascade_pid_anti_windup(state, state[::-1], limited),
            sign_smc_step(meas, ref, state[:4], 0.002, ss),
        )))  # fmt: skip
    with compiled() as jit:
        for meas, ref, state, accel, limited, c, cp, want in cases:
            got = (
                jit[pid_smc_step](meas, ref, state, 0.002, c),
                jit[pid_smc_step_measured](meas, ref, state, 0.002, c, accel),
                jit[pid_smc_anti_windup](state, state[::-1], accel, limited),
                jit[cascade_pid_step](meas, ref, state[:10], 0.002, cp),
                jit[cascade_pid_anti_windup](state, state[::-1], limited),
                jit[sign_smc_step](meas, ref, state[:4], 0.002, ss),
            )
            assert bits(got) == bits(want)


def _plant_steps() -> list[tuple]:
    """(state, motors, armed, force, torque, t, h, params, input) and the result of every interpreted
    plant step of a take-off with gusts and the paper's disturbances, a motor at 70 % for a while
    (with a heading turn counted), a spin-down and a touchdown."""
    env = Environment(EnvironmentParams(paper_disturbance=True, gust_force_std_xy_n=0.3, wind_force_n=(0.2, -0.1, 0.0)), random.Random(3))
    p = rigid_body_params(DEFAULT_VEHICLE)
    nominal = StepInput((1.0, 1.0, 1.0, 1.0), True, 0.0)
    faulty = StepInput((0.7, 1.0, 1.0, 1.0), True, 1.0)
    s = RigidBodyPlant(DEFAULT_VEHICLE).state
    rows = []
    t = 0.0
    for k in range(1500):
        motors = (0.52, 0.521, 0.519, 0.52) if k < 900 else (0.3, 0.3, 0.3, 0.3)
        armed = k < 1300
        env.advance(0.001)
        args = (s, motors, armed, env.force_world_n, env.torque_body_n_m, t, 0.001, p, faulty if 600 <= k < 700 else nominal)
        out = rigid_body_step(*args)
        assert out[2]
        rows.append((args, out))
        s = out[0]
        t += 0.001
    assert max(r[1][0][2] for r in rows) > 0.2 and rows[-1][1][0][2] == 0.0, "took off and came down"
    return rows


def test_compiled_plant_step_gives_the_same_bits() -> None:
    pytest.importorskip("numba")
    rows = _plant_steps()
    with compiled() as jit:
        step = jit[rigid_body_step]
        for k, (args, want) in enumerate(rows):
            assert bits(step(*args)) == bits(want), f"plant step {k} differs"


# -- the FC's estimate ------------------------------------------------------------------------------
def _estimate_ticks() -> list[tuple]:
    """(state, measured, result) of every interpreted estimator tick: clean, noisy, a position
    dropout past its timeout, a velocity dropout, an attitude dropout and a yaw across +-pi."""
    r = random.Random(2)
    nan = math.nan
    p = estimate.estimator_params(estimate.EstimatorConfig(pos_timeout_s=0.1), 0.002)
    est = estimate.ESTIMATOR_START
    rows = []
    for k in range(400):
        noise = r.gauss(0.0, 0.01) if k >= 100 else 0.0
        x, y, z = 0.5 * k * 0.002 + noise, -0.2 + noise, 3.0
        vx, vy, vz = 0.5, 0.0, 0.0
        psi = estimate.wrap_pi(3.1 + 0.002 * k + noise)
        if 150 <= k < 220:
            x = y = z = nan
        if 240 <= k < 260:
            vx = nan
        if 300 <= k < 305:
            psi = math.inf
        m = VehicleState(x, y, z, vx, vy, vz, 0.01, -0.02, psi, 0.0, 0.0, 1.0)
        out = estimate.estimate_step(est, m, 0.002, p)
        rows.append((est, m, p, out + (estimate.hold_point(out[0], p),)))
        est = out[0]
    statuses = {row[3][2] for row in rows}
    assert statuses == {estimate.EST_OK, estimate.EST_DEAD_RECKONING, estimate.EST_POSITION_LOST, estimate.EST_ATTITUDE_LOST}
    return rows


def test_estimator_state_keeps_its_types_from_tick_to_tick() -> None:
    rows = _estimate_ticks()
    first = tuple(t for _, t in leaf_types(rows[1][0]))
    assert [path for path, t in leaf_types(rows[0][2]) if t is not float] == []
    for est, _, _, out in rows[1:]:
        assert tuple(t for _, t in leaf_types(est)) == first
        assert tuple(t for _, t in leaf_types(out[1])) == (float,) * 12 and type(out[2]) is int and type(out[3]) is int


def test_compiled_estimate_step_gives_the_same_bits() -> None:
    pytest.importorskip("numba")
    rows = _estimate_ticks()
    fn, hold = estimate.estimate_step, estimate.hold_point  # the module's names are the dispatchers inside compiled()
    with compiled() as jit:
        step, hold_jit = jit[fn], jit[hold]
        for k, (est, m, p, want) in enumerate(rows):
            got = step(est, m, 0.002, p)
            assert bits(got + (hold_jit(got[0], p),)) == bits(want), f"tick {k} differs"
