"""Fault injection: the shared fault specs and SIM_* parameters (validation, round trips), the
simulator's fault models against analytic values, determinism, and live PARAM_SET over UDP."""

from __future__ import annotations

import json
import math
import random
import subprocess
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink
from sitl_helpers import HANG_TIMEOUT_S, PYTHON, parse_datagram, udp_socket

from fc.params import config_for
from lab.run import fly
from lab.runner import fly as runner_fly
from lab.runner import state_of_wire, wire_values
from sim_bridge.build import plant_for
from sim_bridge.environment import Environment, EnvironmentParams
from sim_bridge.faults import SEVERITY_START, SEVERITY_STOP, SimFaults
from sim_bridge.plants.paper_vehicle import PaperVehiclePlant
from sim_bridge.plants.rigid_body import NOMINAL_INPUT, RigidBodyPlant, StepInput, rigid_body_step, rigid_body_targets
from sim_bridge.sensors import SensorNoiseParams, VehicleObservation
from smcpilot.actuators import commands_to_omega_sq
from smcpilot.faults import (
    FAULT_KINDS,
    SENSOR_FAULT_PARAM,
    SIM_PARAM_INDEX,
    SIM_PARAMS,
    FaultError,
    FaultSpec,
    check_sim_param,
    motor_efficiencies,
    sensor_fault_from_params,
    sim_param,
)
from smcpilot.frames import euler_flu_to_frd, nwu_to_ned, quat_from_euler, rates_flu_to_frd
from smcpilot.plan import PlanStep
from smcpilot.protocol import ACTUATOR_FLAG_LOCKSTEP, SIM_COMPONENT_ID
from smcpilot.scenario import EnvironmentSpec, Scenario, ScenarioError
from smcpilot.tlog import read_tlog
from smcpilot.vehicle import DEFAULT_VEHICLE


# -- the specs ---------------------------------------------------------------------------------------
def test_fault_error_is_a_scenario_error() -> None:
    assert issubclass(FaultError, ScenarioError)


@pytest.mark.parametrize(
    ("table", "message"),
    [
        ({"kind": "motor", "motor": 1, "efficiency": 1.5}, r"^fault\[2\] \(motor\): efficiency must lie in \[0, 1\], got 1.5$"),
        ({"kind": "motor", "motor": 5, "efficiency": 0.5}, r"^fault\[2\] \(motor\): motor must be 1..4"),
        ({"kind": "motor", "motor": 0}, r"^fault\[2\] \(motor\): motor must be 1..4"),
        ({"kind": "motor", "motor": 1.0}, r"^fault\[2\] \(motor\): motor must be a whole number"),
        ({"kind": "laser"}, r"^fault\[2\]: unknown kind 'laser' \(known: motor, sensor"),
        ({"start_s": 1.0}, r"^fault\[2\]: missing key 'kind'"),
        ({"kind": "force", "start_s": math.nan}, r"^fault\[2\] \(force\): start_s must be a finite number >= 0"),
        ({"kind": "force", "start_s": -1.0}, r"^fault\[2\] \(force\): start_s must be a finite number >= 0"),
        ({"kind": "force", "start_s": 2.0, "stop_s": math.nan}, r"^fault\[2\] \(force\): stop_s must be a number"),
        ({"kind": "force", "start_s": 2.0, "stop_s": 1.0}, r"^fault\[2\] \(force\): stop_s \(1.0\) must be after start_s \(2.0\)"),
        ({"kind": "sensor", "sensor": "lidar", "mode": "bias"}, r"^fault\[2\] \(sensor\): unknown sensor 'lidar'"),
        ({"kind": "sensor", "sensor": "gyro", "mode": "melt"}, r"^fault\[2\] \(sensor\): unknown mode 'melt'"),
        ({"kind": "sensor", "sensor": "gyro", "mode": "noise", "value": -1.0}, r"noise std, rad/s\) must be >= 0"),
        ({"kind": "sensor", "sensor": "gyro", "mode": "delay", "value": 9.0}, r"value \(delay\) must lie in \[0, 5\] s"),
        ({"kind": "sensor", "sensor": "gyro", "mode": "bias", "value": [1.0, 2.0]}, r"value must be one number or a list of 3"),
        ({"kind": "sensor", "sensor": "gyro", "mode": "bias", "value": [1.0, math.inf, 0.0]}, r"value must be 3 finite numbers"),
        ({"kind": "force", "force_ned_n": [1.0, 2.0, "x"]}, r"force_ned_n must be a list of 3 numbers"),
        ({"kind": "gust", "force_std_n": -0.1}, r"force_std_n must be a finite number >= 0 N"),
        ({"kind": "gust", "tau_s": 0.0}, r"tau_s must be a finite number > 0 s"),
        ({"kind": "motor", "motor": 1, "sensor": "gyro"}, r"unknown key 'sensor' \(it belongs to kind 'sensor'\)"),
        ({"kind": "motor", "motor": 1, "colour": 3}, r"unknown key 'colour'; known: kind, start_s, stop_s, motor, efficiency"),
    ],
)
def test_bad_fault_tables_name_the_item(table: dict, message: str) -> None:
    with pytest.raises(FaultError, match=message):
        FaultSpec.from_mapping(table, "fault[2]")


def test_spec_validates_on_construction_too() -> None:
    with pytest.raises(FaultError, match=r"^fault \(motor\): efficiency must lie in \[0, 1\], got -0.1$"):
        FaultSpec("motor", motor=1, efficiency=-0.1)
    with pytest.raises(FaultError, match="unknown kind"):
        FaultSpec("nope")


SPECS = [
    FaultSpec("motor", start_s=10.0, motor=1, efficiency=0.7),
    FaultSpec("motor", start_s=1.0, stop_s=2.5, motor=4, efficiency=0.0),
    FaultSpec("sensor", start_s=1.0, stop_s=2.0, sensor="gyro", mode="bias", value=(0.1, -0.2, 0.0)),
    FaultSpec("sensor", sensor="position", mode="dropout"),
    FaultSpec("sensor", sensor="velocity", mode="noise", value=(0.5, 0.5, 0.5)),
    FaultSpec("sensor", sensor="attitude", mode="delay", value=(0.1, 0.0, 0.0)),
    FaultSpec("sensor", sensor="accel", mode="stuck"),
    FaultSpec("force", start_s=3.0, force_ned_n=(1.0, -2.0, 0.5)),
    FaultSpec("torque", start_s=3.0, stop_s=4.0, torque_frd_n_m=(0.0, 0.0, 0.1)),
    FaultSpec("gust", force_std_n=0.5, torque_std_n_m=0.02, tau_s=2.0),
    FaultSpec("paper_disturbance", start_s=5.0),
]


