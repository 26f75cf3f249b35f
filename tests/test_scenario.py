"""The one scenario description: TOML round trips, errors that name the key, and the flight it
describes flown both ways (in-process on the flight core, and the two SITL processes) with the
same per-tick motor commands."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink import mavutil

from ground.sitl import SitlOptions
from lab.run import fly
from smcpilot.faults import SENSOR_MODES, SENSORS, FaultSpec
from smcpilot.plan import PlanStep
from smcpilot.scenario import EnvironmentSpec, Scenario, ScenarioError
from smcpilot.vehicle import DEFAULT_VEHICLE, VehicleParams

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = sorted((ROOT / "examples" / "scenarios").glob("*.toml"))


# -- the description ---------------------------------------------------------------------------------
finite = st.floats(min_value=-50.0, max_value=50.0, allow_nan=False, allow_infinity=False)
unit = st.floats(0.0, 1.0)
vec3 = st.tuples(finite, finite, finite)


@st.composite
def faults(draw) -> FaultSpec:
    start = draw(st.floats(0.0, 100.0))
    stop = draw(st.one_of(st.just(float("inf")), st.floats(start + 0.001, 200.0)))
    kind = draw(st.sampled_from(("motor", "sensor", "force", "torque", "gust", "paper_disturbance")))
    kw: dict = {}
    if kind == "motor":
        kw = {"motor": draw(st.integers(1, 4)), "efficiency": draw(unit)}
    elif kind == "sensor":
        mode = draw(st.sampled_from(SENSOR_MODES))
        value = (draw(unit), 0.0, 0.0) if mode == "delay" else draw(st.tuples(unit, unit, unit)) if mode == "noise" else draw(vec3)
        kw = {"sensor": draw(st.sampled_from(SENSORS)), "mode": mode, "value": value}
    elif kind == "force":
        kw = {"force_ned_n": draw(vec3)}
    elif kind == "torque":
        kw = {"torque_frd_n_m": draw(vec3)}
    elif kind == "gust":
        kw = {"force_std_n": draw(unit), "torque_std_n_m": draw(unit), "tau_s": draw(st.floats(0.01, 10.0))}
    return FaultSpec(kind, start_s=start, stop_s=stop, **kw)


@st.composite
def scenarios(draw) -> Scenario:
    rate = draw(st.sampled_from((100.0, 250.0, 500.0)))
    steps = [PlanStep(0.0, "takeoff", alt_m=draw(st.floats(0.5, 20.0)))]
    if draw(st.booleans()):
        steps.append(PlanStep(draw(st.floats(1.0, 10.0)), "goto", north_m=draw(finite), east_m=draw(finite),
                              alt_m=draw(st.floats(0.0, 30.0)), yaw_deg=draw(st.one_of(st.none(), st.floats(-180, 180)))))  # fmt: skip
    params = draw(st.dictionaries(st.sampled_from(("SMC_CHI_DZ", "SMC_Z_KP", "ARMING_CHECK")), st.floats(0.0, 5.0), max_size=3))
    return Scenario(
        name=draw(st.text("abcdefghij-_0123456789", min_size=1, max_size=12)),
        description=draw(st.text(max_size=30)),
        duration_s=draw(st.floats(0.01, 1000.0)),
        seed=draw(st.integers(0, 2**40)),
        vehicle=DEFAULT_VEHICLE if draw(st.booleans()) else VehicleParams(mass_kg=draw(st.floats(0.2, 3.0))),
        plant=draw(st.sampled_from(("rigid-body", "paper"))),
        environment=EnvironmentSpec(
            noise=draw(st.booleans()), noise_scale=draw(st.floats(0.0, 5.0)),
            wind_force_ned_n=(draw(finite), draw(finite), draw(finite)), gust_std_n=draw(st.floats(0.0, 2.0)),
            gust_tau_s=draw(st.floats(0.01, 10.0)), paper_disturbance=draw(st.booleans()),
        ),  # fmt: skip
        controller=draw(st.sampled_from(("adaptive_pid_smc", "pid_smc", "cascade_pid"))),
        rate_hz=rate,
        physics_hz=rate * draw(st.sampled_from((1, 2, 4))),
        home=draw(st.one_of(st.none(), st.tuples(st.floats(-89, 89), st.floats(-179, 179), st.floats(-100, 4000)))),
        params=tuple(params.items()),
        plan=tuple(steps),
        faults=tuple(draw(st.lists(faults(), max_size=4))),
    )


@settings(max_examples=60, deadline=None)
@given(scenarios())
def test_toml_round_trip_gives_an_equal_scenario(sc: Scenario) -> None:
    import tomllib

    back = Scenario.from_mapping(tomllib.loads(sc.to_toml()))
    assert back.with_changes(vehicle_file=None) == sc.with_changes(vehicle_file=None)


def test_examples_load_and_name_themselves() -> None:
    assert {p.stem for p in EXAMPLES} >= {"hover", "step-yaw", "gusty-hold"}
    for path in EXAMPLES:
        sc = Scenario.from_toml(path)
        assert sc.name == path.stem and sc.plan and sc.description


def test_a_vehicle_file_resolves_against_the_scenario(tmp_path: Path) -> None:
    (tmp_path / "v").mkdir()
    (tmp_path / "v" / "q.toml").write_text("[vehicle]\nmass_kg = 0.8\n")
    (tmp_path / "s.toml").write_text('[vehicle]\nfile = "v/q.toml"\narm_length_m = 0.3\n')
    sc = Scenario.from_toml(tmp_path / "s.toml")
    assert sc.name == "s" and sc.vehicle.mass_kg == 0.8 and sc.vehicle.arm_length_m == 0.3


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("duration_s = -1\n", "duration_s must be > 0"),
        ("colour = 1\n", "unknown key 'colour'"),
        ("[environment]\nwind = 1\n", "unknown key environment.'wind'"),
        ("[environment]\nwind_force_ned_n = [1, 2]\n", "environment.wind_force_ned_n must be a list of 3 numbers"),
        ("[environment]\ngust_std_n = -0.5\n", "environment.gust_std_n must be >= 0"),
        ("[environment]\nnoise = 1\n", "environment.noise must be true or false"),
        ('[fc]\ncontroller = "lqr"\n', "fc.controller: unknown controller 'lqr'; choose from: adaptive_pid_smc"),
        ("[fc]\nrate_hz = 300\n", "sim.physics_hz (1000.0) must be a whole multiple of fc.rate_hz (300.0)"),
        ("[fc]\nhome = [91, 0, 0]\n", "fc.home latitude/longitude out of range"),
        ('[vehicle]\nplant = "blimp"\n', "vehicle.plant must be one of"),
        ("[vehicle]\nmass_kg = -1\n", "mass_kg"),
        ('[vehicle]\nfile = "missing.toml"\n', "cannot read vehicle file"),
        ('[[step]]\nt_s = 0\naction = "hover"\n', "action must be one of"),
        ('plan = "x.toml"\n[[step]]\nt_s = 0\naction = "land"\n', "either plan"),
        ("seed = 1.5\n", "seed must be a whole number"),
        ("duration_s = [\n", "not valid TOML"),
        ('[[fault]]\nkind = "motor"\nmotor = 1\n[[fault]]\nkind = "motor"\nmotor = 1\nefficiency = 1.5\n',
         "fault[2] (motor): efficiency must lie in [0, 1], got 1.5"),
        ('[[fault]]\nkind = "motor"\nmotor = 5\n', "fault[1] (motor): motor must be 1..4"),
        ('[[fault]]\nkind = "laser"\n', "fault[1]: unknown kind 'laser'"),
        ('[[fault]]\nkind = "force"\nstart_s = nan\n', "fault[1] (force): start_s must be a finite number >= 0"),
        ('[[fault]]\nkind = "force"\nstart_s = -1.0\n', "fault[1] (force): start_s must be a finite number >= 0"),
        ('[[fault]]\nkind = "force"\nstart_s = 2.0\nstop_s = 1.0\n', "fault[1] (force): stop_s (1.0) must be after start_s (2.0)"),
        ('[[fault]]\nkind = "sensor"\nsensor = "lidar"\nmode = "bias"\n', "fault[1] (sensor): unknown sensor 'lidar'"),
        ('[[fault]]\nkind = "sensor"\nsensor = "gyro"\nmode = "melt"\n', "fault[1] (sensor): unknown mode 'melt'"),
        ('fault = 3\n', "fault must be [[fault]] tables"),
    ],
)
def test_errors_name_the_file_and_the_key(tmp_path: Path, text: str, needle: str) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ScenarioError) as err:
        Scenario.from_toml(path)
    assert str(err.value).startswith(str(path)) and needle in str(err.value), str(err.value)


def test_unknown_fc_parameter_is_refused_when_the_flight_is_built() -> None:
    from fc.params import config_for

    with pytest.raises(ScenarioError, match="fc.params.NOPE: unknown parameter"):
        config_for(Scenario(params=(("NOPE", 1.0),)))
    with pytest.raises(ScenarioError, match=r"fc.params.SMC_Z_KD: SMC_Z_KD out of range"):
        config_for(Scenario(params=(("SMC_Z_KD", 1e9),)))
    cfg = config_for(Scenario(controller="pid_smc", rate_hz=250.0, physics_hz=1000.0, params=(("SMC_CHI_DZ", 0.25),)))
    assert (cfg.controller, cfg.rate_hz, cfg.adaptation.dead_zone) == ("pid_smc", 250.0, 0.25)


def test_flat_sitl_keywords_build_the_same_scenario(tmp_path: Path) -> None:
    plan = ROOT / "examples" / "plans" / "hover.toml"
    o = SitlOptions.of(controller="pid_smc", seed=4, wind_force_ned_n=(0.5, 0, 0), noise=True, plan=plan,
                       duration_s=12.0, home="47.0,8.0,400", gcs=None)  # fmt: skip
    sc = o.scenario
    assert (sc.controller, sc.seed, sc.environment.wind_force_ned_n, sc.environment.noise) == ("pid_smc", 4, (0.5, 0.0, 0.0), True)
    assert sc.home == (47.0, 8.0, 400.0) and sc.duration_s == 12.0 and o.timed and sc.plan and o.gcs is None
    assert SitlOptions.of(scenario=sc, seed=9).scenario == sc.with_changes(seed=9)
    assert not SitlOptions.of().timed  # no duration: until stopped


# -- flying it both ways ------------------------------------------------------------------------------
def _motors(tlog: Path) -> dict[int, tuple[float, ...]]:
    m = mavutil.mavlink_connection(str(tlog))
    out: dict[int, tuple[float, ...]] = {}
    while (msg := m.recv_match(type="HIL_ACTUATOR_CONTROLS")) is not None:
        assert msg.time_usec not in out, "one actuator message per tick"
        out[msg.time_usec] = tuple(msg.controls[:4])
    m.close()
    return out


@pytest.mark.slow
@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.stem)
def test_each_example_flies_the_same_in_process_and_as_sitl(tmp_path: Path, path: Path) -> None:
    sc = Scenario.from_toml(path)
    sc = sc.with_changes(duration_s=min(sc.duration_s, 12.0))
    a = fly(sc, tmp_path / "inproc")
    b = fly(sc, tmp_path / "sitl", sitl=True)
    assert a.status == b.status == "ok", (a.message, b.message)
    ma, mb = _motors(a.tlog), _motors(b.tlog)
    assert len(ma) == sc.n_ticks == a.ticks == b.ticks
    assert ma == mb  # bit for bit, tick for tick
    assert max(max(v) for v in ma.values()) > 0.1  # it flew
    sa, sb = a.as_json(), b.as_json()
    for key in ("ticks", "chi_hat_final", "position_error_final_m", "position_error_rms_m", "max_tilt_deg", "metrics"):
        assert sa[key] == sb[key], key
    assert [t for _, t in a.events] == [t for _, t in b.events]
    # Both ways flew the scenario's FC parameters: the FC logs its configuration at start.
    from ground.logs import load_log

    for res in (a, b):
        logged = load_log(res.tlog).params
        for name, value in sc.params:
            assert logged[name] == pytest.approx(value, rel=1e-6), (res.mode, name)
    if sc.name == "step-yaw":
        assert dict(sc.params) == {"SMC_CHI_DZ": 0.3}


def test_in_process_runs_are_deterministic_and_seeded(tmp_path: Path) -> None:
    sc = Scenario.from_toml(ROOT / "examples" / "scenarios" / "gusty-hold.toml").with_changes(duration_s=6.0)
    one = fly(sc, tmp_path / "a").tlog.read_bytes()
    two = fly(sc, tmp_path / "b").tlog.read_bytes()
    other = fly(sc.with_changes(seed=8), tmp_path / "c").tlog.read_bytes()
    assert one == two and one != other


def test_smcpilot_run_prints_the_summary_and_writes_json(tmp_path: Path) -> None:
    out = tmp_path / "out"
    r = subprocess.run(
        [sys.executable, "-m", "lab.cli", "run", str(ROOT / "examples" / "scenarios" / "hover.toml"), "--out", str(out),
         "--json", str(tmp_path / "r.json"), "--duration", "8", "--controller", "cascade_pid"],
        capture_output=True, text=True, timeout=120, cwd=tmp_path,
    )  # fmt: skip
    assert r.returncode == 0, r.stdout + r.stderr
    doc = json.loads((tmp_path / "r.json").read_text())
    assert doc["status"] == "ok" and doc["mode"] == "in-process" and doc["controller"] == "cascade_pid"
    assert doc["ticks"] == 8 * 500 + 1 and doc["sim_seconds"] == pytest.approx(8.0)
    assert doc["chi_hat_final"] is None  # the cascaded PID has no adaptive gain
    assert doc["max_tilt_deg"] < 10 and doc["events"][0]["text"] == "Armed"
    assert "Max tilt" in r.stdout and "run: ok; 4001 ticks" in r.stdout
    assert (out / "hover.tlog").is_file() and (out / "position.png").is_file()
    again = Scenario.from_toml(out / "hover.scenario.toml")  # the effective scenario, re-runnable
    assert again.controller == "cascade_pid" and again.duration_s == 8.0


def test_smcpilot_run_refuses_a_broken_scenario_in_one_line(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text("[environment]\ngust_std_n = -1\n")
    r = subprocess.run([sys.executable, "-m", "lab.cli", "run", str(bad)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "gust_std_n must be >= 0" in r.stderr, r.stderr


@pytest.mark.slow
def test_smcpilot_sitl_flies_a_scenario_and_flags_change_it(tmp_path: Path) -> None:
    r = subprocess.run(
        [sys.executable, "-m", "lab.cli", "sitl", "--scenario", str(ROOT / "examples" / "scenarios" / "gusty-hold.toml"),
         "--lockstep", "--duration", "2", "--gcs", "none", "--seed", "9", "--log-dir", str(tmp_path)],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert r.returncode == 0, r.stdout + r.stderr
    (written,) = tmp_path.glob("*.scenario.toml")
    sc = Scenario.from_toml(written)
    assert sc.seed == 9 and sc.environment.noise and sc.environment.gust_std_n == 0.15 and len(sc.plan) == 3
    assert "1001 control ticks" in r.stdout


def test_a_file_that_is_not_text_is_a_clear_error_for_every_toml_reader(tmp_path: Path) -> None:
    from smcpilot.errors import VehicleFileError
    from smcpilot.plan import PlanError, load_plan

    path = tmp_path / "binary.toml"
    path.write_bytes(b"\xff\xfe\x00garbage")
    for load, error in ((Scenario.from_toml, ScenarioError), (VehicleParams.from_toml, VehicleFileError), (load_plan, PlanError)):
        with pytest.raises(error, match=r"cannot read .*binary\.toml: not UTF-8 text"):
            load(path)
    with pytest.raises(ScenarioError, match="cannot read scenario"):
        Scenario.from_toml(tmp_path)  # a directory
