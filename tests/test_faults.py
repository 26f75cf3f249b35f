"""Fault injection: the shared fault specs and SIM_* parameters (validation, round trips), the
simulator's fault models against analytic values, determinism, and live PARAM_SET over UDP."""

from __future__ import annotations

import math

import pytest

from smcpilot.faults import (
    FAULT_KINDS,
    SENSOR_FAULT_PARAM,
    SIM_PARAMS,
    FaultError,
    FaultSpec,
    check_sim_param,
    motor_efficiencies,
    sensor_fault_from_params,
    sim_param,
)
from smcpilot.scenario import ScenarioError


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
    with pytest.raises(FaultError, match=r"SIM_GYR_FAULT_V = -1.0 with noise: value \(noise std, rad/s\) must be >= 0"):
        sensor_fault_from_params("gyro", 3, -1.0)
    with pytest.raises(FaultError, match=r"SIM_POS_FAULT_V = 7.0 with delay"):
        sensor_fault_from_params("position", 5, 7.0)
