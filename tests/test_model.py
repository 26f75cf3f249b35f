"""The paper model (smcpilot.model): mixer, drift and its time derivatives, typo switches, hover trim."""

from __future__ import annotations

import math
import sys

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from smcpilot.errors import ConfigError
from smcpilot.model import PaperModel
from smcpilot.typos import CONTROLLER_TYPOS, MODEL_TYPOS, TYPOS
from smcpilot.vehicle import DEFAULT_VEHICLE, VehicleParams

EPS = sys.float_info.epsilon
MODEL = PaperModel.from_vehicle()


def _f(lo: float, hi: float):
    return st.floats(min_value=lo, max_value=hi, allow_nan=False, allow_infinity=False)


@st.composite
def vehicles(draw):
    """Random plausible vehicles, so every coefficient a1..a9 is exercised (the default has a7 = 0)."""
    return VehicleParams(
        name="random",
        mass_kg=draw(_f(0.2, 5.0)),
        arm_length_m=draw(_f(0.05, 0.6)),
        thrust_coeff_n_s2=draw(_f(1e-6, 1e-4)),
        drag_coeff_n_m_s2=draw(_f(1e-8, 1e-5)),
        ixx_kg_m2=draw(_f(1e-3, 5e-2)),
        iyy_kg_m2=draw(_f(1e-3, 5e-2)),
        izz_kg_m2=draw(_f(1e-3, 8e-2)),
        rot_drag_x_n_m_s2=draw(_f(0.0, 2e-3)),
        rot_drag_y_n_m_s2=draw(_f(0.0, 2e-3)),
        rot_drag_z_n_m_s2=draw(_f(0.0, 2e-3)),
        lin_drag_z_n_s_m=draw(_f(0.0, 0.5)),
        rotor_inertia_kg_m2=draw(_f(0.0, 1e-4)),
    )


models = vehicles().map(PaperModel.from_vehicle)


# -- mixer (eq. 11) -----------------------------------------------------------------------------


@settings(max_examples=100, deadline=None)
@given(model=models, w=st.tuples(*[_f(0.0, 1.0e6)] * 4))
def test_unmix_of_mix_is_identity(model, w):
    back = model.unmix(*model.mix(*w))
    scale = max(w) + 1.0
    for a, b in zip(back, w):
        assert a == pytest.approx(b, abs=1e-9 * scale)


@settings(max_examples=100, deadline=None)
@given(
    model=models,
    u=st.tuples(_f(-5.0, 5.0), _f(-5.0, 5.0), _f(-0.5, 0.5), _f(0.0, 60.0)),
)
def test_mix_of_unmix_is_identity(model, u):
    back = model.mix(*model.unmix(*u))
    # rounding of the intermediate w^2 (size ~ u / Kp or u / Cd) scaled back by Kp or Cd
    w_scale = max(abs(x) for x in model.unmix(*u)) + 1.0
    for k, (a, b) in enumerate(zip(back, u)):
        coeff = model.drag_coeff_n_m_s2 if k == 2 else model.thrust_coeff_n_s2
        assert a == pytest.approx(b, abs=64 * EPS * w_scale * coeff * 4 + 1e-15)


def test_mixer_matches_eq_11_by_hand():
    kp, cd = MODEL.thrust_coeff_n_s2, MODEL.drag_coeff_n_m_s2
    w = (1.0e4, 2.0e4, 3.0e4, 5.0e4)
    u_phi, u_theta, u_psi, u_z = MODEL.mix(*w)
    assert u_phi == pytest.approx(kp * (3.0e4 - 1.0e4))
    assert u_theta == pytest.approx(kp * (5.0e4 - 2.0e4))
    assert u_psi == pytest.approx(cd * (1.0e4 - 2.0e4 + 3.0e4 - 5.0e4))
    assert u_z == pytest.approx(kp * 11.0e4)


def test_omega_bar_signs_and_clamp():
    assert MODEL.omega_bar(100.0**2, 90.0**2, 80.0**2, 70.0**2) == pytest.approx(100 - 90 + 80 - 70)
    # negative w^2 (not realisable) count as zero speed
    assert MODEL.omega_bar(-5.0, 0.0, 16.0, 0.0) == pytest.approx(4.0)
    assert MODEL.omega_bar_of_inputs(*MODEL.hover_inputs()) == pytest.approx(0.0, abs=1e-9)


# -- drift rates against finite differences along the nominal motion ----------------------------

H = 1e-5  # finite-difference step along the motion, s