@pytest.mark.parametrize("spec", SPECS, ids=lambda s: s.describe())
def test_mapping_round_trip(spec: FaultSpec) -> None:
    table = spec.to_mapping()
    assert set(table) <= {"kind", "start_s", "stop_s", *(k for k in table if k not in ("kind", "start_s", "stop_s"))}
    assert ("stop_s" in table) == math.isfinite(spec.stop_s)
    assert FaultSpec.from_mapping(table, "fault[1]") == spec
    assert len(spec.describe()) <= 50


def test_value_as_one_number_means_every_axis_and_stop_defaults_to_inf() -> None:
    s = FaultSpec.from_mapping({"kind": "sensor", "sensor": "gyro", "mode": "bias", "value": 0.25}, "f")
    assert s.value == (0.25, 0.25, 0.25)
    assert s.stop_s == math.inf
    assert s.active(1e9) and not FaultSpec("force", start_s=1.0).active(0.999)


def test_describe() -> None:
    assert FaultSpec("motor", motor=1, efficiency=0.7).describe() == "motor 1 at 70%"
    assert FaultSpec("motor", motor=1, efficiency=0.7).describe_stop() == "motor 1 ok"
    assert FaultSpec("motor", motor=3, efficiency=0.0).describe() == "motor 3 off"
    assert FaultSpec("sensor", sensor="gyro", mode="bias", value=(0.1, 0.1, 0.1)).describe() == "gyro bias 0.1 rad/s"
    assert FaultSpec("sensor", sensor="position", mode="dropout").describe() == "position dropout"
    assert FaultSpec("sensor", sensor="gyro", mode="delay", value=(0.1, 0, 0)).describe() == "gyro delay 0.1 s"
    assert {k for k in FAULT_KINDS} == {s.kind for s in SPECS}


# -- the SIM_* parameters ----------------------------------------------------------------------------
def test_sim_param_table() -> None:
    names = [p.name for p in SIM_PARAMS]
    assert names[:3] == ["SIM_ENGINE_MUL", "SIM_ENGINE_FAIL", "SIM_MOT_OFF"]
    for sensor, name in SENSOR_FAULT_PARAM.items():
        assert name in names and name + "_V" in names, sensor
    assert names[-9:] == ["SIM_DIST_FN", "SIM_DIST_FE", "SIM_DIST_FD", "SIM_DIST_TX", "SIM_DIST_TY", "SIM_DIST_TZ",
                          "SIM_GUST_F", "SIM_GUST_T", "SIM_PAPER_DIST"]  # fmt: skip
    assert len(names) == len(set(names)) == 3 + 10 + 9
    assert all(len(n) <= 16 for n in names)  # MAVLink param_id
    for p in SIM_PARAMS:
        assert p.lo <= p.default <= p.hi, p.name
    assert sim_param("SIM_ENGINE_MUL").default == 1.0


def test_check_sim_param() -> None:
    assert check_sim_param("SIM_ENGINE_MUL", 0.7) == 0.7
    assert check_sim_param("SIM_ENGINE_FAIL", 2.4) == 2.0
    assert check_sim_param("SIM_GYR_FAULT", 5) == 5.0
    with pytest.raises(FaultError, match=r"SIM_ENGINE_MUL out of range \[0, 1\]: 1.5"):
        check_sim_param("SIM_ENGINE_MUL", 1.5)
    with pytest.raises(FaultError, match=r"SIM_ENGINE_FAIL out of range \[0, 15\]: 16"):
        check_sim_param("SIM_ENGINE_FAIL", 16)
    with pytest.raises(FaultError, match="SIM_DIST_FN must be a finite number, got nan"):
        check_sim_param("SIM_DIST_FN", math.nan)
    with pytest.raises(FaultError, match="unknown simulator parameter 'SIM_NOPE'"):
        sim_param("SIM_NOPE")
    with pytest.raises(FaultError, match="unknown simulator parameter"):
        check_sim_param("SIM_NOPE", 1.0)


def test_param_helpers() -> None:
    assert motor_efficiencies(1.0, 0, 0) == (1.0, 1.0, 1.0, 1.0)
    assert motor_efficiencies(0.7, 0b0101, 0) == (0.7, 1.0, 0.7, 1.0)
    assert motor_efficiencies(0.7, 0b0001, 0b1001) == (0.0, 1.0, 1.0, 0.0)
    assert sensor_fault_from_params("gyro", 0, 1.0) is None
    assert sensor_fault_from_params("gyro", 2, 0.1) == FaultSpec("sensor", sensor="gyro", mode="bias", value=(0.1, 0.1, 0.1))
    assert sensor_fault_from_params("gyro", 5, 0.1).delay_s == 0.1  # type: ignore[union-attr]
    with pytest.raises(FaultError, match=r"^SIM_GYR_FAULT_V=-1: a noise std must be >= 0$"):
        sensor_fault_from_params("gyro", 3, -1.0)
    with pytest.raises(FaultError, match=r"^SIM_POS_FAULT_V=7: a delay must be 0..5 s$"):
        sensor_fault_from_params("position", 5, 7.0)


# -- the simulator's fault models, against analytic values ---------------------------------------------
V = DEFAULT_VEHICLE
H_S = 1e-6  # one tiny integration step: the state's change over it is h times the derivative at t


def hover_plant(faults: Sequence[FaultSpec] = (), *, z_m: float = 10.0, env: Environment | None = None) -> tuple[RigidBodyPlant, tuple[float, ...]]:
    """A rigid body in the air (no ground), level, at rest, its rotors already at the speed the
    hover command asks for (no lag transient); returns it and that command."""
    plant = RigidBodyPlant(V, env, ground_contact=False, faults=SimFaults(faults, seed=1))
    w_hover_sq = V.mass_kg * V.gravity_mps2 / (4.0 * V.thrust_coeff_n_s2)
    c = (w_hover_sq - V.rotor_speed_idle_radps**2) / (V.rotor_speed_max_radps**2 - V.rotor_speed_idle_radps**2)
    cmds = (c, c, c, c)
    w = rigid_body_targets(cmds, True, plant.params)
    plant.reset((0.0, 0.0, z_m), rotor_speeds_radps=w)
    return plant, cmds


