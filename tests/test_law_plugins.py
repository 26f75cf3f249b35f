"""Laws from outside the project: a file, a module, an installed package's entry point.

The example plug-in (``examples/law-plugin``, the tutorial's law) flies in-process and as the two
processes, with the same motor commands tick for tick; installed with pip it is found through its
entry point by real ``smcpilot`` processes. Its parameters are MAVLink parameters. Bad laws (import
errors, bad prefixes, names taken, parameters without ranges, names too long) give one line and
exit 2; a law that raises or returns NaN in flight is counted, flown around (failsafe, land) and
reported, in-process and over the two processes, with the log whole.
"""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from fc.config import FcConfig
from fc.control import registry
from fc.control.law import LawError
from fc.flight import FlightControl
from fc.params import ParamStore, param_table
from ground.logs import load_log
from lab.run import fly
from smcpilot.errors import ParamError
from smcpilot.scenario import Scenario
from smcpilot.vehicle import DEFAULT_VEHICLE

ROOT = Path(__file__).resolve().parent.parent
PLUGIN_DIR = ROOT / "examples" / "law-plugin"
PD_FILE = PLUGIN_DIR / "smcpilot_pd_law" / "pd_law.py"
PD_REF = f"{PD_FILE}:PD_LAW"
SMCPILOT = str(Path(sys.executable).with_name("smcpilot"))


def _hover(controller: str, duration_s: float = 6.0) -> Scenario:
    sc = Scenario.from_toml(ROOT / "examples" / "scenarios" / "hover.toml")
    return sc.with_changes(controller=controller, duration_s=duration_s)


