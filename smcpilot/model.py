"""The paper's quadrotor model, corrected (``docs/pid-smc.md`` §1): the one place its equations live.

Frame: the paper's inertial frame, z up. Euler angles phi (roll), theta (pitch), psi (yaw) in rad;
as in the paper, Euler-angle rates stand in for body rates (small-angle simplification).

Channel order everywhere is the paper's ``U = [u2, u3, u4, u1]`` (eq. 12):

====== ======= =========================================== ==========
index  channel input                                       unit
====== ======= =========================================== ==========
0      phi     u2 = Kp (w3^2 - w1^2), roll force difference  N (torque d u2)
1      theta   u3 = Kp (w4^2 - w2^2), pitch force difference N (torque d u3)
2      psi     u4 = Cd (w1^2 - w2^2 + w3^2 - w4^2)          N m
3      z       u1 = Kp (w1^2 + w2^2 + w3^2 + w4^2)          N
====== ======= =========================================== ==========

Dynamics per channel: ``x_k'' = f_k(X) + g_k(X) u_k + d_k`` with X = (phi, phi', theta, theta',
psi, psi', z, z'). The controller uses f and g as its nominal model; the simulator uses them as
the truth and adds disturbances d. Both build a :class:`PaperModel` from the same
:class:`~smcpilot.vehicle.VehicleParams`, so the equations exist once.

All methods take and return plain floats (they sit in the hot path). The equations the control
law and the paper's plant need (:func:`unmix`, :func:`mix`, :func:`actuation`, :func:`omega_bar`,
:func:`drift`, :func:`accelerations`, :func:`drift_rates`, :func:`horizontal_accelerations`,
:func:`tilt_cos`) are module-level pure functions of :meth:`PaperModel.consts`, a :class:`ModelConsts` NamedTuple of
floats and bools (what a compiled hot path takes); the methods of the same names call them, so the
equations exist once.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

from smcpilot.typos import MODEL_TYPOS, parse_typos
from smcpilot.vehicle import DEFAULT_VEHICLE, VehicleParams

CHANNELS: tuple[str, str, str, str] = ("phi", "theta", "psi", "z")
#: Unit of each channel's input u_k.
INPUT_UNITS: tuple[str, str, str, str] = ("N", "N", "N m", "N")
#: Unit of each channel's coordinate x_k.
STATE_UNITS: tuple[str, str, str, str] = ("rad", "rad", "rad", "m")

_sqrt = math.sqrt
_sin = math.sin
_cos = math.cos


class ModelConsts(NamedTuple):
    """The coefficients the control law reads, flattened (floats; the model typos as bools)."""

    mass_kg: float
    gravity_mps2: float
    thrust_coeff_n_s2: float
    drag_coeff_n_m_s2: float
    a1: float
    a2: float
    a3: float
    a4: float
    a5: float
    a6: float
    a7: float
    a8: float
    a9: float
    b1: float
    b2: float
    b3: float
    #: the "z-drift" typo (f_z = a9 z' psi') is reproduced.
    z_drift_typo: bool
    #: the "fdot" typo (f' as printed in eqs. 20/34) is reproduced.
    fdot_typo: bool


# -- the equations, as pure functions of ``m``, a ModelConsts ---------------------------------------
def unmix(m, u_phi: float, u_theta: float, u_psi: float, u_z: float) -> tuple[float, float, float, float]:
    """Inverse of eq. (11): inputs -> (w1^2, w2^2, w3^2, w4^2), (rad/s)^2.

    A result below zero means the command cannot be realised by any rotor speeds.
    """
    kp = m[2]  # thrust_coeff_n_s2
    t = u_z / kp
    y = u_psi / m[3]  # drag_coeff_n_m_s2
    r = u_phi / kp
    p = u_theta / kp
    q13 = 0.25 * (t + y)
    q24 = 0.25 * (t - y)
    return (q13 - 0.5 * r, q24 - 0.5 * p, q13 + 0.5 * r, q24 + 0.5 * p)


def omega_bar(w1_sq: float, w2_sq: float, w3_sq: float, w4_sq: float) -> float:
    """Net rotor speed w1 - w2 + w3 - w4 [rad/s] for the gyroscopic term (negatives clamp to 0)."""
    return (
        _sqrt(w1_sq if w1_sq > 0.0 else 0.0)
        - _sqrt(w2_sq if w2_sq > 0.0 else 0.0)
        + _sqrt(w3_sq if w3_sq > 0.0 else 0.0)
        - _sqrt(w4_sq if w4_sq > 0.0 else 0.0)
    )


def omega_bar_of_inputs(m, u_phi: float, u_theta: float, u_psi: float, u_z: float) -> float:
    """Omega-bar of the rotor speeds that realise the inputs."""
    w1, w2, w3, w4 = unmix(m, u_phi, u_theta, u_psi, u_z)
    return omega_bar(w1, w2, w3, w4)


def drift(m, phi_dot: float, theta_dot: float, psi_dot: float, z_dot: float, omega_bar: float) -> tuple[float, float, float, float]:
    """f = (f_phi, f_theta, f_psi, f_z): rad/s^2, rad/s^2, rad/s^2, m/s^2."""
    _mass, gravity, _kp, _cd, a1, a2, a3, a4, a5, a6, a7, a8, a9, _b1, _b2, _b3, z_drift_typo, _fdot_typo = m
    fz = a9 * z_dot * psi_dot if z_drift_typo else a9 * z_dot
    return (
        a1 * theta_dot * psi_dot + a2 * phi_dot * phi_dot + a3 * omega_bar * theta_dot,
        a4 * phi_dot * psi_dot + a5 * theta_dot * theta_dot + a6 * omega_bar * phi_dot,
        a7 * phi_dot * theta_dot + a8 * psi_dot * psi_dot,
        fz - gravity,
    )


def mix(m, w1_sq: float, w2_sq: float, w3_sq: float, w4_sq: float) -> tuple[float, float, float, float]:
    """Eq. (11): rotor speeds squared [(rad/s)^2] -> inputs (u_phi, u_theta, u_psi, u_z) = (u2, u3, u4, u1)."""
    kp = m[2]  # thrust_coeff_n_s2
    return (
        kp * (w3_sq - w1_sq),
        kp * (w4_sq - w2_sq),
        m[3] * (w1_sq - w2_sq + w3_sq - w4_sq),  # drag_coeff_n_m_s2
        kp * (w1_sq + w2_sq + w3_sq + w4_sq),
    )


def actuation(m, pitch_moment_typo: bool, w1_sq: float, w2_sq: float, w3_sq: float, w4_sq: float) -> tuple[float, float, float, float]:
    """Inputs that rotor speeds really produce: eq. (11), or with ``pitch_moment_typo`` eq. (7)'s
    printed pitch moment Kp (w4^2 - w1^2)."""
    u_phi, u_theta, u_psi, u_z = mix(m, w1_sq, w2_sq, w3_sq, w4_sq)
    if pitch_moment_typo:
        u_theta = m[2] * (w4_sq - w1_sq)
    return u_phi, u_theta, u_psi, u_z


def accelerations(
    m, phi: float, phi_dot: float, theta: float, theta_dot: float, psi_dot: float, z_dot: float,
    u_phi: float, u_theta: float, u_psi: float, u_z: float, omega_bar: float,
) -> tuple[float, float, float, float]:
    """Nominal accelerations f + g u (no disturbance): (phi'', theta'', psi'' [rad/s^2], z'' [m/s^2])."""
    f0, f1, f2, f3 = drift(m, phi_dot, theta_dot, psi_dot, z_dot, omega_bar)
    return (
        f0 + m[13] * u_phi,  # b1
        f1 + m[14] * u_theta,  # b2
        f2 + m[15] * u_psi,  # b3
        f3 + _cos(phi) * _cos(theta) / m[0] * u_z,  # mass_kg
    )  # fmt: skip


def horizontal_accelerations(
    mass: float, drag_x: float, drag_y: float, phi: float, theta: float, psi: float, x_dot: float, y_dot: float, u_z: float
) -> tuple[float, float]:
    """(x'', y'') [m/s^2] of eq. (10), z-up inertial frame (linear drags in N s/m)."""
    sp, cp = _sin(phi), _cos(phi)
    st = _sin(theta)
    ss, cs = _sin(psi), _cos(psi)
    return (
        (-drag_x * x_dot + (cp * st * cs + sp * ss) * u_z) / mass,
        (-drag_y * y_dot + (cp * st * ss - sp * cs) * u_z) / mass,
    )


def tilt_cos(phi: float, theta: float, floor: float) -> float:
    """cos(phi) cos(theta) kept at least ``floor`` away from zero (guards 1/g_z near 90 deg tilt)."""
    ctc = _cos(phi) * _cos(theta)
    if -floor < ctc < floor:
        return floor if ctc >= 0.0 else -floor
    return ctc


def drift_rates(
    m,
    phi: float,
    phi_dot: float,
    theta: float,
    theta_dot: float,
    psi_dot: float,
    z_dot: float,
    phi_dd: float,
    theta_dd: float,
    psi_dd: float,
    z_dd: float,
    omega_bar: float,
) -> tuple[float, float, float, float, float]:
    """(f_phi', f_theta', f_psi', f_z', g_z') with Omega-bar held constant over the step.

    The accelerations are inputs (the controller passes its nominal ``f + g u``).
    """
    mass, _g, _kp, _cd, a1, a2, a3, a4, a5, a6, a7, a8, a9, _b1, _b2, _b3, z_drift_typo, fdot_typo = m
    if fdot_typo:
        # As printed in eqs. (20)/(34): a1 x4' x6' + 2 a2 x2' x2 + a3 W x4', etc.
        fp = a1 * theta_dd * psi_dd + 2.0 * a2 * phi_dd * phi_dot + a3 * omega_bar * theta_dd
        ft = a4 * phi_dd * psi_dd + 2.0 * a5 * theta_dd * theta_dot + a6 * omega_bar * phi_dd
        fs = a7 * phi_dd * theta_dd + 2.0 * a8 * psi_dd * psi_dot
    else:
        fp = a1 * (theta_dd * psi_dot + theta_dot * psi_dd) + 2.0 * a2 * phi_dot * phi_dd + a3 * omega_bar * theta_dd
        ft = a4 * (phi_dd * psi_dot + phi_dot * psi_dd) + 2.0 * a5 * theta_dot * theta_dd + a6 * omega_bar * phi_dd
        fs = a7 * (phi_dd * theta_dot + phi_dot * theta_dd) + 2.0 * a8 * psi_dot * psi_dd
    if z_drift_typo:
        fz = a9 * (z_dd * psi_dot + z_dot * psi_dd)
    else:
        fz = a9 * z_dd
    sp, cp = _sin(phi), _cos(phi)
    st, ct = _sin(theta), _cos(theta)
    gz_dot = -(phi_dot * sp * ct + theta_dot * cp * st) / mass
    return fp, ft, fs, fz, gz_dot


@dataclass(frozen=True)
class PaperModel:
    """Coefficients of eqs. (10)-(14), derived once from a vehicle.

    Build with :meth:`from_vehicle`. ``typos`` holds the names (see :mod:`smcpilot.typos`) of the
    model typos to reproduce literally; the default is the corrected model.
    """

    mass_kg: float
    gravity_mps2: float
    arm_length_m: float
    thrust_coeff_n_s2: float
    drag_coeff_n_m_s2: float
    lin_drag_x_n_s_m: float
    lin_drag_y_n_s_m: float
    a1: float
    a2: float
    a3: float
    a4: float
    a5: float
    a6: float
    a7: float
    a8: float
    a9: float
    b1: float
    b2: float
    b3: float
    typos: frozenset[str] = frozenset()
    #: the coefficients the equations read, in :class:`ModelConsts` order (derived). An exact
    #: tuple: the functions unpack it on every call, and CPython does that fastest for exact tuples.
    _k: tuple[float | bool, ...] = field(default=(), init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        k = (*(float(getattr(self, f)) for f in ModelConsts._fields[:-2]), "z-drift" in self.typos, "fdot" in self.typos)
        object.__setattr__(self, "_k", k)

    def consts(self) -> ModelConsts:
        """The coefficients as a :class:`ModelConsts` of plain floats (what the pure functions take)."""
        return ModelConsts(*self._k)  # type: ignore[arg-type]  # _k holds exactly ModelConsts' fields

    @classmethod
    def from_vehicle(
        cls, vehicle: VehicleParams = DEFAULT_VEHICLE, typos: frozenset[str] | str | None = None
    ) -> PaperModel:
        ty = parse_typos(typos) & MODEL_TYPOS
        v = vehicle
        ix, iy, iz = v.ixx_kg_m2, v.iyy_kg_m2, v.izz_kg_m2
        b3 = v.drag_coeff_n_m_s2 / iz if "b3" in ty else 1.0 / iz
        return cls(
            mass_kg=v.mass_kg,
            gravity_mps2=v.gravity_mps2,
            arm_length_m=v.arm_length_m,
            thrust_coeff_n_s2=v.thrust_coeff_n_s2,
            drag_coeff_n_m_s2=v.drag_coeff_n_m_s2,
            lin_drag_x_n_s_m=v.lin_drag_x_n_s_m,
            lin_drag_y_n_s_m=v.lin_drag_y_n_s_m,
            a1=(iy - iz) / ix,
            a2=-v.rot_drag_x_n_m_s2 / ix,
            a3=-v.rotor_inertia_kg_m2 / ix,
            a4=(iz - ix) / iy,
            a5=-v.rot_drag_y_n_m_s2 / iy,
            a6=v.rotor_inertia_kg_m2 / iy,
            a7=(ix - iy) / iz,
            a8=-v.rot_drag_z_n_m_s2 / iz,
            a9=-v.lin_drag_z_n_s_m / v.mass_kg,
            b1=v.arm_length_m / ix,
            b2=v.arm_length_m / iy,
            b3=b3,
            typos=ty,
        )

    # -- eq. (11): mixer --------------------------------------------------------------------------
    def mix(self, w1_sq: float, w2_sq: float, w3_sq: float, w4_sq: float) -> tuple[float, float, float, float]:
        """Rotor speeds squared [(rad/s)^2] -> inputs (u_phi, u_theta, u_psi, u_z) = (u2, u3, u4, u1)."""
        return mix(self._k, w1_sq, w2_sq, w3_sq, w4_sq)

    def unmix(self, u_phi: float, u_theta: float, u_psi: float, u_z: float) -> tuple[float, float, float, float]:
        """Inverse of :meth:`mix`: inputs -> (w1^2, w2^2, w3^2, w4^2), (rad/s)^2 (:func:`unmix`).

        A result below zero means the command cannot be realised by any rotor speeds.
        """
        return unmix(self._k, u_phi, u_theta, u_psi, u_z)

    omega_bar = staticmethod(omega_bar)

    def omega_bar_of_inputs(self, u_phi: float, u_theta: float, u_psi: float, u_z: float) -> float:
        """Omega-bar of the rotor speeds that realise the inputs."""
        return omega_bar_of_inputs(self._k, u_phi, u_theta, u_psi, u_z)

    # -- eq. (13) with corrections: drift f and input gain g --------------------------------------
    def drift(
        self, phi_dot: float, theta_dot: float, psi_dot: float, z_dot: float, omega_bar: float
    ) -> tuple[float, float, float, float]:
        """f = (f_phi, f_theta, f_psi, f_z): rad/s^2, rad/s^2, rad/s^2, m/s^2 (:func:`drift`)."""
        return drift(self._k, phi_dot, theta_dot, psi_dot, z_dot, omega_bar)

    tilt_cos = staticmethod(tilt_cos)

    def gain_z(self, phi: float, theta: float) -> float:
        """g_z = cos(phi) cos(theta) / m, 1/kg. (g_phi = b1, g_theta = b2, g_psi = b3 are constants.)"""
        return _cos(phi) * _cos(theta) / self.mass_kg

    def gains(self, phi: float, theta: float) -> tuple[float, float, float, float]:
        """g = (b1 [1/(kg m)], b2 [1/(kg m)], b3 [1/(kg m^2)], g_z [1/kg])."""
        return (self.b1, self.b2, self.b3, _cos(phi) * _cos(theta) / self.mass_kg)

    def accelerations(
        self,
        phi: float,
        phi_dot: float,
        theta: float,
        theta_dot: float,
        psi_dot: float,
        z_dot: float,
        u_phi: float,
        u_theta: float,
        u_psi: float,
        u_z: float,
        omega_bar: float,
    ) -> tuple[float, float, float, float]:
        """Nominal accelerations f + g u (no disturbance): (phi'', theta'', psi'' [rad/s^2], z'' [m/s^2])
        (:func:`accelerations`)."""
        return accelerations(self._k, phi, phi_dot, theta, theta_dot, psi_dot, z_dot, u_phi, u_theta, u_psi, u_z, omega_bar)

    # -- time derivatives of f and g (spec §2; the paper's (20)/(27) drop half of each product) ---
    def drift_rates(
        self,
        phi: float,
        phi_dot: float,
        theta: float,
        theta_dot: float,
        psi_dot: float,
        z_dot: float,
        phi_dd: float,
        theta_dd: float,
        psi_dd: float,
        z_dd: float,
        omega_bar: float,
    ) -> tuple[float, float, float, float, float]:
        """(f_phi', f_theta', f_psi', f_z', g_z') with Omega-bar held constant (:func:`drift_rates`)."""
        return drift_rates(self._k, phi, phi_dot, theta, theta_dot, psi_dot, z_dot, phi_dd, theta_dd, psi_dd, z_dd, omega_bar)

    # -- physical actuation (plant side) ----------------------------------------------------------
    def actuation(
        self, w1_sq: float, w2_sq: float, w3_sq: float, w4_sq: float
    ) -> tuple[float, float, float, float]:
        """Inputs that rotor speeds really produce: eq. (11), or eq. (7)'s printed pitch moment.

        With the ``pitch-moment`` typo the pitch input is Kp (w4^2 - w1^2) instead of
        Kp (w4^2 - w2^2); otherwise this equals :meth:`mix`.
        """
        return actuation(self._k, "pitch-moment" in self.typos, w1_sq, w2_sq, w3_sq, w4_sq)

    def horizontal_accelerations(
        self, phi: float, theta: float, psi: float, x_dot: float, y_dot: float, u_z: float
    ) -> tuple[float, float]:
        """(x'', y'') [m/s^2] of eq. (10), z-up inertial frame (:func:`horizontal_accelerations`)."""
        return horizontal_accelerations(self.mass_kg, self.lin_drag_x_n_s_m, self.lin_drag_y_n_s_m, phi, theta, psi, x_dot, y_dot, u_z)

    def hover_inputs(self, phi: float = 0.0, theta: float = 0.0) -> tuple[float, float, float, float]:
        """Hover trim (0, 0, 0, m g / (cos phi cos theta)) in channel order."""
        return (0.0, 0.0, 0.0, self.mass_kg * self.gravity_mps2 / (_cos(phi) * _cos(theta)))

    @property
    def hover_omega_sq(self) -> float:
        """Rotor speed squared at level hover, (rad/s)^2."""
        return self.mass_kg * self.gravity_mps2 / (4.0 * self.thrust_coeff_n_s2)