def one_step(faults: Sequence[FaultSpec] = (), **kw) -> tuple[tuple[float, ...], tuple[float, ...], RigidBodyPlant]:
    """(state before, state after one H_S step from t = 0, plant)."""
    plant, cmds = hover_plant(faults, **kw)
    s0 = plant.state
    plant.step(0.0, H_S, cmds, True)
    return s0, plant.state, plant


def test_motor_at_70_percent_gives_the_analytic_roll_and_yaw_torque() -> None:
    s0, s1, plant = one_step([FaultSpec("motor", motor=1, efficiency=0.7)])
    w1 = s0[13]
    assert s0[13:17] == (w1,) * 4 and s1[13:17] == (w1,) * 4  # rotors in steady state
    # motor 1 (right) at 70 %: tau_x = d Kp (S3 - S1) = d Kp 0.3 w^2 (rolls right-side down, + about FLU x);
    # tau_y = 0; tau_z = Cd (S1 - S2 + S3 - S4) = -0.3 Cd w^2; thrust 3.7 Kp w^2.
    tau_x = V.arm_length_m * V.thrust_coeff_n_s2 * 0.3 * w1**2
    tau_z = -0.3 * V.drag_coeff_n_m_s2 * w1**2
    p_dot, q_dot, r_dot = (s1[10] - s0[10]) / H_S, (s1[11] - s0[11]) / H_S, (s1[12] - s0[12]) / H_S
    assert p_dot == pytest.approx(tau_x / V.ixx_kg_m2, rel=1e-6)
    assert abs(q_dot) < 1e-9
    assert r_dot == pytest.approx(tau_z / V.izz_kg_m2, rel=1e-6)
    az = (s1[5] - s0[5]) / H_S
    assert az == pytest.approx(3.7 * V.thrust_coeff_n_s2 * w1**2 / V.mass_kg - V.gravity_mps2, rel=1e-6)
    # the healthy vehicle in the same state: no torque, thrust = weight
    h0, h1, _ = one_step()
    assert h1[10:13] == (0.0, 0.0, 0.0)
    assert abs((h1[5] - h0[5]) / H_S) < 1e-9


@pytest.mark.parametrize("motor", [1, 2, 3, 4])
def test_motor_off_on_each_rotor(motor: int) -> None:
    s0, s1, _ = one_step([FaultSpec("motor", motor=motor, efficiency=0.0)])
    w_sq = s0[13] ** 2
    dkp = V.arm_length_m * V.thrust_coeff_n_s2 * w_sq
    # rotor: (tau_x, tau_y, tau_z) lost; 1 right, 2 front, 3 left, 4 rear; tau_x = dKp(S3 - S1), tau_y = dKp(S4 - S2)
    want = {1: (dkp, 0.0, -V.drag_coeff_n_m_s2 * w_sq), 2: (0.0, dkp, V.drag_coeff_n_m_s2 * w_sq),
            3: (-dkp, 0.0, -V.drag_coeff_n_m_s2 * w_sq), 4: (0.0, -dkp, V.drag_coeff_n_m_s2 * w_sq)}[motor]  # fmt: skip
    inertia = (V.ixx_kg_m2, V.iyy_kg_m2, V.izz_kg_m2)
    for i in range(3):
        got = (s1[10 + i] - s0[10 + i]) / H_S
        assert got == pytest.approx(want[i] / inertia[i], rel=1e-6, abs=1e-9), (motor, i)


def test_force_step_gives_exactly_f_over_m() -> None:
    f_ned = (1.0, -2.0, 0.5)
    s0, s1, plant = one_step([FaultSpec("force", force_ned_n=f_ned)])
    h0, h1, _ = one_step()
    f_nwu = (1.0, 2.0, -0.5)
    for i in range(3):
        dv = (s1[3 + i] - s0[3 + i]) - (h1[3 + i] - h0[3 + i])
        assert dv / H_S == pytest.approx(f_nwu[i] / V.mass_kg, rel=1e-6)
    assert plant.faults is not None and plant.faults.force_world_n == f_nwu


def test_torque_step_in_frd() -> None:
    s0, s1, _ = one_step([FaultSpec("torque", torque_frd_n_m=(0.01, 0.02, 0.03))])
    want_flu = (0.01 / V.ixx_kg_m2, -0.02 / V.iyy_kg_m2, -0.03 / V.izz_kg_m2)
    for i in range(3):
        assert (s1[10 + i] - s0[10 + i]) / H_S == pytest.approx(want_flu[i], rel=1e-6)


def test_paper_disturbance_fault_adds_the_papers_z_term() -> None:
    plant, cmds = hover_plant([FaultSpec("paper_disturbance", start_s=1.0)], z_m=10.0)
    ref, _ = hover_plant(z_m=10.0)
    for p in (plant, ref):
        p.reset((0.0, 0.0, 10.0), rotor_speeds_radps=p.state[13:17], t_s=1.0)
        p.step(1.0, H_S, cmds, True)
    dz_acc = (plant.state[5] - ref.state[5]) / H_S
    assert dz_acc == pytest.approx(0.1 * 10.0 * math.sin(1.0), rel=1e-6)


def test_faults_start_and_stop_on_the_physics_step() -> None:
    """A motor fault from 11 ms to 15 ms (physics 1 kHz, control 500 Hz: 11 ms is the second step of
    a control period): the flight equals the healthy one up to t = 11 ms, differs from there on."""
    spec = FaultSpec("motor", start_s=0.011, stop_s=0.015, motor=2, efficiency=0.5)
    faulty, cmds = hover_plant([spec])
    healthy, _ = hover_plant()
    t_us = 0
    diverged_at = None
    while t_us < 20_000:
        faulty.step(t_us * 1e-6, 0.002, cmds, True)  # one control period, two physics steps
        healthy.step(t_us * 1e-6, 0.002, cmds, True)
        t_us += 2000
        if diverged_at is None and faulty.state != healthy.state:
            diverged_at = t_us
    assert diverged_at == 12_000  # the period 10..12 ms holds the first faulty step (11..12 ms)
    # exactly one physics step faulty in it: the q rate after the period equals one step of the analytic torque
    f2, _ = hover_plant([spec])
    f2.step(0.0, 0.010, cmds, True)
    q_before = f2.state[11]
    f2.step(0.010, 0.001, cmds, True)
    assert f2.state[11] == q_before
    f2.step(0.011, 0.001, cmds, True)
    assert f2.state[11] != q_before
    ev = f2.faults.take_events()  # type: ignore[union-attr]
    assert [(round(e.t_s, 6), e.severity, e.text) for e in ev] == [(0.011, SEVERITY_START, "SIM: motor 2 at 50%")]
    f2.step(0.012, 0.004, cmds, True)  # steps at 12, 13, 14, 15 ms
    ev = f2.faults.take_events()  # type: ignore[union-attr]
    assert [(round(e.t_s, 6), e.severity, e.text) for e in ev] == [(0.015, SEVERITY_STOP, "SIM: motor 2 ok")]


