"""Motor-command mapping (smcpilot.actuators): thrust-linear above idle, clamped, NaN-safe."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from smcpilot import actuators as act
from smcpilot.model import PaperModel
from smcpilot.vehicle import DEFAULT_VEHICLE, VehicleParams

V = DEFAULT_VEHICLE
IDLE_SQ = V.rotor_speed_idle_radps**2
MAX_SQ = V.rotor_speed_max_radps**2
unit = st.floats(min_value=0.0, max_value=1.0)


def test_endpoints() -> None:
    assert act.command_to_omega_sq(0.0, V) == pytest.approx(IDLE_SQ)
    assert act.command_to_omega_sq(1.0, V) == pytest.approx(MAX_SQ)
    assert act.command_to_omega_radps(1.0, V) == pytest.approx(V.rotor_speed_max_radps)
    assert act.command_to_omega_radps(0.0, V) == pytest.approx(V.rotor_speed_idle_radps)


def test_thrust_is_linear_in_command() -> None:
    kp = V.thrust_coeff_n_s2
    thrusts = [kp * act.command_to_omega_sq(c, V) for c in (0.0, 0.25, 0.5, 0.75, 1.0)]
    steps = [b - a for a, b in zip(thrusts, thrusts[1:])]
    assert all(s == pytest.approx(steps[0], rel=1e-12) for s in steps)


@given(unit)
def test_round_trip_command(c: float) -> None:
    assert act.omega_sq_to_command(act.command_to_omega_sq(c, V), V) == pytest.approx(c, abs=1e-12)


@given(st.floats(min_value=IDLE_SQ, max_value=MAX_SQ))
def test_round_trip_omega_sq(w_sq: float) -> None:
    assert act.command_to_omega_sq(act.omega_sq_to_command(w_sq, V), V) == pytest.approx(w_sq, rel=1e-12)


@given(st.floats(allow_nan=True, allow_infinity=True))
def test_command_always_maps_into_range(c: float) -> None:
    w_sq = act.command_to_omega_sq(c, V)
    assert IDLE_SQ <= w_sq <= MAX_SQ * (1 + 1e-15)
    assert 0.0 <= act.sanitize_command(c) <= 1.0


@pytest.mark.parametrize(
    "c, expected",
    [(-0.5, 0.0), (1.5, 1.0), (float("nan"), 0.0), (float("inf"), 1.0), (float("-inf"), 0.0), (0.3, 0.3)],
)
def test_sanitize(c: float, expected: float) -> None:
    assert act.sanitize_command(c) == expected


@pytest.mark.parametrize("w_sq, expected", [(0.0, 0.0), (-5.0, 0.0), (1e9, 1.0), (float("nan"), 0.0)])
def test_omega_sq_to_command_clamps(w_sq: float, expected: float) -> None:
    assert act.omega_sq_to_command(w_sq, V) == expected


def test_vector_helpers() -> None:
    cmds = (0.0, 0.5, 1.0, float("nan"))
    w = act.commands_to_omega_sq(cmds, V)
    assert w == pytest.approx((IDLE_SQ, 0.5 * (IDLE_SQ + MAX_SQ), MAX_SQ, IDLE_SQ))
    assert act.commands_to_omega_sq(cmds, V, armed=False) == (0.0, 0.0, 0.0, 0.0)
    assert act.omega_sq_to_commands(w, V) == pytest.approx((0.0, 0.5, 1.0, 0.0))
    assert all(
        act.commands_to_omega_sq(cmds, V)[i] == act.command_to_omega_sq(cmds[i], V) for i in range(4)
    )


@pytest.mark.parametrize(
    "vehicle",
    [
        V,
        VehicleParams(mass_kg=1.5, thrust_coeff_n_s2=1.2e-5, rotor_speed_max_radps=783.0, rotor_speed_idle_radps=150.0),
    ],
)
def test_hover_command_gives_weight(vehicle: VehicleParams) -> None:
    c = act.hover_command(vehicle)
    assert 0.0 < c < 1.0
    w_sq = act.commands_to_omega_sq((c, c, c, c), vehicle)
    u = PaperModel.from_vehicle(vehicle).mix(*w_sq)
    assert u[3] == pytest.approx(vehicle.weight_n, rel=1e-12)
    assert u[:3] == pytest.approx((0.0, 0.0, 0.0), abs=1e-15)


def test_default_vehicle_hover_margin() -> None:
    """Thrust/weight = 2 means hover sits a bit under half of the thrust-linear command range."""
    c = act.hover_command(V)
    assert math.isclose(c, (V.hover_omega_sq - IDLE_SQ) / (MAX_SQ - IDLE_SQ))
    assert 0.4 < c < 0.5
