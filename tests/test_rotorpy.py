"""An independent plant: rotorpy's quadrotor flies our flight controller through PX4's simulator API.

rotorpy (PyPI, the ``test`` extra) is another team's multirotor simulator with aerodynamics; its
``px4_sihsim_quadx_params`` is PX4's SIH quad X (1 kg, 0.24 m arms, 50 ms motors), not our default
vehicle. The FC runs as a real process (``python -m fc --sim px4:tcp:...``), rotorpy's
``PX4Multirotor`` listens on TCP and steps its own integrator (``lab.rotorpy_px4``). The FC's
vehicle is rotorpy's mapped by :func:`smcpilot.rotorpy_vehicle.vehicle_from_rotorpy`.

The bounds (docs/external-simulators.md, "rotorpy"), measured first and then set with margin:
the take-off, set-point and landing flight holds within 0.1 m of each set-point once settled
(rotorpy's own truth, not the FC's log), tilts less than 20°, lands and disarms; in the comparison
with our plant (the same mapped vehicle on our rigid body, same plan and fault), each case's
position IAE is within 15 % of ours, the fault's attitude IAE within 40 %, both tilt less than 10°,
neither crashes, both recover.
"""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import pytest
from rotorpy.vehicles import hummingbird_params, px4_sihsim_quadx_params

from ground.logs.load import load_log
from ground.logs.summary import log_metrics
from lab.rotorpy_px4 import MotorFault, fly
from smcpilot.errors import VehicleFileError
from smcpilot.rotorpy_vehicle import rotorpy_frame, vehicle_from_rotorpy
from tests.sitl_helpers import write_plan

PX4_QUAD = px4_sihsim_quadx_params.quad_params


def test_converter_maps_px4_sih_quad() -> None:
    v = vehicle_from_rotorpy(PX4_QUAD)
    assert rotorpy_frame(PX4_QUAD) == "quad-x"
    assert v.mass_kg == 1.0 and (v.ixx_kg_m2, v.iyy_kg_m2, v.izz_kg_m2) == (0.025, 0.025, 0.030)
    assert v.arm_length_m == pytest.approx(0.17 * math.sqrt(2.0))
    assert (v.thrust_coeff_n_s2, v.drag_coeff_n_m_s2) == (5e-6, 1e-7)
    assert (v.motor_time_constant_s, v.rotor_speed_max_radps, v.rotor_speed_idle_radps) == (0.05, 1000.0, 0.0)
    assert (v.lin_drag_x_n_s_m, v.lin_drag_z_n_s_m) == (0.01, 0.01)  # c_D at 1 m/s; no rotor drag in these params
    assert v.thrust_to_weight == pytest.approx(4 * 5e-6 * 1000.0**2 / 9.81)
    # rotor drag and inflow at hover join the linear drag
    h = hummingbird_params.quad_params
    vh = vehicle_from_rotorpy({**h, "rotor_pos": PX4_QUAD["rotor_pos"], "rotor_directions": PX4_QUAD["rotor_directions"]},
                              drag_speed_mps=2.0)  # fmt: skip
    w_hover = math.sqrt(h["mass"] * 9.81 / (4 * h["k_eta"]))
    assert vh.lin_drag_x_n_s_m == pytest.approx(h["c_Dx"] * 2.0 + 4 * h["k_d"] * w_hover)
    assert vh.lin_drag_z_n_s_m == pytest.approx(h["c_Dz"] * 2.0 + 4 * h["k_z"] * w_hover)


def test_converter_names_what_it_cannot_map() -> None:
    # the Hummingbird is an X with another motor order than PX4's
    with pytest.raises(VehicleFileError, match="neither in PX4's quadrotor X order"):
        rotorpy_frame(hummingbird_params.quad_params)
    d = 0.2
    plus = {**PX4_QUAD, "rotor_pos": {"r1": [0.0, -d, 0.0], "r2": [d, 0.0, 0.0], "r3": [0.0, d, 0.0], "r4": [-d, 0.0, 0.0]},
            "rotor_directions": [1, -1, 1, -1]}  # fmt: skip
    assert rotorpy_frame(plus) == "plus"
    with pytest.raises(VehicleFileError, match="different distances"):
        vehicle_from_rotorpy({**plus, "rotor_pos": {**plus["rotor_pos"], "r1": [0.0, -0.3, 0.0]}})
    with pytest.raises(VehicleFileError, match="num_rotors must be 4"):
        vehicle_from_rotorpy({**PX4_QUAD, "num_rotors": 6})
    with pytest.raises(VehicleFileError, match="products of inertia"):
        vehicle_from_rotorpy({**PX4_QUAD, "Ixy": 1e-4})