def test_all_efficiencies_one_is_the_nominal_step_bit_for_bit() -> None:
    plant, cmds = hover_plant()
    s = plant.state
    p = plant.params
    a = rigid_body_step(s, cmds, True, (0.1, 0.2, 0.3), (0.01, 0.0, -0.01), 0.0, 0.001, p, NOMINAL_INPUT)
    b = rigid_body_step(s, cmds, True, (0.1, 0.2, 0.3), (0.01, 0.0, -0.01), 0.0, 0.001, p, StepInput((1.0, 1.0, 1.0, 1.0), False, 0.0))
    assert a == b
    # a plant with an idle SimFaults flies as one without
    with_faults, _ = hover_plant()
    without = RigidBodyPlant(V, ground_contact=False)
    without.reset((0.0, 0.0, 10.0), rotor_speeds_radps=with_faults.state[13:17])
    for k in range(50):
        c = (0.5 + 0.01 * math.sin(k), 0.5, 0.52, 0.49)
        with_faults.step(k * 0.002, 0.002, c, True)
        without.step(k * 0.002, 0.002, c, True)
    assert with_faults.state == without.state


def test_paper_yaw_disturbance_is_smooth_across_180_degrees() -> None:
    """Rotors off, yaw 3.1 rad turning left at 1 rad/s: the heading crosses +pi after ~0.04 s. The
    paper's yaw term 0.1 psi cos 2t must use the continuous heading (about +pi on both sides)."""
    env = Environment(EnvironmentParams(paper_disturbance=True))
    plant = RigidBodyPlant(V, env, ground_contact=False, faults=SimFaults())
    plant.reset((0.0, 0.0, 100.0), 3.1, body_rates_radps=(0.0, 0.0, 1.0))
    kaz = V.rot_drag_z_n_m_s2 / V.izz_kg_m2
    t = 0.0
    h = 0.001
    worst = 0.0
    for _ in range(100):
        r0 = plant.state[12]
        psi0 = plant.truth().euler_rad[2] + 2.0 * math.pi * plant.heading_turns
        plant.step(t, h, (0.0, 0.0, 0.0, 0.0), False)
        r_dot = (plant.state[12] - r0) / h
        want = 0.1 * psi0 * math.cos(2.0 * t) - kaz * r0 * abs(r0)
        worst = max(worst, abs(r_dot - want))
        t += h
    assert plant.heading_turns == 1
    assert plant.truth().euler_rad[2] < -3.0  # wrapped heading crossed to the negative side
    assert worst < 2e-3  # a sign flip would be 0.2 pi cos 2t ~ 0.63 rad/s^2


def observations(faults: Sequence[FaultSpec], n: int = 40, *, seed: int = 1, noise: bool = False) -> tuple[list, list]:
    """(faulty observations, truths) of a hovering-then-tilting flight, one per 2 ms control tick."""
    env = Environment(EnvironmentParams(sensor_noise=SensorNoiseParams(0.002, 0.01, 0.01, 0.02) if noise else SensorNoiseParams()),
                      random.Random(seed))  # fmt: skip
    plant, cmds = hover_plant(faults, env=env)
    obs, truth = [], []
    for k in range(n):
        obs.append(plant.observe())
        truth.append(plant.truth())
        c = (cmds[0] * 1.05, cmds[1], cmds[2] * 0.95, cmds[3] * 1.01)  # rolling and yawing, everything changes
        plant.step(k * 0.002, 0.002, c, True)
    return obs, truth


def test_gyro_bias_in_frd_shows_on_the_wire_rates_exactly() -> None:
    bias_frd = (0.1, -0.2, 0.3)
    obs, truth = observations([FaultSpec("sensor", start_s=0.02, sensor="gyro", mode="bias", value=bias_frd)])
    for k, (o, tr) in enumerate(zip(obs, truth)):
        w, w_true = wire_values(o), wire_values(tr)
        if k < 10:
            assert w == w_true
            continue
        p, q, r = rates_flu_to_frd(*tr.body_rates_radps)
        assert w[3:6] == tuple(np.float32(x) for x in (p + 0.1, q - 0.2, r + 0.3)), k
        assert w[:3] + w[6:] == w_true[:3] + w_true[6:]


def test_bias_on_every_other_sensor_in_its_wire_frame() -> None:
    v = (0.05, -0.1, 0.2)
    for sensor, sl, conv in (("attitude", slice(0, 3), lambda o: euler_flu_to_frd(*o.euler_rad)),
                             ("position", slice(6, 9), lambda o: nwu_to_ned(o.position_m)),
                             ("velocity", slice(9, 12), lambda o: nwu_to_ned(o.velocity_mps))):  # fmt: skip
        obs, truth = observations([FaultSpec("sensor", sensor=sensor, mode="bias", value=v)], n=5)
        for o, tr in zip(obs, truth):
            want = tuple(np.float32(a + b) for a, b in zip(conv(tr), v))
            assert wire_values(o)[sl] == want, sensor
    obs, truth = observations([FaultSpec("sensor", sensor="accel", mode="bias", value=v)], n=5)
    for o, tr in zip(obs, truth):
        assert nwu_to_ned(o.accel_mps2) == pytest.approx(tuple(a + b for a, b in zip(nwu_to_ned(tr.accel_mps2), v)), abs=1e-15)


def test_attitude_fault_keeps_the_quaternion_consistent() -> None:
    obs, _ = observations([FaultSpec("sensor", sensor="attitude", mode="bias", value=(0.1, 0.2, 0.3))], n=3)
    for o in obs:
        assert o.quaternion == quat_from_euler(*o.euler_rad)