def _run(*args: str, env: dict[str, str] | None = None, cwd: Path = ROOT, timeout: float = 120.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run([SMCPILOT, *args], capture_output=True, text=True, timeout=timeout, cwd=cwd, env=env, stdin=subprocess.DEVNULL)


# -- a law from a file, flown both ways ---------------------------------------------------------------
@pytest.mark.slow
def test_a_law_from_a_file_flies_in_process_and_as_sitl_with_the_same_motor_commands(tmp_path: Path) -> None:
    sc = _hover(PD_REF, 6.0)
    a = fly(sc, tmp_path / "in")
    b = fly(sc, tmp_path / "sitl", sitl=True)
    assert a.status == "ok" and b.status == "ok", (a.message, b.message)
    la, lb = load_log(a.tlog), load_log(b.tlog)
    n = min(len(la.motors), len(lb.motors))
    assert n > 2500
    assert np.array_equal(la.motors[:n], lb.motors[:n]), "the same law, the same commands, tick for tick"
    # it took off and holds 3 m
    assert abs(la.alt_m[-1] - 3.0) < 0.05 and abs(la.north_m[-1]) < 0.05 and abs(la.east_m[-1]) < 0.05


def test_the_file_law_is_listed_with_its_parameters_and_its_origin() -> None:
    r = _run("laws", "--law", str(PD_FILE.relative_to(ROOT)) + ":PD_LAW", "--params")
    assert r.returncode == 0, r.stderr
    line = next(ln for ln in r.stdout.splitlines() if "pd_feedback" in ln and "attitude" in ln)
    assert f"file {PD_FILE}" in line
    for name in ("PDL_KP_ATT", "PDL_KD_ATT", "PDL_KP_YAW", "PDL_KD_YAW", "PDL_KP_Z", "PDL_KD_Z", "PDL_KI_Z"):
        assert name in r.stdout
    for name in ("adaptive_pid_smc", "pid_smc", "cascade_pid", "sign_smc"):
        assert f"  {name} " in r.stdout


def test_its_parameters_are_mavlink_parameters_settable_live_and_validated() -> None:
    law = registry.resolve(PD_REF)
    table = param_table()
    assert "PDL_KP_ATT" in table.index and table.specs[table.index["FC_CONTROLLER"]].hi >= 6
    cfg = FcConfig(controller=PD_REF)
    store = ParamStore(cfg)
    assert store.value("PDL_KP_ATT") == 64.0
    fl = FlightControl(store.config, DEFAULT_VEHICLE)
    assert fl.params.law[1] == 64.0 and fl.law is law
    fl.reconfigure(store.set("PDL_KP_ATT", 49.0, persist=False))
    assert fl.params.law[1] == 49.0, "a live change reaches the flying law's constants"
    with pytest.raises(ParamError, match=r"PDL_KP_ATT out of range \[0, 1000\]"):
        store.set("PDL_KP_ATT", 5000.0)
    # FC_CONTROLLER names it by its place in the table, and switching back and forth works
    idx = [lw.name for lw in registry.flight_laws()].index("pd_feedback")
    assert store.value("FC_CONTROLLER") == idx
    store.set("FC_CONTROLLER", 2.0, persist=False)
    assert store.pending.controller == "cascade_pid"


def test_a_scenario_sets_its_parameters_and_a_relative_law_file_resolves_beside_it(tmp_path: Path) -> None:
    law_dir = tmp_path / "laws"
    law_dir.mkdir()
    (law_dir / "my_law.py").write_text(PD_FILE.read_text().replace('name="pd_feedback"', 'name="pd_copy"').replace('prefix="PDL"', 'prefix="PDC"'))
    (tmp_path / "s.toml").write_text(textwrap.dedent("""
        name = "mine"
        duration_s = 2.0
        [fc]
        controller = "laws/my_law.py:PD_LAW"
        [fc.params]
        PDC_KP_Z = 5.0
        [[step]]
        t_s = 0.0
        action = "takeoff"
        alt_m = 1.0
    """))
    sc = Scenario.from_toml(tmp_path / "s.toml")
    assert sc.controller == f"{(law_dir / 'my_law.py').resolve()}:PD_LAW"
    from fc.params import config_for

    assert dict(config_for(sc).law_values) == {"PDC_KP_Z": 5.0}
    # the same name from another file is refused, naming the first
    (law_dir / "other.py").write_text((law_dir / "my_law.py").read_text())
    with pytest.raises(LawError, match="law name 'pd_copy' is already taken by file .*my_law.py"):
        registry.resolve(f"{law_dir / 'other.py'}:PD_LAW")


# -- installed with pip: the entry point ----------------------------------------------------------------
@pytest.fixture(scope="module")
def installed_plugin(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    """The example package installed by pip into a directory of its own (no index, no build isolation);
    an environment whose PYTHONPATH has it, as a user's site-packages would."""
    target = tmp_path_factory.mktemp("site")
    r = subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-build-isolation", "--no-index",
                        "--target", str(target), str(PLUGIN_DIR)], capture_output=True, text=True, timeout=300)  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert any(p.name.startswith("smcpilot_pd_law") and p.name.endswith(".dist-info") for p in target.iterdir())
    env = dict(os.environ)
    env["PYTHONPATH"] = str(target) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    return env