def _motion_point(model, x, h):
    """(phi, theta, rates...) advanced by h along the nominal motion: angles with their rates, rates
    with the nominal accelerations f + g u; Omega-bar held constant."""
    phi, phi_d, th, th_d, psi_d, z_d, u, wbar = x
    a = model.accelerations(phi, phi_d, th, th_d, psi_d, z_d, *u, wbar)
    return (phi + h * phi_d, th + h * th_d, phi_d + h * a[0], th_d + h * a[1], psi_d + h * a[2], z_d + h * a[3]), a


def _observed(model, x, h):
    (phi, th, phi_d, th_d, psi_d, z_d), _ = _motion_point(model, x, h)
    return model.drift(phi_d, th_d, psi_d, z_d, x[7]) + (model.gain_z(phi, th),)


def _central_difference(model, x):
    plus = _observed(model, x, H)
    minus = _observed(model, x, -H)
    fd = tuple((p - m) / (2 * H) for p, m in zip(plus, minus))
    # rounding bound of each difference quotient
    rnd = tuple(8 * EPS * (abs(p) + abs(m)) / (2 * H) for p, m in zip(plus, minus))
    return fd, rnd


def _analytic(model, x):
    phi, phi_d, th, th_d, psi_d, z_d, u, wbar = x
    _, a = _motion_point(model, x, 0.0)
    return model.drift_rates(phi, phi_d, th, th_d, psi_d, z_d, *a, wbar), a


states = st.tuples(
    _f(-1.2, 1.2),  # phi
    _f(-5.0, 5.0),  # phi_dot
    _f(-1.2, 1.2),  # theta
    _f(-5.0, 5.0),  # theta_dot
    _f(-5.0, 5.0),  # psi_dot
    _f(-5.0, 5.0),  # z_dot
    st.tuples(_f(-2.0, 2.0), _f(-2.0, 2.0), _f(-0.2, 0.2), _f(0.0, 40.0)),  # u
    _f(-400.0, 400.0),  # Omega-bar
)


def _scales(model, x, a):
    """Size of the terms of each product rule, to make the tolerance relative."""
    phi, phi_d, th, th_d, psi_d, z_d, u, wbar = x
    return (
        abs(model.a1) * (abs(a[1] * psi_d) + abs(th_d * a[2])) + 2 * abs(model.a2 * phi_d * a[0]) + abs(model.a3 * wbar * a[1]),
        abs(model.a4) * (abs(a[0] * psi_d) + abs(phi_d * a[2])) + 2 * abs(model.a5 * th_d * a[1]) + abs(model.a6 * wbar * a[0]),
        abs(model.a7) * (abs(a[0] * th_d) + abs(phi_d * a[1])) + 2 * abs(model.a8 * psi_d * a[2]),
        abs(model.a9 * a[3]),
        (abs(phi_d) + abs(th_d)) / model.mass_kg,
    )


@settings(max_examples=150, deadline=None)
@given(model=models, x=states)
def test_drift_rates_match_finite_differences(model, x):
    analytic, a = _analytic(model, x)
    fd, rnd = _central_difference(model, x)
    scales = _scales(model, x, a)
    # f is quadratic in the rates, so along a straight line its central difference is exact up to
    # rounding; g_z = cos(phi) cos(theta)/m adds the truncation h^2/6 |g'''| <= h^2 (|phi'|+|theta'|)^3/(6m).
    trunc = (0.0, 0.0, 0.0, 0.0, H * H * (abs(x[1]) + abs(x[3])) ** 3 / (6 * model.mass_kg))
    names = ("f_phi'", "f_theta'", "f_psi'", "f_z'", "g_z'")
    for k in range(5):
        tol = 1e-9 * scales[k] + rnd[k] + trunc[k] + 1e-12
        assert abs(analytic[k] - fd[k]) <= tol, (names[k], analytic[k], fd[k], tol)


@settings(max_examples=50, deadline=None)
@given(model=vehicles().map(lambda v: PaperModel.from_vehicle(v, "z-drift")), x=states)
def test_z_drift_typo_rates_are_the_derivative_of_the_printed_drift(model, x):
    """The typo'd model is at least self-consistent: its f_z' is the derivative of its f_z."""
    analytic, a = _analytic(model, x)
    fd, rnd = _central_difference(model, x)
    scale = abs(model.a9) * (abs(a[3] * x[4]) + abs(x[5] * a[2]))
    assert abs(analytic[3] - fd[3]) <= 1e-9 * scale + rnd[3] + 1e-12


# Fixed states for the typo comparisons (generic: no rate or acceleration zero).
TYPO_STATES = [
    (0.9, -0.9, 0.75, -1.0, -0.1, -0.1, (0.05, -0.03, 0.01, 6.0), 150.0),
    (-0.3, 2.0, 0.2, 1.5, 0.8, 0.4, (-0.2, 0.1, -0.02, 4.0), -80.0),
]