def test_stuck_holds_the_value_at_fault_start_then_follows_again() -> None:
    obs, truth = observations([FaultSpec("sensor", start_s=0.02, stop_s=0.05, sensor="attitude", mode="stuck")])
    held = truth[10].euler_rad
    for k, (o, tr) in enumerate(zip(obs, truth)):
        if 10 <= k < 25:
            assert o.euler_rad == held, k
        else:
            assert o.euler_rad == tr.euler_rad, k
    assert truth[24].euler_rad != held  # it did move meanwhile


def test_delay_returns_the_value_from_exactly_n_ticks_ago() -> None:
    obs, truth = observations([FaultSpec("sensor", start_s=0.04, sensor="gyro", mode="delay", value=(0.01, 0.0, 0.0))], n=40)
    for k, (o, tr) in enumerate(zip(obs, truth)):
        want = truth[k - 5].body_rates_radps if k >= 20 else tr.body_rates_radps  # 10 ms = 5 ticks of 2 ms
        assert o.body_rates_radps == want, k
        assert o.euler_rad == tr.euler_rad


def test_delay_started_at_once_holds_the_oldest_value() -> None:
    obs, truth = observations([FaultSpec("sensor", sensor="position", mode="delay", value=(0.01, 0.0, 0.0))], n=12)
    assert [o.position_m for o in obs[:6]] == [truth[0].position_m] * 6
    assert [o.position_m for o in obs[6:]] == [t.position_m for t in truth[1:7]]


@pytest.mark.parametrize(("sensor", "wire_slice"), [("attitude", slice(0, 3)), ("gyro", slice(3, 6)), ("position", slice(6, 9)), ("velocity", slice(9, 12))])
def test_dropout_gives_nan_only_in_that_sensors_fields(sensor: str, wire_slice: slice) -> None:
    obs, truth = observations([FaultSpec("sensor", start_s=0.01, stop_s=0.02, sensor=sensor, mode="dropout")], n=15)
    for k, (o, tr) in enumerate(zip(obs, truth)):
        w, wt = wire_values(o), wire_values(tr)
        dropped = 5 <= k < 10
        for i in range(12):
            if dropped and wire_slice.start <= i < wire_slice.stop:
                assert math.isnan(w[i]), (k, i)
            else:
                assert w[i] == wt[i], (k, i)
        st = state_of_wire(w)  # NaN passes through: the state has NaN, no exception
        assert dropped == any(math.isnan(x) for x in st)


def test_noise_fault_has_its_std_and_its_own_stream() -> None:
    n = 400
    obs, truth = observations([FaultSpec("sensor", sensor="velocity", mode="noise", value=(0.5, 0.0, 0.2))], n=n)
    errs = [[o.velocity_mps[i] - t.velocity_mps[i] for o, t in zip(obs, truth)] for i in range(3)]
    assert np.std(errs[0]) == pytest.approx(0.5, rel=0.15)
    assert errs[1] == [0.0] * n
    assert np.std(errs[2]) == pytest.approx(0.2, rel=0.15)
    # the fault's noise does not draw from the environment's sensor-noise stream
    noisy_a, truth_a = observations([], n=30, noise=True)
    noisy_b, truth_b = observations([FaultSpec("sensor", sensor="velocity", mode="noise", value=(0.5, 0.5, 0.5))], n=30, noise=True)
    assert [o.position_m for o in noisy_a] == [o.position_m for o in noisy_b]
    assert [o.body_rates_radps for o in noisy_a] == [o.body_rates_radps for o in noisy_b]


def test_several_faults_on_one_sensor_apply_in_order() -> None:
    obs, truth = observations([FaultSpec("sensor", start_s=0.01, sensor="gyro", mode="stuck"),
                               FaultSpec("sensor", sensor="gyro", mode="bias", value=(0.1, 0.0, 0.0))], n=10)  # fmt: skip
    held = truth[5].body_rates_radps[0] + 0.1
    assert [o.body_rates_radps[0] for o in obs[5:]] == [held] * 5


# -- gusts and determinism ------------------------------------------------------------------------------
def fly_scenario(scenario: Scenario, n_ticks: int = 300, lift: float = 1.0) -> tuple[list[VehicleObservation], RigidBodyPlant]:
    """Observations of ``lift`` x the hover command held from the ground, one per 2 ms tick."""
    plant = plant_for(scenario)
    _, cmds = hover_plant()
    cmds = tuple(c * lift for c in cmds)
    out = []
    for k in range(n_ticks):
        out.append(plant.observe())
        plant.step(k * 0.002, 0.002, cmds, True)
    return out, plant  # type: ignore[return-value]


GUSTY = Scenario(duration_s=1.0, seed=7, environment=EnvironmentSpec(noise=True, gust_std_n=0.3),
                 faults=(FaultSpec("gust", start_s=0.1, force_std_n=0.5, torque_std_n_m=0.01),
                         FaultSpec("sensor", sensor="gyro", mode="noise", value=(0.05, 0.05, 0.05))))  # fmt: skip


def test_same_seed_same_faulty_flight_bit_for_bit() -> None:
    a, _ = fly_scenario(GUSTY)
    b, _ = fly_scenario(GUSTY)
    assert a == b
    c, _ = fly_scenario(GUSTY.with_changes(seed=8))
    assert a != c


def test_a_gust_fault_does_not_change_the_environments_streams() -> None:
    clean = GUSTY.with_changes(faults=())
    _, pa = fly_scenario(GUSTY)
    _, pb = fly_scenario(clean)
    assert pa.env._gust_rng.getstate() == pb.env._gust_rng.getstate()  # type: ignore[union-attr]
    assert pa.env.sensors._rng.getstate() == pb.env.sensors._rng.getstate()  # type: ignore[union-attr]
    # the environment's gust force is the same draw for draw
    ea = Environment(pa.env.params, random.Random(1))
    assert ea.force_world_n == Environment(pb.env.params, random.Random(1)).force_world_n


def test_gust_fault_is_gauss_markov_with_its_std() -> None:
    faults = SimFaults([FaultSpec("gust", force_std_n=0.5, torque_std_n_m=0.02, tau_s=0.05)], seed=3)
    fs, ts = [], []
    for k in range(200_00):
        faults.advance(k * 0.001, 0.001)
        fs.append(faults.force_world_n)
        ts.append(faults.torque_body_n_m)
    f = np.array(fs)
    t = np.array(ts)
    assert np.all(f[:, 2] == 0.0)  # horizontal only
    assert np.std(f[:, 0]) == pytest.approx(0.5, rel=0.1) and np.std(f[:, 1]) == pytest.approx(0.5, rel=0.1)
    assert np.std(t, axis=0) == pytest.approx([0.02] * 3, rel=0.1)
    lag = 50  # one correlation time: autocorrelation exp(-1)
    x = f[:, 0] - f[:, 0].mean()
    assert np.dot(x[:-lag], x[lag:]) / np.dot(x, x) == pytest.approx(math.exp(-1.0), abs=0.1)