@pytest.mark.slow
def test_rotorpy_flies_take_off_set_point_landing(tmp_path: Path) -> None:
    plan = write_plan(tmp_path / "plan.toml", [{"t_s": 0.0, "action": "takeoff", "alt_m": 3.0},
                                               {"t_s": 12.0, "action": "goto", "north_m": 2.0, "east_m": -1.0, "alt_m": 4.0},
                                               {"t_s": 26.0, "action": "land"}])  # fmt: skip
    f = fly(PX4_QUAD, plan=plan, duration_s=34.0, out_dir=tmp_path / "flight")
    assert f.fc_returncode == 0, f.fc_output
    px4 = f.fc_summary["px4"]
    assert px4["bad"] == {} and px4["clipped_ticks"] == 0 and px4["states"] == f.steps == 34 * 250 + 1
    truth = {round(t, 3): (x, y, z) for t, x, y, z in f.truth}  # rotorpy's own state: x east, y north, z up

    def at(t_s: float) -> tuple[float, float, float]:
        return truth[round(t_s, 3)]

    for t in (9.0, 10.0, 11.0, 11.996):  # settled after the take-off: (east, north, up) = (0, 0, 3)
        assert at(t) == pytest.approx((0.0, 0.0, 3.0), abs=0.1)
    for t in (22.0, 24.0, 25.996):  # settled at the set-point 2 m north, 1 m west, 4 m up
        assert at(t) == pytest.approx((-1.0, 2.0, 4.0), abs=0.1)
    assert at(33.996)[2] < 0.01  # on the ground
    log = load_log(f.tlog)
    m = log_metrics(log)
    assert m is not None and not m["crashed"] and m["max_tilt_deg"] < 20.0
    texts = [e.text for e in log.events]
    assert texts[-1].startswith("Landed"), texts


def _our_plant(tmp_path: Path, name: str, fault: MotorFault | None) -> Path:
    """The same flight on our rigid body: rotorpy's vehicle mapped, the FC at 250 Hz, in-process."""
    vehicle = vehicle_from_rotorpy(PX4_QUAD).to_toml().split("\n", 1)[1]
    text = f'name = "{name}"\nduration_s = 25.0\nseed = 0\n[fc]\nrate_hz = 250.0\n[vehicle]\n{vehicle}\n'
    text += '[[step]]\nt_s = 0.0\naction = "takeoff"\nalt_m = 3.0\n'
    if fault is not None:  # our rotor 1 is the right one, rotorpy's (PX4's) the front right: one rotor either way
        text += f'\n[[fault]]\nkind = "motor"\nstart_s = {fault.at_s}\nmotor = 1\nefficiency = {fault.efficiency}\n'
    scenario = tmp_path / f"{name}.toml"
    scenario.write_text(text, encoding="utf-8")
    out = tmp_path / name
    r = subprocess.run([sys.executable, "-m", "lab.cli", "run", str(scenario), "--out", str(out), "--no-plots"],
                       capture_output=True, text=True, timeout=600)  # fmt: skip
    assert r.returncode == 0, r.stdout + r.stderr
    return next(out.glob("*.tlog"))


@pytest.mark.slow
def test_fault_free_and_motor_loss_compare_with_our_plant(tmp_path: Path) -> None:
    plan = write_plan(tmp_path / "plan.toml", [{"t_s": 0.0, "action": "takeoff", "alt_m": 3.0}])
    fault = MotorFault(rotor=1, efficiency=0.7, at_s=10.0)
    metrics = {}
    for case, flt in (("clean", None), ("motor30", fault)):
        f = fly(PX4_QUAD, plan=plan, duration_s=25.0, out_dir=tmp_path / f"rotorpy-{case}", fault=flt)
        assert f.fc_returncode == 0, f.fc_output
        metrics[("rotorpy", case)] = log_metrics(load_log(f.tlog))
        metrics[("ours", case)] = log_metrics(load_log(_our_plant(tmp_path, f"ours-{case}", flt)))
    for key, m in metrics.items():
        assert m is not None and not m["crashed"], key
        assert m["max_tilt_deg"] < 10.0, (key, m["max_tilt_deg"])
    for case in ("clean", "motor30"):
        r, o = metrics[("rotorpy", case)], metrics[("ours", case)]
        assert r["iae_pos_m_s"] == pytest.approx(o["iae_pos_m_s"], rel=0.15), case
    r, o = metrics[("rotorpy", "motor30")], metrics[("ours", "motor30")]
    assert r["fault_start_s"] == pytest.approx(10.0, abs=0.01) and o["fault_start_s"] == pytest.approx(10.0, abs=0.01)
    assert r["recovered"] and o["recovered"]
    assert r["iae_att_rad_s"] == pytest.approx(o["iae_att_rad_s"], rel=0.4)
    # the fault costs each plant position error (it is felt), and about as much
    for plant in ("rotorpy", "ours"):
        assert metrics[(plant, "motor30")]["iae_pos_m_s"] > metrics[(plant, "clean")]["iae_pos_m_s"]