@pytest.mark.parametrize("x", TYPO_STATES)
def test_literal_fdot_disagrees_with_finite_differences(x):
    """The printed eqs. (20)/(34) drop half of each product rule: their f' is not the derivative of f."""
    vehicle = VehicleParams(ixx_kg_m2=3.0e-3, iyy_kg_m2=4.5e-3)  # Ix != Iy so a7 != 0 and psi shows it too
    right = PaperModel.from_vehicle(vehicle)
    literal = PaperModel.from_vehicle(vehicle, "fdot")
    fd, rnd = _central_difference(right, x)
    good, _ = _analytic(right, x)
    bad, _ = _analytic(literal, x)
    for k in range(3):  # phi, theta, psi
        assert abs(good[k] - fd[k]) <= 1e-6 * abs(fd[k]) + rnd[k] + 1e-12
        assert abs(bad[k] - fd[k]) > 0.1 * abs(fd[k]), k
    # f_z' and g_z' are not affected by this typo
    assert bad[3:] == good[3:]


def test_literal_fdot_disagrees_for_default_vehicle_phi_theta():
    """With the spec's vehicle (Ix = Iy, a7 = 0) the typo shows in phi and theta, not psi."""
    literal = PaperModel.from_vehicle(DEFAULT_VEHICLE, "fdot")
    x = TYPO_STATES[0]
    fd, _ = _central_difference(MODEL, x)
    bad, _ = _analytic(literal, x)
    assert abs(bad[0] - fd[0]) > 0.1 * abs(fd[0])
    assert abs(bad[1] - fd[1]) > 0.1 * abs(fd[1])
    assert bad[2] == pytest.approx(fd[2], rel=1e-6)


# -- typo switches ------------------------------------------------------------------------------


def test_b3_corrected_and_literal():
    v = DEFAULT_VEHICLE
    assert MODEL.b3 == pytest.approx(1.0 / v.izz_kg_m2, rel=1e-15)
    literal = PaperModel.from_vehicle(v, "b3")
    assert literal.b3 == pytest.approx(v.drag_coeff_n_m_s2 / v.izz_kg_m2, rel=1e-15)
    # Cd counted twice: the literal gain is Cd ~ 3e-7 times the right one
    assert literal.b3 / MODEL.b3 == pytest.approx(v.drag_coeff_n_m_s2, rel=1e-12)
    # nothing else changes
    assert (literal.b1, literal.b2, literal.a1, literal.a9) == (MODEL.b1, MODEL.b2, MODEL.a1, MODEL.a9)


def test_other_gains_and_coefficients_from_the_spec():
    v = DEFAULT_VEHICLE
    ix, iy, iz = v.ixx_kg_m2, v.iyy_kg_m2, v.izz_kg_m2
    assert MODEL.b1 == pytest.approx(v.arm_length_m / ix)
    assert MODEL.b2 == pytest.approx(v.arm_length_m / iy)
    assert MODEL.a1 == pytest.approx((iy - iz) / ix)
    assert MODEL.a3 == pytest.approx(-v.rotor_inertia_kg_m2 / ix)
    assert MODEL.a6 == pytest.approx(v.rotor_inertia_kg_m2 / iy)
    assert MODEL.a8 == pytest.approx(-v.rot_drag_z_n_m_s2 / iz)
    assert MODEL.a9 == pytest.approx(-v.lin_drag_z_n_s_m / v.mass_kg)


@settings(max_examples=50, deadline=None)
@given(rates=st.tuples(*[_f(-10.0, 10.0)] * 4), wbar=_f(-400.0, 400.0))
def test_z_drift_typo_changes_f_z_exactly_as_printed(rates, wbar):
    literal = PaperModel.from_vehicle(DEFAULT_VEHICLE, "z-drift")
    phi_d, th_d, psi_d, z_d = rates
    f_right = MODEL.drift(phi_d, th_d, psi_d, z_d, wbar)
    f_lit = literal.drift(phi_d, th_d, psi_d, z_d, wbar)
    assert f_right[3] == pytest.approx(MODEL.a9 * z_d - MODEL.gravity_mps2, rel=1e-14, abs=1e-14)
    assert f_lit[3] == pytest.approx(MODEL.a9 * z_d * psi_d - MODEL.gravity_mps2, rel=1e-14, abs=1e-14)
    assert f_lit[:3] == f_right[:3]