def test_scenario_faults_fly_the_same_in_both_plants_builds() -> None:
    sc = Scenario(faults=(FaultSpec("motor", start_s=0.1, motor=1, efficiency=0.7),))
    a, pa = fly_scenario(sc, 100)
    b, pb = fly_scenario(sc, 100)
    assert a == b and pa.faults is not None and pa.faults.faults == sc.faults


def test_paper_plant_takes_motor_force_and_paper_disturbance_faults() -> None:
    base = Scenario(plant="paper")
    for faults in ((FaultSpec("motor", motor=1, efficiency=0.7),), (FaultSpec("force", force_ned_n=(1.0, 0.0, 0.0)),),
                   (FaultSpec("torque", torque_frd_n_m=(0.0, 0.0, 0.05)),), (FaultSpec("paper_disturbance"),)):  # fmt: skip
        a, _ = fly_scenario(base.with_changes(faults=faults), 200, lift=1.2)
        b, _ = fly_scenario(base, 200, lift=1.2)
        assert a[-1] != b[-1], faults
    # motor 1 at 70 %: the paper plant's roll acceleration is the same analytic torque / Ixx
    plant = plant_for(base.with_changes(faults=(FaultSpec("motor", motor=1, efficiency=0.7),)))
    assert isinstance(plant, PaperVehiclePlant)
    _, cmds = hover_plant()
    plant.reset((0.0, 0.0, 10.0))
    plant.step(0.0, H_S, cmds, True)
    w_sq = commands_to_omega_sq(cmds, V, True)[0]
    phi_dd = plant.state[1] / H_S
    assert phi_dd == pytest.approx(V.arm_length_m * V.thrust_coeff_n_s2 * 0.3 * w_sq / V.ixx_kg_m2, rel=1e-5)


# -- live parameters ------------------------------------------------------------------------------------
def test_live_parameters_start_and_stop_faults() -> None:
    f = SimFaults()
    assert f.set_param("SIM_ENGINE_MUL", 0.7, 1.0) == 0.7
    assert f.motor_eff == (1.0, 1.0, 1.0, 1.0) and f.take_events() == []  # no motor selected yet
    f.set_param("SIM_ENGINE_FAIL", 0b0101, 1.5)
    assert f.motor_eff == (0.7, 1.0, 0.7, 1.0)
    assert [(e.t_s, e.severity, e.text) for e in f.take_events()] == [
        (1.5, SEVERITY_START, "SIM: motor 1 at 70%"), (1.5, SEVERITY_START, "SIM: motor 3 at 70%")]
    f.set_param("SIM_MOT_OFF", 1, 2.0)
    assert f.motor_eff == (0.0, 1.0, 0.7, 1.0)
    assert [e.text for e in f.take_events()] == ["SIM: motor 1 off"]
    f.set_param("SIM_ENGINE_FAIL", 0, 2.5)
    f.set_param("SIM_MOT_OFF", 0, 2.5)
    assert f.motor_eff == (1.0, 1.0, 1.0, 1.0) and not f.physics_on
    assert [(e.severity, e.text) for e in f.take_events()] == [(SEVERITY_STOP, "SIM: motor 3 ok"), (SEVERITY_STOP, "SIM: motor 1 ok")]
    f.set_param("SIM_DIST_FN", 2.0, 3.0)
    assert f.force_world_n == (2.0, 0.0, 0.0) and f.physics_on
    f.set_param("SIM_DIST_TZ", 0.1, 3.0)
    assert f.torque_body_n_m == (0.0, 0.0, -0.1)
    f.set_param("SIM_PAPER_DIST", 1, 3.0)
    assert f.paper_disturbance
    f.set_param("SIM_GYR_FAULT_V", 0.1, 3.0)
    assert not f.sensing
    f.set_param("SIM_GYR_FAULT", 2, 3.0)
    assert f.sensing
    assert [e.text for e in f.take_events()] == ["SIM: force 2,0,0 N NED", "SIM: torque 0,0,0.1 Nm FRD", "SIM: paper disturbance",
                                                 "SIM: gyro bias 0.1 rad/s"]  # fmt: skip
    assert f.param_value("SIM_GYR_FAULT") == 2.0


def test_live_parameter_refusals_keep_the_old_value() -> None:
    f = SimFaults()
    with pytest.raises(FaultError, match="out of range"):
        f.set_param("SIM_ENGINE_MUL", 1.5, 0.0)
    assert f.param_value("SIM_ENGINE_MUL") == 1.0
    f.set_param("SIM_VEL_FAULT_V", -1.0, 0.0)  # fine as a bias
    with pytest.raises(FaultError, match="a noise std must be >= 0"):
        f.set_param("SIM_VEL_FAULT", 3, 0.0)
    assert f.param_value("SIM_VEL_FAULT") == 0.0 and not f.sensing
    with pytest.raises(FaultError, match="unknown simulator parameter"):
        f.set_param("SIM_NOPE", 1.0, 0.0)


def test_live_stuck_keeps_its_value_across_other_changes() -> None:
    obs, truth = observations([], n=1)
    f = SimFaults()
    f.set_param("SIM_ATT_FAULT", 1, 0.0)
    first = f.observe(obs[0]).euler_rad
    f.set_param("SIM_DIST_FN", 1.0, 0.01)  # another change re-evaluates the live faults
    moved = obs[0]._replace(t_s=0.002, euler_rad=(0.3, 0.2, 0.1))
    assert f.observe(moved).euler_rad == first