@pytest.mark.slow
def test_an_installed_plugin_is_listed_through_its_entry_point(installed_plugin: dict[str, str], tmp_path: Path) -> None:
    r = _run("laws", "--json", env=installed_plugin, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    import json

    rows = {row["name"]: row for row in json.loads(r.stdout)}
    assert rows["pd_feedback"]["origin"] == "entry point smcpilot-pd-law"
    assert rows["pd_feedback"]["fc_controller"] == 6 and rows["pd_feedback"]["stage"] == "attitude"
    assert [p["name"] for p in rows["pd_feedback"]["parameters"]][:2] == ["PDL_KP_ATT", "PDL_KD_ATT"]
    pdef = tmp_path / "apm.pdef.xml"
    assert _run("laws", "--pdef", str(pdef), env=installed_plugin, cwd=tmp_path).returncode == 0
    assert 'name="ArduCopter:PDL_KP_ATT"' in pdef.read_text() and "6 pd_feedback" in pdef.read_text()


@pytest.mark.slow
def test_an_installed_plugin_flies_by_name_in_process_and_as_sitl(installed_plugin: dict[str, str], tmp_path: Path) -> None:
    for extra in ((), ("--sitl",)):
        out = tmp_path / ("sitl" if extra else "in")
        r = _run("run", str(ROOT / "examples" / "scenarios" / "hover.toml"), "--controller", "pd_feedback", "--duration", "4",
                 "--no-plots", "--quiet", "--out", str(out), *extra, env=installed_plugin, cwd=tmp_path)  # fmt: skip
        assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
        assert "run: ok" in r.stdout
        assert 'controller = "pd_feedback"' in (out / "hover.scenario.toml").read_text()


# -- bad laws: one line, exit 2, nothing started --------------------------------------------------------
_GOOD = PD_FILE.read_text()


@pytest.mark.parametrize(
    ("source", "needle"),
    [
        ("raise RuntimeError('boom')\n", "importing .* failed: RuntimeError: boom"),
        (_GOOD.replace('prefix="PDL"', 'prefix="pd_l"'), "parameter prefix 'pd_l' must be 1-8 upper-case"),
        (_GOOD.replace('name="pd_feedback"', 'name="cascade_pid"'), "law name 'cascade_pid' is a built-in law's"),
        (_GOOD.replace('kp_att: float = param(64.0, lo=0.0, hi=1000.0, unit="1/s^2", doc="roll/pitch: angle error -> angular acceleration")',
                       "kp_att: float = 64.0"), "parameter PdParams.kp_att has no range"),
        (_GOOD.replace("param(64.0, lo=0.0,", 'param(64.0, name="KP_ATTITUDE_X", lo=0.0,'), "parameter name PDL_KP_ATTITUDE_X is longer than 16"),
        (_GOOD.replace("param(64.0, lo=0.0,", "param(-1.0, lo=0.0,"), "PDL_KP_ATT default -1 outside its range"),
        (_GOOD + "\nPD_LAW = 3\n", "not a fc.control.law.Law but int"),
    ],
    ids=["import-error", "bad-prefix", "taken-name", "no-range", "name-too-long", "default-out-of-range", "not-a-law"],
)
def test_a_bad_law_is_one_line_and_exit_2(tmp_path: Path, source: str, needle: str) -> None:
    f = tmp_path / "bad_law.py"
    f.write_text(source)
    for args in (("laws", "--law", f"{f}:PD_LAW"), ("run", str(ROOT / "examples" / "scenarios" / "hover.toml"), "--law", f"{f}:PD_LAW",
                                                    "--out", str(tmp_path / "out"), "--no-plots")):  # fmt: skip
        r = _run(*args, cwd=tmp_path)
        assert r.returncode == 2, (args, r.stdout, r.stderr)
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1, r.stderr
        import re

        assert re.search(needle, lines[0]), lines[0]
        assert not (tmp_path / "out").exists(), "nothing flew"


def test_unknown_names_list_the_choices() -> None:
    with pytest.raises(LawError, match="unknown control law 'lqr'; choose from: adaptive_pid_smc, pid_smc, cascade_pid, sign_smc"):
        registry.resolve("lqr")
    with pytest.raises(LawError, match="no such file"):
        registry.resolve("/nonexistent/law.py:LAW")
    with pytest.raises(LawError, match="has no NOPE"):
        registry.resolve(f"{PD_FILE}:NOPE")


# -- a law that fails in flight ----------------------------------------------------------------------------
_FAILING = '''
import math
from dataclasses import dataclass
from fc.control.law import Law, param

@dataclass(frozen=True)
class P:
    after: float = param(800.0, lo=1.0, hi=1e6, unit="ticks", doc="fail after this many ticks")

def consts(ctx, p):
    return (tuple(ctx.model.consts()), p.after)

def init(meas, k):
    return (0.0,)

def step(meas, ref, state, dt_s, k, d_hat, u_prev):
    m = k[0]
    z = (0.0, 0.0, 0.0, 0.0)
    n = state[0] + 1.0
    if n > k[1]:
        {failure}
    # hover thrust with a little altitude feedback and attitude damping
    u = (-0.05 * meas[1] - 0.2 * meas[0], -0.05 * meas[3] - 0.2 * meas[2], -0.002 * meas[5], m[0] * (m[1] + 2.0 * (ref[12] - meas[6]) - 2.0 * meas[7]))
    return u, (n,), (z, z, z, z)

LAW = Law(name="{name}", stage="attitude", prefix="{prefix}", description="fails in flight", params_class=P,
          consts=consts, initial_state=init, step=step)
'''


@pytest.mark.slow
@pytest.mark.parametrize(("kind", "failure", "why"), [
    ("raises", "raise ZeroDivisionError('the law divided by zero')", "ZeroDivisionError: the law divided by zero"),
    ("nan", "return (math.nan, 0.0, 0.0, 1.0), (n,), (z, z, z, z)", "non-finite command"),
    ("inf", "return (0.0, 0.0, 0.0, math.inf), (n,), (z, z, z, z)", "non-finite command"),
    ("short", "return (0.0, 0.0, 1.0), (n,), (z, z, z, z)", "IndexError: tuple index out of range"),
])  # fmt: skip
@pytest.mark.parametrize("sitl", [False, True], ids=["in-process", "sitl"])
def test_a_law_failing_in_flight_is_counted_flown_around_and_reported(tmp_path: Path, kind: str, failure: str, why: str, sitl: bool) -> None:
    f = tmp_path / f"failing_{kind}.py"
    mode = "sitl" if sitl else "inproc"  # law names are unique in a process: one per case
    f.write_text(_FAILING.replace("{failure}", failure).replace("{name}", f"failing_{kind}_{mode}").replace("{prefix}", f"F{kind.upper()[:3]}{mode[0].upper()}"))
    sc = _hover(f"{f}:LAW", 5.0)
    result = fly(sc, tmp_path / "out", sitl=sitl)
    log = load_log(result.tlog)
    texts = [e.text for e in log.events]
    assert any(t.startswith("FAILSAFE: law failing_") for t in texts), texts
    assert sum(t.startswith("FAILSAFE: law") for t in texts) == 1, "announced once, not every tick"
    assert any(why[:20] in t for t in texts), texts
    assert log.act_t_s[-1] - log.act_t_s[0] > 4.9
    assert len(log.motors) >= 0.95 * 5.0 * sc.rate_hz, "the log is whole: the loop flew on to the end"
    if not sitl:
        assert result.status == "error" and why in result.message, result.message
    # after the failure the motors are the failsafe's: level, equal, below hover
    late = log.motors[-100:]
    assert np.allclose(late, late[:, :1], atol=1e-9) or not late.any()


def test_a_law_failure_keeps_the_state_and_counts(tmp_path: Path) -> None:
    f = tmp_path / "nan_law.py"
    f.write_text(_FAILING.replace("{failure}", "return (math.nan, 0.0, 0.0, 1.0), (n,), (z, z, z, z)").replace("{name}", "nan_law").replace("{prefix}", "NANL"))
    from fc.flight import LawFault, VehicleState

    fl = FlightControl(dataclasses.replace(FcConfig(controller=f"{f}:LAW"), law_values=(("NANL_AFTER", 3.0),)), DEFAULT_VEHICLE)
    st = VehicleState(*(0.0,) * 12)
    fl.arm(st)
    for _ in range(3):
        fl.step(st, 0.002)
    before = fl.pipeline_state
    with pytest.raises(LawFault, match="law nan_law: non-finite command"):
        fl.step(st, 0.002)
    assert fl.pipeline_state is before and fl.law_faults == 1


# -- the tutorial, as written -------------------------------------------------------------------------------
TUTORIAL = (ROOT / "docs" / "your-own-law.md").read_text(encoding="utf-8")


def _blocks(lang: str) -> list[str]:
    import re

    return re.findall(rf"```{lang}\n(.*?)```", TUTORIAL, flags=re.S)


def test_the_tutorials_law_is_the_example_plugins_code() -> None:
    import ast

    (code,) = _blocks("python")
    module = ast.parse(PD_FILE.read_text())
    body = module.body[1:] if isinstance(module.body[0], ast.Expr) else module.body  # the file's docstring
    assert ast.dump(ast.parse(code)) == ast.dump(ast.Module(body=body, type_ignores=[])), "docs/your-own-law.md and pd_law.py differ"
    assert len(code.strip().splitlines()) <= 60


@pytest.mark.slow
def test_the_tutorials_fly_it_commands_run_as_written(tmp_path: Path) -> None:
    block = next(b for b in _blocks("bash") if b.startswith("LAW="))
    env = dict(os.environ)
    env["PATH"] = str(Path(SMCPILOT).parent) + os.pathsep + env.get("PATH", "")
    # as written, from the project root; the runs' output goes where the commands put it (out/run/...)
    r = subprocess.run(["bash", "-euo", "pipefail", "-c", block.replace("--sitl", "--sitl --out " + str(tmp_path / "sitl"))
                        .replace("--law $LAW            #", f"--law $LAW --out {tmp_path / 'in'} #")],
                       capture_output=True, text=True, timeout=300, cwd=ROOT, env=env, stdin=subprocess.DEVNULL)  # fmt: skip
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert "PDL_KP_ATT" in r.stdout and r.stdout.count("run: ok") == 2


@pytest.mark.slow
def test_a_law_too_slow_for_the_rate_in_real_time_is_failed_and_the_failsafe_flies(tmp_path: Path) -> None:
    """Real time at 100 Hz, a law that takes 15 ms a tick once armed: after 25 ticks (net) over the
    10 ms period the FC announces it, and the open-loop failsafe (cheap) keeps the rate."""
    from sitl_helpers import HANG_TIMEOUT_S, sitl_options

    from ground.sitl import Sitl

    f = tmp_path / "slow_law.py"
    f.write_text(_FAILING.replace("{failure}", "time.sleep(0.015)").replace("import math", "import math\nimport time")
                 .replace("{name}", "slow_law").replace("{prefix}", "SLOW").replace("param(800.0,", "param(20.0,"))  # fmt: skip
    opts = sitl_options(tmp_path, "slow", duration_s=3.0, lockstep=False, controller=f"{f}:LAW", rate_hz=100.0, physics_hz=1000.0)
    with Sitl(opts) as sitl:
        assert sitl.wait(timeout_s=HANG_TIMEOUT_S) == 0
    assert opts.tlog is not None
    texts = [e.text for e in load_log(opts.tlog).events]
    slow = [t for t in texts if t.startswith("FAILSAFE: law slow_law: overran its tick 25 times")]
    assert len(slow) == 1, texts


# -- campaigns and tuning: plug-in laws on Dask workers ------------------------------------------------------
@pytest.mark.slow
def test_a_campaign_flies_plugin_laws_on_workers_and_records_a_failing_law_as_an_error(tmp_path: Path) -> None:
    """The worker processes load the law files themselves; a law that fails in flight is its unit's
    'error' row, and the campaign goes on; a plug-in's parameter is a campaign variation."""
    import csv

    failing = tmp_path / "failing_campaign.py"
    failing.write_text(_FAILING.replace("{failure}", "raise ValueError('bad gain')").replace("{name}", "failing_campaign")
                       .replace("{prefix}", "FCMP").replace("param(800.0,", "param(600.0,"))  # fmt: skip
    camp = tmp_path / "c.toml"
    camp.write_text(textwrap.dedent(f"""
        name = "plugins"
        seed = 1
        seeds = 2
        scenario = "{ROOT / 'examples' / 'scenarios' / 'hover.toml'}"
        duration_s = 4.0
        [[controller]]
        label = "pd"
        controller = "{PD_FILE}:PD_LAW"
        [[controller]]
        label = "failing"
        controller = "{failing.name}:LAW"
        [[vary]]
        field = "fc.params.PDL_KP_Z"
        dist = "uniform"
        low = 3.0
        high = 5.0
    """))
    r = _run("campaign", "run", str(camp), "--out", str(tmp_path / "out"), "--workers", "1", "--quiet", "--no-plots", cwd=tmp_path, timeout=300)
    rows = list(csv.DictReader((tmp_path / "out" / "results.csv").open()))
    assert len(rows) == 4, (r.stdout[-2000:], r.stderr[-2000:])
    by = {(row["controller"], row["seed_index"]): row for row in rows}
    assert {k[0] for k in by} == {"pd", "failing"}
    for s in ("0", "1"):
        assert by[("pd", s)]["status"] == "ok", by[("pd", s)]
        assert 3.0 <= float(by[("pd", s)]["fc.params.PDL_KP_Z"]) <= 5.0
        assert by[("failing", s)]["status"] == "error" and "ValueError: bad gain" in by[("failing", s)]["message"]


@pytest.mark.slow
def test_a_plugin_laws_gains_are_tunable(tmp_path: Path) -> None:
    from lab.tuning.study import parse_tune

    spec = parse_tune({
        "scenario": str(ROOT / "examples" / "scenarios" / "hover.toml"), "controllers": [PD_REF], "trials": 2,
        "gain": [{"name": "PDL_KP_ATT", "low": 20.0, "high": 200.0, "log": True}],
    }, source="t.toml")  # fmt: skip
    assert [g.name for g in spec.gains] == ["PDL_KP_ATT"] and spec.campaign.variants[0].controller == PD_REF
    from lab.campaign.spec import CampaignError

    with pytest.raises(CampaignError, match=r"PDL_KP_ATT\): the range \[20, 2000\] leaves the parameter's valid range \[0, 1000\]"):
        parse_tune({"scenario": str(ROOT / "examples" / "scenarios" / "hover.toml"), "controllers": [PD_REF], "trials": 2,
                    "gain": [{"name": "PDL_KP_ATT", "low": 20.0, "high": 2000.0}]}, source="t.toml")  # fmt: skip


def test_laws_says_which_law_is_not_in_the_pure_style(tmp_path: Path) -> None:
    f = tmp_path / "impure_law.py"
    f.write_text(_FAILING.replace("{failure}", "raise ValueError('no')").replace("{name}", "impure_law").replace("{prefix}", "IMPL"))
    r = _run("laws", "--law", f"{PD_FILE}:PD_LAW", "--law", f"{f}:LAW", "--json", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    import json

    rows = {row["name"]: row for row in json.loads(r.stdout)}
    assert rows["pd_feedback"]["pure_style"] and all(rows[n]["pure_style"] for n in ("adaptive_pid_smc", "se3_geometric", "indi"))
    assert not rows["impure_law"]["pure_style"]
    assert any("step line" in p and "Raise" in p for p in rows["impure_law"]["style_problems"]), rows["impure_law"]["style_problems"]
    text = _run("laws", "--law", f"{f}:LAW", cwd=tmp_path).stdout
    assert "not in the pure style (flies in CPython only): step line" in text


@pytest.mark.slow
def test_a_mission_file_flies_a_law_file_beside_it(tmp_path: Path) -> None:
    """``smcpilot mission run``: the mission's [sitl] controller is a law file relative to the mission."""
    (tmp_path / "laws").mkdir()
    (tmp_path / "laws" / "pd.py").write_text(PD_FILE.read_text().replace('name="pd_feedback"', 'name="pd_mission"').replace('prefix="PDL"', 'prefix="PDM"'))
    mission = tmp_path / "m.toml"
    mission.write_text(textwrap.dedent("""
        name = "pd-mission"
        [sitl]
        controller = "laws/pd.py:PD_LAW"
        max_duration_s = 60.0
        [[item]]
        type = "takeoff"
        alt_m = 2.0
        [[item]]
        type = "waypoint"
        north_m = 1.0
        east_m = 0.0
        alt_m = 2.0
        [[item]]
        type = "land"
        [[expect]]
        kind = "reach"
        item = 2
        within_m = 0.35
        by_s = 20.0
    """))
    from ground.missions import load_mission

    assert load_mission(mission).sitl.controller == f"{(tmp_path / 'laws' / 'pd.py').resolve()}:PD_LAW"
    r = _run("mission", "run", str(mission), cwd=tmp_path, timeout=300)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-2000:]
    assert "1/1 expectations held" in r.stdout and "FC_CONTROLLER=6" in r.stdout + r.stderr


def test_a_value_the_laws_constants_refuse_is_undone_and_the_fc_flies_on(tmp_path: Path) -> None:
    """A plug-in whose consts() raises for some value (its own check): the PARAM_SET is refused with
    the reason, the old value stays in force and in the answer, and the law keeps flying."""
    f = tmp_path / "picky_law.py"
    f.write_text(_FAILING.replace("{failure}", "pass").replace("{name}", "picky_law").replace("{prefix}", "PICKY")
                 .replace("def consts(ctx, p):\n    return", "def consts(ctx, p):\n    assert p.after < 5000.0, 'after must stay below 5000'\n    return"))  # fmt: skip
    from fc.control.law import LawError
    from fc.flight import VehicleState

    cfg = FcConfig(controller=f"{f}:LAW")
    store = ParamStore(cfg)
    fl = FlightControl(store.config, DEFAULT_VEHICLE)
    fl.arm(VehicleState(*(0.0,) * 12))
    before = fl.params
    new = store.set("PICKY_AFTER", 6000.0, persist=False)  # in its range: the store takes it
    with pytest.raises(LawError, match="law picky_law: its constants could not be computed: AssertionError: after must stay below 5000"):
        fl.reconfigure(new)
    assert fl.params is before and fl.config is cfg, "nothing changed"
    fl.step(VehicleState(*(0.0,) * 12), 0.002)


@pytest.mark.slow
def test_over_mavlink_a_value_the_law_refuses_is_answered_with_the_old_one(tmp_path: Path) -> None:
    from gcs_helpers import LOOPBACK, Gcs

    from ground.sitl import Sitl, SitlOptions

    f = tmp_path / "picky_law.py"
    f.write_text(_FAILING.replace("{failure}", "pass").replace("{name}", "picky_mav").replace("{prefix}", "PICKM")
                 .replace("def consts(ctx, p):\n    return", "def consts(ctx, p):\n    assert p.after < 5000.0, 'after must stay below 5000'\n    return"))  # fmt: skip
    gcs = Gcs()
    try:
        opts = SitlOptions.of(lockstep=True, speed=5.0, gcs=f"udp:{LOOPBACK}:{gcs.port}", tlog=tmp_path / "p.tlog", log_dir=tmp_path,
                              param_file=tmp_path / "p.parm", controller=f"{f}:LAW")  # fmt: skip
        with Sitl(opts):
            gcs.heartbeat()
            mark = gcs.mark()
            assert gcs.param_set("PICKM_AFTER", 6000.0).param_value == 800.0, "refused: the value in force"
            gcs.wait("STATUSTEXT", lambda m: "its constants" in m.text, since=mark, what="the reason")
            assert gcs.param_set("PICKM_AFTER", 1000.0).param_value == 1000.0, "a value it takes is taken"
        assert "PICKM_AFTER 1000.0" in (tmp_path / "p.parm").read_text()
    finally:
        gcs.close()


@pytest.mark.slow
def test_the_fc_says_once_that_a_law_is_not_in_the_pure_style(tmp_path: Path) -> None:
    f = tmp_path / "impure_fc.py"
    f.write_text(_FAILING.replace("{failure}", "raise ValueError('no')").replace("{name}", "impure_fc").replace("{prefix}", "IMPF"))
    r = _run("run", str(ROOT / "examples" / "scenarios" / "hover.toml"), "--law", f"{f}:LAW", "--sitl", "--duration", "1", "--no-plots",
             "--out", str(tmp_path / "out"), cwd=tmp_path)  # fmt: skip
    said = [ln for ln in (r.stdout + r.stderr).splitlines() if "is not in the pure style" in ln]
    assert len(said) == 1 and "step line" in said[0] and "flies in CPython only" in said[0], r.stdout[-2000:]