def test_z_drift_typo_visible():
    literal = PaperModel.from_vehicle(DEFAULT_VEHICLE, "z-drift")
    assert literal.drift(0.0, 0.0, 2.0, 3.0, 0.0)[3] != MODEL.drift(0.0, 0.0, 2.0, 3.0, 0.0)[3]


@settings(max_examples=60, deadline=None)
@given(w=st.tuples(*[_f(0.0, 1.0e5)] * 4))
def test_pitch_moment_typo_changes_actuation(w):
    literal = PaperModel.from_vehicle(DEFAULT_VEHICLE, "pitch-moment")
    kp = MODEL.thrust_coeff_n_s2
    right = MODEL.actuation(*w)
    lit = literal.actuation(*w)
    assert right == MODEL.mix(*w)  # corrected actuation is the mixer
    assert lit[1] == pytest.approx(kp * (w[3] - w[0]), rel=1e-12, abs=1e-15)
    assert right[1] == pytest.approx(kp * (w[3] - w[1]), rel=1e-12, abs=1e-15)
    assert (lit[0], lit[2], lit[3]) == (right[0], right[2], right[3])
    # the mixer itself (what the controller inverts) is not changed by the typo
    assert literal.mix(*w) == MODEL.mix(*w)


def test_pitch_moment_typo_visible():
    literal = PaperModel.from_vehicle(DEFAULT_VEHICLE, "pitch-moment")
    w = (1.0e4, 2.0e4, 3.0e4, 4.0e4)
    assert literal.actuation(*w)[1] != pytest.approx(MODEL.actuation(*w)[1])


def test_controller_typos_do_not_reach_the_model():
    m = PaperModel.from_vehicle(DEFAULT_VEHICLE, ",".join(sorted(CONTROLLER_TYPOS)))
    assert m.typos == frozenset()
    assert m == MODEL
    assert PaperModel.from_vehicle(DEFAULT_VEHICLE, "all").typos == MODEL_TYPOS
    assert MODEL_TYPOS | CONTROLLER_TYPOS == frozenset(TYPOS)


def test_unknown_typo_name_raises():
    with pytest.raises(ConfigError, match="nope"):
        PaperModel.from_vehicle(DEFAULT_VEHICLE, "b3,nope")


# -- hover --------------------------------------------------------------------------------------


def test_hover_inputs_give_zero_nominal_acceleration_at_level_hover():
    u = MODEL.hover_inputs()
    assert u[:3] == (0.0, 0.0, 0.0)
    assert u[3] == pytest.approx(DEFAULT_VEHICLE.mass_kg * DEFAULT_VEHICLE.gravity_mps2)
    wbar = MODEL.omega_bar_of_inputs(*u)
    acc = MODEL.accelerations(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, *u, wbar)
    assert acc == pytest.approx((0.0, 0.0, 0.0, 0.0), abs=1e-12)
    # all four rotors at the hover speed
    for w_sq in MODEL.unmix(*u):
        assert w_sq == pytest.approx(MODEL.hover_omega_sq, rel=1e-12)
    assert MODEL.hover_omega_sq == pytest.approx(DEFAULT_VEHICLE.hover_omega_sq, rel=1e-15)


@settings(max_examples=50, deadline=None)
@given(model=models, phi=_f(-1.3, 1.3), theta=_f(-1.3, 1.3))
def test_tilted_hover_trim_cancels_gravity(model, phi, theta):
    u = model.hover_inputs(phi, theta)
    acc = model.accelerations(phi, 0.0, theta, 0.0, 0.0, 0.0, *u, 0.0)
    assert acc[3] == pytest.approx(0.0, abs=1e-12 * u[3] / model.mass_kg + 1e-12)


def test_hover_is_not_trivially_zero():
    """Half the hover thrust leaves the vehicle falling at g/2: the check above can fail."""
    u = MODEL.hover_inputs()
    acc = MODEL.accelerations(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.5 * u[3], 0.0)
    assert acc[3] == pytest.approx(-0.5 * DEFAULT_VEHICLE.gravity_mps2)


def test_horizontal_accelerations_level_thrust_is_vertical():
    ax, ay = MODEL.horizontal_accelerations(0.0, 0.0, 1.0, 0.0, 0.0, 10.0)
    assert (ax, ay) == pytest.approx((0.0, 0.0), abs=1e-15)
    # pitch forward (theta > 0) with psi = 0 accelerates along +x
    ax, ay = MODEL.horizontal_accelerations(0.0, 0.3, 0.0, 0.0, 0.0, 10.0)
    assert ax == pytest.approx(math.sin(0.3) * 10.0 / DEFAULT_VEHICLE.mass_kg)
    assert ay == pytest.approx(0.0, abs=1e-15)