# -- live PARAM_SET over real UDP to a real simulator process, in lockstep -------------------------------
class FakeFc:
    """Plays the flight controller on the sim link: answers every state with disarmed actuator
    commands stamped with its time, and can put other messages before or after the answer."""

    def __init__(self) -> None:
        self.sock = udp_socket(HANG_TIMEOUT_S)
        self.port = self.sock.getsockname()[1]
        self.mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        self.sim_addr: tuple[str, int] | None = None
        #: every message from the simulator, in arrival order
        self.received: list[mavlink.MAVLink_message] = []
        #: the time of the last state returned, and how many re-sent copies of a state were skipped
        self.last_ms = -1
        self.resent = 0

    def next_state(self) -> tuple[mavlink.MAVLink_message, mavlink.MAVLink_message, list[mavlink.MAVLink_message]]:
        """(ATTITUDE, LOCAL_POSITION_NED, the other messages that came before them). A state the
        simulator re-sent because our answer was slow to come (a loaded machine) has the time of
        the one before: it is skipped, as the FC skips it, since that state was answered already."""
        others = []
        while True:
            data, addr = self.sock.recvfrom(65535)
            self.sim_addr = addr
            msgs = parse_datagram(data)
            kinds = [m.get_type() for m in msgs]
            if "ATTITUDE" in kinds and msgs[kinds.index("ATTITUDE")].time_boot_ms == self.last_ms:
                self.resent += 1
                continue
            self.received += msgs
            if "ATTITUDE" in kinds:
                self.last_ms = msgs[kinds.index("ATTITUDE")].time_boot_ms
                return msgs[kinds.index("ATTITUDE")], msgs[kinds.index("LOCAL_POSITION_NED")], others
            others += msgs

    def param_set(self, name: str, value: float) -> bytes:
        return bytes(self.mav.param_set_encode(1, SIM_COMPONENT_ID, name.encode(), value, mavlink.MAV_PARAM_TYPE_REAL32).pack(self.mav))

    def answer(self, t_ms: int, before: Sequence[bytes] = (), after: Sequence[bytes] = ()) -> None:
        act = self.mav.hil_actuator_controls_encode(t_ms * 1000, [0.0] * 16, 0, ACTUATOR_FLAG_LOCKSTEP).pack(self.mav)
        assert self.sim_addr is not None
        self.sock.sendto(b"".join([*before, bytes(act), *after]), self.sim_addr)


def _f32(x: float) -> float:
    return float(np.float32(x))


