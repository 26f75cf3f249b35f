"""Frame conversions (smcpilot.frames): round trips, conventions, Euler-rate kinematics."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from smcpilot import frames as fr
from smcpilot.integrate import rk4_step

finite = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False, allow_infinity=False)
vec3 = st.tuples(finite, finite, finite)
angle = st.floats(min_value=-math.pi + 1e-9, max_value=math.pi - 1e-9)
# Pitch away from gimbal lock so the Euler triple is unique.
pitch = st.floats(min_value=-math.pi / 2 + 1e-3, max_value=math.pi / 2 - 1e-3)
any_angle = st.floats(min_value=-1e4, max_value=1e4, allow_nan=False)


def rot_x(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def rot_y(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rot_z(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def r_zyx(phi: float, theta: float, psi: float) -> np.ndarray:
    return rot_z(psi) @ rot_y(theta) @ rot_x(phi)


def quat_to_matrix(q: tuple[float, float, float, float]) -> np.ndarray:
    return np.array([fr.quat_rotate(q, e) for e in ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))]).T


def angle_close(a: float, b: float, tol: float = 1e-9) -> bool:
    return abs(fr.wrap_pi(a - b)) < tol


# -- NED <-> NWU, FRD <-> FLU ------------------------------------------------------------------------
@given(vec3)
def test_ned_nwu_round_trip(v: tuple[float, float, float]) -> None:
    assert fr.nwu_to_ned(fr.ned_to_nwu(v)) == v
    assert fr.flu_to_frd(fr.frd_to_flu(v)) == v


def test_ned_to_nwu_convention() -> None:
    # 1 m north, 2 m east, 3 m down = 1 m north, -2 m west, -3 m up.
    assert fr.ned_to_nwu((1.0, 2.0, 3.0)) == (1.0, -2.0, -3.0)
    assert fr.frd_to_flu((1.0, 2.0, 3.0)) == (1.0, -2.0, -3.0)
    assert fr.rates_frd_to_flu(0.1, 0.2, 0.3) == (0.1, -0.2, -0.3)
    assert fr.euler_frd_to_flu(0.1, 0.2, 0.3) == (0.1, -0.2, -0.3)


@given(angle, pitch, angle)
def test_euler_frd_flu_round_trip(phi: float, theta: float, psi: float) -> None:
    assert fr.euler_flu_to_frd(*fr.euler_frd_to_flu(phi, theta, psi)) == (phi, theta, psi)
    assert fr.rates_flu_to_frd(*fr.rates_frd_to_flu(phi, theta, psi)) == (phi, theta, psi)


@given(angle, pitch, angle)
def test_euler_frd_flu_is_conjugation_by_rx_pi(phi: float, theta: float, psi: float) -> None:
    """R_nwu(flu angles) == Rx(pi) R_ned(frd angles) Rx(pi)."""
    r_ned = r_zyx(phi, theta, psi)
    flip = rot_x(math.pi)
    expected = flip @ r_ned @ flip
    got = r_zyx(*fr.euler_frd_to_flu(phi, theta, psi))
    assert np.allclose(got, expected, atol=1e-12)


@given(angle, pitch, angle)
def test_quaternion_ned_nwu_conversion(phi: float, theta: float, psi: float) -> None:
    q_ned = fr.quat_from_euler(phi, theta, psi)
    q_nwu = fr.quat_ned_frd_to_nwu_flu(q_ned)
    assert fr.quat_nwu_flu_to_ned_frd(q_nwu) == q_ned
    e = fr.euler_from_quat(q_nwu)
    expected = fr.euler_frd_to_flu(phi, theta, psi)
    assert all(angle_close(a, b, 1e-7) for a, b in zip(e, expected))
    # a body FLU vector rotated to NWU equals the same vector via FRD and NED
    v_flu = (0.3, -1.2, 2.0)
    direct = fr.quat_rotate(q_nwu, v_flu)
    via_ned = fr.ned_to_nwu(fr.quat_rotate(q_ned, fr.flu_to_frd(v_flu)))
    assert np.allclose(direct, via_ned, atol=1e-12)


# -- quaternion <-> Euler --------------------------------------------------------------------------
@given(angle, pitch, angle)
def test_quaternion_matches_zyx_matrix(phi: float, theta: float, psi: float) -> None:
    q = fr.quat_from_euler(phi, theta, psi)
    assert math.isclose(sum(c * c for c in q), 1.0, rel_tol=1e-12)
    assert np.allclose(quat_to_matrix(q), r_zyx(phi, theta, psi), atol=1e-12)
    assert np.allclose(fr.rotation_matrix_from_euler(phi, theta, psi), r_zyx(phi, theta, psi), atol=1e-12)


@given(angle, pitch, angle)
def test_euler_quaternion_round_trip(phi: float, theta: float, psi: float) -> None:
    e = fr.euler_from_quat(fr.quat_from_euler(phi, theta, psi))
    assert angle_close(e[0], phi, 1e-7)
    assert abs(e[1] - theta) < 1e-7
    assert angle_close(e[2], psi, 1e-7)


@given(st.tuples(*[st.floats(min_value=-1.0, max_value=1.0)] * 4).filter(lambda q: sum(c * c for c in q) > 1e-3))
def test_quaternion_euler_round_trip_any_quaternion(q_raw: tuple[float, float, float, float]) -> None:
    """quaternion -> Euler -> quaternion gives the same rotation (even at gimbal lock)."""
    q = fr.quat_normalize(q_raw)
    q2 = fr.quat_from_euler(*fr.euler_from_quat(q))
    assert np.allclose(quat_to_matrix(q), quat_to_matrix(q2), atol=1e-6)


@given(angle, pitch, angle, vec3)
def test_rotate_and_inverse(phi: float, theta: float, psi: float, v: tuple[float, float, float]) -> None:
    q = fr.quat_from_euler(phi, theta, psi)
    back = fr.quat_rotate_inverse(q, fr.quat_rotate(q, v))
    assert np.allclose(back, v, rtol=1e-9, atol=1e-6)
    assert np.allclose(fr.quat_rotate(q, v), r_zyx(phi, theta, psi) @ np.array(v), rtol=1e-9, atol=1e-6)


def test_quat_multiply_composes_rotations() -> None:
    a = fr.quat_from_euler(0.3, -0.2, 1.0)
    b = fr.quat_from_euler(-0.7, 0.4, -2.0)
    v = (1.0, 2.0, -0.5)
    assert np.allclose(fr.quat_rotate(fr.quat_multiply(a, b), v), fr.quat_rotate(a, fr.quat_rotate(b, v)))
    assert np.allclose(fr.quat_multiply(a, fr.quat_conjugate(a)), (1.0, 0.0, 0.0, 0.0))


def test_thrust_axis_convention() -> None:
    """Positive roll tilts body +z (thrust) toward world -y; positive pitch toward world +x."""
    up_roll = fr.quat_rotate(fr.quat_from_euler(0.1, 0.0, 0.0), (0.0, 0.0, 1.0))
    up_pitch = fr.quat_rotate(fr.quat_from_euler(0.0, 0.1, 0.0), (0.0, 0.0, 1.0))
    assert up_roll[1] < 0.0 and abs(up_roll[0]) < 1e-15
    assert up_pitch[0] > 0.0 and abs(up_pitch[1]) < 1e-15


# -- body rates <-> Euler rates --------------------------------------------------------------------
@given(angle, pitch, finite, finite, finite)
def test_rate_conversions_are_inverse(phi: float, theta: float, a: float, b: float, c: float) -> None:
    e = fr.body_rates_to_euler_rates(phi, theta, a, b, c)
    back = fr.euler_rates_to_body_rates(phi, theta, *e)
    scale = 1.0 + abs(a) + abs(b) + abs(c)
    # error grows like 1/cos(theta) near the singularity
    assert np.allclose(back, (a, b, c), atol=1e-9 * scale / math.cos(theta) ** 2)


def _body_rates(t: float) -> tuple[float, float, float]:
    return (0.8 * math.sin(1.3 * t) + 0.2, 0.6 * math.cos(0.7 * t), -0.9 + 0.5 * math.sin(2.1 * t))


def test_euler_rates_match_finite_differences_along_rotating_body() -> None:
    """Integrate q' = q (0, w)/2 for known body rates; d/dt of the Euler angles (central
    differences) equals body_rates_to_euler_rates, and euler_rates_to_body_rates inverts it."""

    def qdot(t: float, q: list[float]) -> list[float]:
        p, qq, r = _body_rates(t)
        d = fr.quat_multiply(tuple(q), (0.0, p, qq, r))
        return [0.5 * c for c in d]

    h = 1e-4
    q = list(fr.quat_from_euler(0.4, -0.3, 2.5))
    t = 0.0
    samples: list[tuple[float, tuple[float, float, float]]] = []
    for _ in range(30000):  # 3 s
        samples.append((t, fr.euler_from_quat(tuple(q))))
        q = rk4_step(qdot, t, q, h)
        t += h
    checked = 0
    for i in range(100, len(samples) - 1, 1000):
        t_i, (phi, theta, _psi) = samples[i]
        prev = samples[i - 1][1]
        nxt = samples[i + 1][1]
        fd = tuple(fr.wrap_pi(b - a) / (2 * h) for a, b in zip(prev, nxt))
        model = fr.body_rates_to_euler_rates(phi, theta, *_body_rates(t_i))
        assert np.allclose(fd, model, atol=1e-6), (t_i, fd, model)
        assert np.allclose(fr.euler_rates_to_body_rates(phi, theta, *fd), _body_rates(t_i), atol=1e-6)
        checked += 1
    assert checked >= 25


def test_euler_rates_singularity_guard() -> None:
    out = fr.body_rates_to_euler_rates(0.2, math.pi / 2, 0.1, 0.2, 0.3)
    assert all(math.isfinite(v) for v in out)
    out = fr.body_rates_to_euler_rates(0.2, -math.pi / 2, 0.1, 0.2, 0.3)
    assert all(math.isfinite(v) for v in out)


# -- wrap_pi -----------------------------------------------------------------------------------------
@given(any_angle)
def test_wrap_pi_range_and_equivalence(a: float) -> None:
    w = fr.wrap_pi(a)
    assert -math.pi <= w < math.pi
    assert math.isclose(math.sin(w), math.sin(a), abs_tol=1e-9)
    assert math.isclose(math.cos(w), math.cos(a), abs_tol=1e-9)
    assert fr.wrap_pi(w) == w


@given(st.floats(min_value=-math.pi, max_value=math.pi, exclude_max=True))
def test_wrap_pi_identity_inside(a: float) -> None:
    assert fr.wrap_pi(a) == a


@pytest.mark.parametrize(
    "a, expected",
    [
        (math.pi, -math.pi),
        (-math.pi, -math.pi),
        (3 * math.pi, -math.pi),
        (2 * math.pi, 0.0),
        (-1e-20, -1e-20),
        # (a + pi) % 2pi rounds up to exactly 2 pi here
        (math.nextafter(-math.pi, -math.inf), -math.pi),
    ],
)
def test_wrap_pi_edges(a: float, expected: float) -> None:
    assert fr.wrap_pi(a) == pytest.approx(expected, abs=1e-12)
    assert -math.pi <= fr.wrap_pi(a) < math.pi


@settings(max_examples=200)
@given(st.floats(min_value=-1e-12, max_value=0.0).map(lambda x: x - 2 * math.pi))
def test_wrap_pi_rounding_edge(a: float) -> None:
    assert -math.pi <= fr.wrap_pi(a) < math.pi


def test_wrap_pi_nan() -> None:
    assert math.isnan(fr.wrap_pi(float("nan")))