@pytest.mark.slow
def test_live_param_set_over_udp_to_the_simulator_process(tmp_path: Path) -> None:
    sc = Scenario(duration_s=0.2, faults=(FaultSpec("sensor", start_s=0.05, stop_s=0.1, sensor="velocity", mode="bias", value=(0.5, 0.0, 0.0)),))
    path = sc.save(tmp_path / "s.toml")
    fc = FakeFc()
    proc = subprocess.Popen([PYTHON, "-m", "sim_bridge", "--fc", f"udp:127.0.0.1:{fc.port}", "--lockstep", "--scenario", str(path),
                             "--duration", "0.2"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=tmp_path)  # fmt: skip
    try:
        states = {}
        between: dict[int, list] = {}
        for tick in range(101):
            att, pos, others = fc.next_state()
            t_ms = att.time_boot_ms
            assert t_ms == 2 * tick
            states[t_ms] = (att, pos)
            between[t_ms] = others
            if t_ms == 20:  # before the answer: acts on the period from 20 ms
                fc.answer(t_ms, before=[fc.param_set("SIM_GYR_FAULT_V", 0.1), fc.param_set("SIM_GYR_FAULT", 2),
                                        fc.param_set("SIM_ENGINE_MUL", 1.5)])  # fmt: skip
            elif t_ms == 30:  # after the answer in the same datagram: the state at 32 ms is sent first, so from 34 ms on
                fc.answer(t_ms, after=[fc.param_set("SIM_POS_FAULT", 4)])
            elif t_ms == 40:
                fc.answer(t_ms, before=[fc.param_set("SIM_POS_FAULT", 0), bytes(fc.mav.param_request_list_encode(1, SIM_COMPONENT_ID).pack(fc.mav))])
            else:
                fc.answer(t_ms)
        out, _ = proc.communicate(timeout=HANG_TIMEOUT_S)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        fc.sock.close()
    assert proc.returncode == 0, out
    # the bias: not in the state at 20 ms (already sent), in every one after; the vehicle rests (rates 0)
    assert (states[20][0].rollspeed, states[20][0].pitchspeed, states[20][0].yawspeed) == (0.0, 0.0, 0.0)
    for t_ms in range(22, 201, 2):
        a = states[t_ms][0]
        assert (a.rollspeed, a.pitchspeed, a.yawspeed) == (_f32(0.1),) * 3, t_ms
    # answered: PARAM_VALUE with the value in force, its index and the count; STATUSTEXT for the start and the refusal
    got = [(m.get_type(), m.param_id, m.param_value, m.param_index, m.param_count) if m.get_type() == "PARAM_VALUE" else
           (m.get_type(), m.severity, m.text) for m in between[22]]  # fmt: skip
    n = len(SIM_PARAMS)
    assert got == [
        ("PARAM_VALUE", "SIM_GYR_FAULT_V", _f32(0.1), SIM_PARAM_INDEX["SIM_GYR_FAULT_V"], n),
        ("PARAM_VALUE", "SIM_GYR_FAULT", 2.0, SIM_PARAM_INDEX["SIM_GYR_FAULT"], n),
        ("STATUSTEXT", mavlink.MAV_SEVERITY_WARNING, "SIM: gyro bias 0.1 rad/s"),
        ("PARAM_VALUE", "SIM_ENGINE_MUL", 1.0, 0, n),  # refused: the old value
        ("STATUSTEXT", mavlink.MAV_SEVERITY_ERROR, "SIM: SIM_ENGINE_MUL out of range [0, 1]: 1.5"),
    ]
    # position dropout set after the answer at 30 ms: applied at 32 ms, after that state went out; NaN only in x, y, z
    for t_ms in (30, 32, 34, 40, 42):
        pos = states[t_ms][1]
        dropped = 34 <= t_ms <= 40
        assert all(math.isnan(v) for v in (pos.x, pos.y, pos.z)) == dropped, t_ms
        assert all(math.isfinite(v) for v in (pos.vx, pos.vy, pos.vz))
        assert math.isfinite(states[t_ms][0].roll)
    assert [m.text for m in between[34] if m.get_type() == "STATUSTEXT"] == ["SIM: position dropout"]
    listed = [m for m in between[42] if m.get_type() == "PARAM_VALUE"]
    assert [m.param_id for m in listed] == ["SIM_POS_FAULT"] + [p.name for p in SIM_PARAMS]
    assert {m.param_id: m.param_value for m in listed[1:]}["SIM_GYR_FAULT"] == 2.0
    assert [(m.severity, m.text) for m in between[42] if m.get_type() == "STATUSTEXT"] == [(mavlink.MAV_SEVERITY_INFO, "SIM: position ok")]
    # the scenario's timed fault: announced right after the first state it acts on (50 ms) and the
    # first it no longer does (100 ms), the velocity biased in between
    texts = {t: [m.text for m in ms if m.get_type() == "STATUSTEXT"] for t, ms in between.items()}
    assert texts[52] == ["SIM: velocity bias 0.5,0,0 m/s"] and texts[102] == ["SIM: velocity ok"]
    assert [t for t, tx in texts.items() if tx] == [22, 34, 42, 52, 102]
    assert states[48][1].vx == 0.0 and states[50][1].vx == _f32(0.5) and states[98][1].vx == _f32(0.5) and states[100][1].vx == 0.0
    summary = json.loads(next(line for line in out.splitlines() if line.startswith("SIM_SUMMARY "))[len("SIM_SUMMARY "):])
    assert (summary["params_set"], summary["params_rejected"], summary["faults_started"], summary["faults_stopped"]) == (4, 1, 3, 2)
    assert summary["resends"] >= fc.resent  # every copy skipped was one the simulator counted


# -- the same faults in-process and as the two SITL processes ---------------------------------------------
def _sim_statustexts(tlog: Path) -> list[tuple[int, int, str]]:
    """(time_us, severity, text) of the simulator component's STATUSTEXT in a .tlog."""
    return [(t, m.severity, m.text) for t, m in read_tlog(tlog)
            if m.get_type() == "STATUSTEXT" and m.get_srcComponent() == SIM_COMPONENT_ID]  # fmt: skip


def _actuators(tlog: Path) -> list[tuple[int, tuple[float, ...]]]:
    return [(m.time_usec, tuple(m.controls[:4])) for _, m in read_tlog(tlog) if m.get_type() == "HIL_ACTUATOR_CONTROLS"]


@pytest.mark.slow
def test_faults_fly_the_same_in_process_and_as_sitl_and_are_logged(tmp_path: Path) -> None:
    faults = (
        FaultSpec("gust", start_s=1.0, force_std_n=0.2, torque_std_n_m=0.002),
        FaultSpec("motor", start_s=1.5, stop_s=2.5, motor=1, efficiency=0.9),
        FaultSpec("sensor", start_s=2.0, sensor="gyro", mode="bias", value=(0.01, 0.0, 0.0)),
        FaultSpec("torque", start_s=2.2, stop_s=2.4, torque_frd_n_m=(0.0, 0.0, 0.01)),
    )
    sc = Scenario(name="faulty", duration_s=3.0, seed=3, plan=(PlanStep(0.0, "takeoff", alt_m=2.0),), faults=faults)
    a = fly(sc, tmp_path / "inproc")
    b = fly(sc, tmp_path / "sitl", sitl=True)
    assert a.status == b.status == "ok", (a.message, b.message)
    assert Scenario.from_toml(b.tlog.with_name("faulty.scenario.toml")).faults == faults  # what both processes read
    ma, mb = _actuators(a.tlog), _actuators(b.tlog)
    assert len(ma) == sc.n_ticks and ma == mb  # bit for bit, tick for tick, faults and gust draws included
    clean = fly(sc.with_changes(faults=()), tmp_path / "clean")
    mc = _actuators(clean.tlog)
    first = next(i for i, (x, y) in enumerate(zip(ma, mc)) if x != y)
    assert ma[first][0] == 1_002_000  # the gust from 1.0 s moves the vehicle; the FC reacts at the next state
    want = [(1_000_000, mavlink.MAV_SEVERITY_WARNING, "SIM: gust 0.2 N 0.002 Nm tau 1 s"),
            (1_500_000, mavlink.MAV_SEVERITY_WARNING, "SIM: motor 1 at 90%"),
            (2_000_000, mavlink.MAV_SEVERITY_WARNING, "SIM: gyro bias 0.01,0,0 rad/s"),
            (2_200_000, mavlink.MAV_SEVERITY_WARNING, "SIM: torque 0,0,0.01 Nm FRD"),
            (2_400_000, mavlink.MAV_SEVERITY_INFO, "SIM: torque off"),
            (2_500_000, mavlink.MAV_SEVERITY_INFO, "SIM: motor 1 ok")]  # fmt: skip
    assert _sim_statustexts(a.tlog) == want
    assert [(sev, text) for _, sev, text in _sim_statustexts(b.tlog)] == [(sev, text) for _, sev, text in want]
    assert [e for e in a.events if e[1].startswith("SIM: ")] == [(round(t_us * 1e-6, 6), text) for t_us, _, text in want]


def test_in_process_runner_records_fault_events() -> None:
    sc = Scenario(duration_s=1.0, faults=(FaultSpec("force", start_s=0.5, stop_s=0.75, force_ned_n=(0.0, 0.0, -1.0)),))
    run = runner_fly(config_for(sc), sc.vehicle, plant_for(sc), (PlanStep(0.0, "takeoff", alt_m=1.0),), sc.duration_s, record_every=1)
    assert [e for e in run.events if e[1].startswith("SIM")] == [(0.5, "SIM: force 0,0,-1 N NED"), (0.75, "SIM: force off")]


def test_live_gust_change_takes_the_new_std() -> None:
    f = SimFaults(seed=2)
    f.set_param("SIM_GUST_F", 0.1, 0.0)
    f.set_param("SIM_GUST_T", 0.0, 0.0)  # unchanged: the same gust goes on, no announcement
    assert [e.text for e in f.take_events()] == ["SIM: gust 0.1 N 0 Nm tau 1 s"]
    f.set_param("SIM_GUST_F", 5.0, 1.0)
    assert [e.text for e in f.take_events()] == ["SIM: gust 5 N 0 Nm tau 1 s"]
    xs = []
    for k in range(20_000):
        f.advance(1.0 + k * 0.001, 0.001)
        xs.append(f.force_world_n[0])
    assert np.std(xs) == pytest.approx(5.0, rel=0.25)
    f.set_param("SIM_GUST_F", 0.0, 30.0)
    assert [(e.severity, e.text) for e in f.take_events()] == [(SEVERITY_STOP, "SIM: gust off")]
    f.advance(30.0, 0.001)
    assert f.force_world_n == (0.0, 0.0, 0.0) and not f.physics_on
