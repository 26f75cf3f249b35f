"""Geometric tracking control on SE(3) (Lee, Leok & McClamroch, CDC 2010) as a whole-stack law.

T. Lee, M. Leok, N. H. McClamroch, "Geometric tracking control of a quadrotor UAV on SE(3)",
49th IEEE Conference on Decision and Control, 2010, pp. 5420-5425 (arXiv:1003.2005). The law
replaces the position loop and the attitude stage (``stage = "full"``): from the prefiltered
position set-point (x_d and three derivatives, psi_d and three derivatives) to the total thrust f
and the body moment M, which become the paper model's inputs u. Equations, tuning and what is
tested: ``docs/geometric-control.md``.

Frames: the project's paper frame, world NWU (z **up**) and body FLU, ``R = Rz(psi) Ry(theta)
Rx(phi)`` body -> world, thrust along +b3. Lee writes z down with the thrust along -b3; in z up
the same law reads (gains per unit mass and per unit inertia, ``e_x = x - x_d``, ``e_v = v - v_d``)::

    A    = m (-kx e_x - kv e_v - ki int e_x + x_d'' + g e3)      desired force (tilt/accel limited)
    f    = A . R e3                                              total thrust
    b3_d = A / |A|,  b1_d = (cos psi_d, sin psi_d, 0)
    b2_d = b3_d x b1_d / |b3_d x b1_d|,  R_d = [b2_d x b3_d, b2_d, b3_d]
    e_R  = 1/2 vee(R_d^T R - R^T R_d),   e_W = W - R^T R_d W_d
    M    = J (-kR e_R - kW e_W - kI int e_R) + W x J W - J (hat(W) R^T R_d W_d - R^T R_d W_d')

with W the body rates (from the Euler-angle rates the FC measures, ZYX kinematics) and W_d, W_d'
from R_d's first two time derivatives computed analytically from the reference's derivatives
(x_d''' and psi_d', psi_d''; the reference's snap is not available and is taken as zero, and the
feedback terms' derivatives are left out: the feed-forward of differential flatness).
The integral terms (``ki`` on position, ``kI`` on attitude, the latter after Goodarzi, Lee & Leok,
ECC 2013, integrating e_R alone) are additions to the 2010 law; with their gains 0 the law is exactly Lee's.

Inputs: ``u = (M_x / l, M_y / l, M_z, f)`` -- the plant's roll torque is ``l u_phi`` about body
+x, its pitch torque ``l u_theta`` about body +y, its yaw torque ``u_psi`` about body +z
(:mod:`sim_bridge.plants.rigid_body`), so the conversion has no sign changes.

The three functions the pipeline calls (:func:`geo_initial_state`, :func:`geo_step`,
:func:`geo_anti_windup`) and everything they call are pure (tuples and floats, module-level, no
method calls): :data:`GEOMETRIC_FUNCTIONS` lists them for the compilability checks.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

from fc.control.law import STAGE_FULL, Law, LawContext, param
from smcpilot.errors import InvalidGainError

_sin = math.sin
_cos = math.cos
_sqrt = math.sqrt
_asin = math.asin
_atan2 = math.atan2
_INF = math.inf
#: the desired force keeps at least this fraction of the weight along e3 (a demand to fall faster
#: than g is flown as a near free fall, level, not as an inverted vehicle).
_AZ_MIN_FRAC = 0.1
#: smallest |b3_d x b1_d| used as a divisor (only reached near 90 deg tilt, which the tilt limit excludes).
_CROSS_MIN = 1.0e-6
_ZERO3 = (0.0, 0.0, 0.0)
_ZERO4 = (0.0, 0.0, 0.0, 0.0)

Vec3 = tuple[float, float, float]
Mat3 = tuple[float, float, float, float, float, float, float, float, float]
Vec4 = tuple[float, float, float, float]
State6 = tuple[float, float, float, float, float, float]


# -- parameters ------------------------------------------------------------------------------------
@dataclass(frozen=True)
class GeometricParams:
    """Gains and limits of the geometric law (MAVLink ``GEO_*``). Translational gains are Lee's
    divided by the mass, rotational ones divided by the axis' moment of inertia (so the defaults
    carry over to another vehicle with the same bandwidths). Defaults: docs/geometric-control.md."""

    kx_xy: float = param(3.0, lo=0.0, hi=50.0, unit="1/s^2", doc="horizontal position gain kx/m (a per m of error)")
    kx_z: float = param(12.0, lo=0.0, hi=100.0, unit="1/s^2", doc="vertical position gain kx/m")
    kv_xy: float = param(2.5, lo=0.0, hi=50.0, unit="1/s", doc="horizontal velocity gain kv/m")
    kv_z: float = param(5.0, lo=0.0, hi=50.0, unit="1/s", doc="vertical velocity gain kv/m")
    ki_xy: float = param(1.0, lo=0.0, hi=20.0, unit="1/s^3", doc="horizontal position integral gain (0: Lee's law)")
    ki_z: float = param(4.0, lo=0.0, hi=20.0, unit="1/s^3", doc="vertical position integral gain (0: Lee's law)")
    imax_xy: float = param(5.0, lo=0.0, hi=20.0, unit="m/s^2", doc="largest horizontal integral term |ki int e_x|")
    imax_z: float = param(5.0, lo=0.0, hi=20.0, unit="m/s^2", doc="largest vertical integral term |ki int e_z|")
    acc_max: float = param(5.0, lo=0.5, hi=30.0, unit="m/s^2", doc="largest horizontal acceleration demand (norm)")
    tilt_max: float = param(0.6, lo=0.05, hi=1.4, unit="rad", doc="largest angle between the desired thrust b3_d and up")
    kr_rp: float = param(126.0, lo=0.0, hi=2000.0, unit="1/s^2", doc="roll/pitch attitude gain kR/J")
    kr_yaw: float = param(32.0, lo=0.0, hi=2000.0, unit="1/s^2", doc="yaw attitude gain kR/J (the yaw weighting)")
    kw_rp: float = param(40.0, lo=0.0, hi=200.0, unit="1/s", doc="roll/pitch angular-rate gain kW/J")
    kw_yaw: float = param(8.0, lo=0.0, hi=200.0, unit="1/s", doc="yaw angular-rate gain kW/J")
    kir_rp: float = param(60.0, lo=0.0, hi=2000.0, unit="1/s^3", doc="roll/pitch attitude integral gain (0: Lee's law)")
    kir_yaw: float = param(8.0, lo=0.0, hi=2000.0, unit="1/s^3", doc="yaw attitude integral gain (0: Lee's law)")
    imaxr_rp: float = param(50.0, lo=0.0, hi=500.0, unit="rad/s^2", doc="largest roll/pitch integral term |kI int e_R|")
    imaxr_yaw: float = param(5.0, lo=0.0, hi=500.0, unit="rad/s^2", doc="largest yaw integral term |kI int e_R|")
    ff: int = param(1, lo=0, hi=1, is_int=True, doc="1: feed W_d and W_d' forward (from the reference's jerk and yaw rate/accel); 0: W_d = W_d' = 0")

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            meta = f.metadata["smcpilot"]
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not meta["lo"] <= v <= meta["hi"]:
                raise InvalidGainError(f"se3_geometric parameter {f.name} must be a number in [{meta['lo']:g}, {meta['hi']:g}], got {v!r}")


class GeometricConsts(NamedTuple):
    """:class:`GeometricParams` and the vehicle, flattened (floats and 3-tuples of floats)."""

    mass_kg: float
    gravity_mps2: float
    arm_m: float
    #: principal moments of inertia (body x, y, z), kg m^2.
    inertia: Vec3
    #: translational gains per unit mass (x, y, z): 1/s^2, 1/s, 1/s^3.
    kx: Vec3
    kv: Vec3
    ki: Vec3
    #: the position integrators' own limits, imax / ki (inf without an I gain), m s.
    int_lim: Vec3
    acc_max: float
    tan_tilt_max: float
    #: rotational gains per unit inertia (body x, y, z): 1/s^2, 1/s, 1/s^3.
    kr: Vec3
    kw: Vec3
    kir: Vec3
    #: the attitude integrators' own limits, imaxr / kir (inf without an I gain), rad s.
    int_lim_r: Vec3
    #: 1.0: W_d, W_d' fed forward; 0.0: not.
    ff: float


def _lim(imax: float, ki: float) -> float:
    return imax / ki if ki > 0.0 else _INF


def geometric_consts(ctx: LawContext, p: GeometricParams) -> GeometricConsts:
    """Flatten the parameters with the vehicle's mass, inertia, arm and gravity (once)."""
    v = ctx.vehicle
    return GeometricConsts(
        float(v.mass_kg), float(v.gravity_mps2), float(v.arm_length_m),
        (float(v.ixx_kg_m2), float(v.iyy_kg_m2), float(v.izz_kg_m2)),
        (float(p.kx_xy), float(p.kx_xy), float(p.kx_z)),
        (float(p.kv_xy), float(p.kv_xy), float(p.kv_z)),
        (float(p.ki_xy), float(p.ki_xy), float(p.ki_z)),
        (_lim(p.imax_xy, p.ki_xy), _lim(p.imax_xy, p.ki_xy), _lim(p.imax_z, p.ki_z)),
        float(p.acc_max), math.tan(p.tilt_max),
        (float(p.kr_rp), float(p.kr_rp), float(p.kr_yaw)),
        (float(p.kw_rp), float(p.kw_rp), float(p.kw_yaw)),
        (float(p.kir_rp), float(p.kir_rp), float(p.kir_yaw)),
        (_lim(p.imaxr_rp, p.kir_rp), _lim(p.imaxr_rp, p.kir_rp), _lim(p.imaxr_yaw, p.kir_yaw)),
        1.0 if p.ff else 0.0,
    )  # fmt: skip


# -- small vector algebra (pure) ---------------------------------------------------------------------
def geo_dot(a: Sequence[float], b: Sequence[float]) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def geo_cross(a: Sequence[float], b: Sequence[float]) -> Vec3:
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def geo_axpy(s: float, a: Sequence[float], b: Sequence[float]) -> Vec3:
    """s a + b."""
    return (s * a[0] + b[0], s * a[1] + b[1], s * a[2] + b[2])


def geo_unit_d2(v: Sequence[float], v1: Sequence[float], v2: Sequence[float], n_min: float) -> tuple[Vec3, Vec3, Vec3]:
    """(u, u', u'') of u = v / |v| given v, v' and v'' (|v| held at least ``n_min``)."""
    n = _sqrt(geo_dot(v, v))
    if n < n_min:
        n = n_min
    inv = 1.0 / n
    u = (v[0] * inv, v[1] * inv, v[2] * inv)
    s1 = geo_dot(u, v1)
    u1 = ((v1[0] - s1 * u[0]) * inv, (v1[1] - s1 * u[1]) * inv, (v1[2] - s1 * u[2]) * inv)
    c = geo_dot(u1, v1) + geo_dot(u, v2)
    # P = v' - (u.v') u,  P' = v'' - (u'.v' + u.v'') u - (u.v') u',  u'' = (P' - (u.v') u') / |v|
    u2 = (
        (v2[0] - c * u[0] - 2.0 * s1 * u1[0]) * inv,
        (v2[1] - c * u[1] - 2.0 * s1 * u1[1]) * inv,
        (v2[2] - c * u[2] - 2.0 * s1 * u1[2]) * inv,
    )
    return u, u1, u2


def geo_rotation_zyx(phi: float, theta: float, psi: float) -> Mat3:
    """R = Rz(psi) Ry(theta) Rx(phi), body -> world, row-major 9-tuple."""
    sp, cp = _sin(phi), _cos(phi)
    st, ct = _sin(theta), _cos(theta)
    ss, cs = _sin(psi), _cos(psi)
    return (
        cs * ct, cs * st * sp - ss * cp, cs * st * cp + ss * sp,
        ss * ct, ss * st * sp + cs * cp, ss * st * cp - cs * sp,
        -st, ct * sp, ct * cp,
    )  # fmt: skip


def geo_body_rates(phi: float, theta: float, phi_dot: float, theta_dot: float, psi_dot: float) -> Vec3:
    """Euler-angle rates (ZYX) -> body rates (p, q, r), rad/s."""
    sp, cp = _sin(phi), _cos(phi)
    st, ct = _sin(theta), _cos(theta)
    return (phi_dot - st * psi_dot, cp * theta_dot + sp * ct * psi_dot, -sp * theta_dot + cp * ct * psi_dot)


def geo_mat_t_vec(m: Sequence[float], v: Sequence[float]) -> Vec3:
    """M^T v for a row-major 9-tuple M."""
    return (
        m[0] * v[0] + m[3] * v[1] + m[6] * v[2],
        m[1] * v[0] + m[4] * v[1] + m[7] * v[2],
        m[2] * v[0] + m[5] * v[1] + m[8] * v[2],
    )


def geo_mat_t_mat(a: Sequence[float], b: Sequence[float]) -> Mat3:
    """A^T B for row-major 9-tuples."""
    return (
        a[0] * b[0] + a[3] * b[3] + a[6] * b[6], a[0] * b[1] + a[3] * b[4] + a[6] * b[7], a[0] * b[2] + a[3] * b[5] + a[6] * b[8],
        a[1] * b[0] + a[4] * b[3] + a[7] * b[6], a[1] * b[1] + a[4] * b[4] + a[7] * b[7], a[1] * b[2] + a[4] * b[5] + a[7] * b[8],
        a[2] * b[0] + a[5] * b[3] + a[8] * b[6], a[2] * b[1] + a[5] * b[4] + a[8] * b[7], a[2] * b[2] + a[5] * b[5] + a[8] * b[8],
    )  # fmt: skip


def geo_clamp(v: float, lim: float) -> float:
    if v > lim:
        return lim
    if v < -lim:
        return -lim
    return v


# -- the law's pieces (pure) -------------------------------------------------------------------------
def geo_desired_force(e_x: Sequence[float], e_v: Sequence[float], integ: Sequence[float], acc_d: Sequence[float], k: GeometricConsts) -> tuple[Vec3, bool]:
    """(A / m, limited): the desired force per unit mass, m/s^2, z up, and whether the
    horizontal-acceleration or tilt limit cut it. Lee's ``-kx e_x - kv e_v + m x_d'' + m g e3``
    (plus ``-ki int e_x``), per unit mass."""
    kx, kv, ki = k.kx, k.kv, k.ki
    ax = -kx[0] * e_x[0] - kv[0] * e_v[0] - ki[0] * integ[0] + acc_d[0]
    ay = -kx[1] * e_x[1] - kv[1] * e_v[1] - ki[1] * integ[1] + acc_d[1]
    az = -kx[2] * e_x[2] - kv[2] * e_v[2] - ki[2] * integ[2] + acc_d[2] + k.gravity_mps2
    limited = False
    h = _sqrt(ax * ax + ay * ay)
    if h > k.acc_max:
        s = k.acc_max / h
        ax *= s
        ay *= s
        h = k.acc_max
        limited = True
    az_min = _AZ_MIN_FRAC * k.gravity_mps2
    if az < az_min:
        az = az_min
    h_max = az * k.tan_tilt_max
    if h > h_max:
        s = h_max / h
        ax *= s
        ay *= s
        limited = True
    return (ax, ay, az), limited


def geo_desired_attitude(a: Sequence[float], a1: Sequence[float], a2: Sequence[float], psi: float, psi_dot: float, psi_ddot: float) -> tuple[Mat3, Vec3, Vec3]:
    """(R_d, W_d, W_d'): Lee's desired attitude from the desired force direction ``a`` (any
    scale) and the heading psi_d, with its body rate and acceleration from ``a``'s first two
    derivatives ``a1``, ``a2`` (same scale) and psi_d', psi_d''."""
    b3, b3_1, b3_2 = geo_unit_d2(a, a1, a2, 1.0e-9)
    cs, ss = _cos(psi), _sin(psi)
    b1d = (cs, ss, 0.0)
    b1d_1 = (-ss * psi_dot, cs * psi_dot, 0.0)
    b1d_2 = (-ss * psi_ddot - cs * psi_dot * psi_dot, cs * psi_ddot - ss * psi_dot * psi_dot, 0.0)
    c = geo_cross(b3, b1d)
    c1 = geo_axpy(1.0, geo_cross(b3_1, b1d), geo_cross(b3, b1d_1))
    c2 = geo_axpy(1.0, geo_axpy(2.0, geo_cross(b3_1, b1d_1), geo_cross(b3_2, b1d)), geo_cross(b3, b1d_2))
    b2, b2_1, b2_2 = geo_unit_d2(c, c1, c2, _CROSS_MIN)
    b1 = geo_cross(b2, b3)
    b1_1 = geo_axpy(1.0, geo_cross(b2_1, b3), geo_cross(b2, b3_1))
    b1_2 = geo_axpy(1.0, geo_axpy(2.0, geo_cross(b2_1, b3_1), geo_cross(b2_2, b3)), geo_cross(b2, b3_2))
    rd = (b1[0], b2[0], b3[0], b1[1], b2[1], b3[1], b1[2], b2[2], b3[2])
    # R_d^T R_d' = hat(W_d); the skew part of R_d^T R_d'' is hat(W_d') (hat(W)^2 is symmetric)
    wd = (geo_dot(b3, b2_1), geo_dot(b1, b3_1), geo_dot(b2, b1_1))
    wd_1 = (
        0.5 * (geo_dot(b3, b2_2) - geo_dot(b2, b3_2)),
        0.5 * (geo_dot(b1, b3_2) - geo_dot(b3, b1_2)),
        0.5 * (geo_dot(b2, b1_2) - geo_dot(b1, b2_2)),
    )
    return rd, wd, wd_1


def geo_attitude_errors(r: Sequence[float], rd: Sequence[float], w: Sequence[float], wd: Sequence[float]) -> tuple[Vec3, Vec3, Vec3]:
    """(e_R, e_W, R^T R_d W_d): ``e_R = 1/2 vee(R_d^T R - R^T R_d)``, ``e_W = W - R^T R_d W_d``."""
    e = geo_mat_t_mat(rd, r)  # E = R_d^T R; R^T R_d = E^T
    e_r = (0.5 * (e[7] - e[5]), 0.5 * (e[2] - e[6]), 0.5 * (e[3] - e[1]))
    wdb = geo_mat_t_vec(e, wd)
    return e_r, (w[0] - wdb[0], w[1] - wdb[1], w[2] - wdb[2]), wdb


def geo_moment(
    r: Sequence[float],
    rd: Sequence[float],
    w: Sequence[float],
    wd: Sequence[float],
    wd_1: Sequence[float],
    integ_r: Sequence[float],
    k: GeometricConsts,
) -> tuple[Vec3, Vec3]:
    """(M, e_R): Lee's moment, body FLU, N m, with the attitude integral term ``-J kI int e_R``."""
    e_r, e_w, wdb = geo_attitude_errors(r, rd, w, wd)
    e = geo_mat_t_mat(rd, r)
    wd1b = geo_mat_t_vec(e, wd_1)
    j = k.inertia
    kr, kw, kir = k.kr, k.kw, k.kir
    jw = (j[0] * w[0], j[1] * w[1], j[2] * w[2])
    gyro = geo_cross(w, jw)
    # hat(W) R^T R_d W_d - R^T R_d W_d'
    ff = geo_axpy(-1.0, wd1b, geo_cross(w, wdb))
    return (
        j[0] * (-kr[0] * e_r[0] - kw[0] * e_w[0] - kir[0] * integ_r[0] - ff[0]) + gyro[0],
        j[1] * (-kr[1] * e_r[1] - kw[1] * e_w[1] - kir[1] * integ_r[1] - ff[1]) + gyro[1],
        j[2] * (-kr[2] * e_r[2] - kw[2] * e_w[2] - kir[2] * integ_r[2] - ff[2]) + gyro[2],
    ), e_r


def geo_roll_pitch(rd: Sequence[float]) -> tuple[float, float]:
    """(phi, theta) of a rotation matrix, ZYX."""
    s = -rd[6]
    if s > 1.0:
        s = 1.0
    elif s < -1.0:
        s = -1.0
    return _atan2(rd[7], rd[8]), _asin(s)


def geo_integrate(i: float, e: float, dt_s: float, lim: float, gain: float) -> float:
    """One forward-Euler step of an integrator clamped to +-lim (held at 0 without a gain)."""
    if gain <= 0.0:
        return 0.0
    return geo_clamp(i + dt_s * e, lim)


# -- the interface's three functions -------------------------------------------------------------------
def geo_initial_state(meas: Sequence[float], k: GeometricConsts) -> State6:
    """The law's state: the position integrators (m s) and the attitude integrators (rad s), zero."""
    return (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


def geo_step(
    meas: Sequence[float],
    ref: Sequence[float],
    state: Sequence[float],
    dt_s: float,
    k: GeometricConsts,
    d_hat: Sequence[float],
    u_prev: Sequence[float],
) -> tuple[Vec4, State6, tuple[Vec4, Vec4, Vec4, Vec4], tuple[float, float]]:
    """One tick: (u, new state, diag (zeros), (phi_d, theta_d)). ``meas`` and ``ref`` as the full
    stage hands them (paper frame; Euler-angle rates; psi unwrapped next to psi_d)."""
    x, y, z, vx, vy, vz, phi, theta, psi, phi_dot, theta_dot, psi_dot = meas
    m = k.mass_kg
    r = geo_rotation_zyx(phi, theta, psi)
    w = geo_body_rates(phi, theta, phi_dot, theta_dot, psi_dot)
    e_x = (x - ref[0], y - ref[4], z - ref[8])
    e_v = (vx - ref[1], vy - ref[5], vz - ref[9])
    acc_d = (ref[2], ref[6], ref[10])
    a, limited = geo_desired_force(e_x, e_v, state, acc_d, k)
    f = m * (a[0] * r[2] + a[1] * r[5] + a[2] * r[8])  # A . R e3
    if f < 0.0:
        f = 0.0
    ff = k.ff
    a1 = (ff * ref[3], ff * ref[7], ff * ref[11])  # (A/m)' from the reference's jerk
    rd, wd, wd_1 = geo_desired_attitude(a, a1, _ZERO3, ref[12], ff * ref[13], ff * ref[14])
    mom, e_r = geo_moment(r, rd, w, wd, wd_1, (state[3], state[4], state[5]), k)
    # integrators: horizontal ones only while the demand is within the limits or the error unwinds it
    ki, lim = k.ki, k.int_lim
    i0, i1 = state[0], state[1]
    if not limited or e_x[0] * a[0] >= 0.0:
        i0 = geo_integrate(i0, e_x[0], dt_s, lim[0], ki[0])
    if not limited or e_x[1] * a[1] >= 0.0:
        i1 = geo_integrate(i1, e_x[1], dt_s, lim[1], ki[1])
    i2 = geo_integrate(state[2], e_x[2], dt_s, lim[2], ki[2])
    kir, limr = k.kir, k.int_lim_r
    new = (
        i0, i1, i2,
        geo_integrate(state[3], e_r[0], dt_s, limr[0], kir[0]),
        geo_integrate(state[4], e_r[1], dt_s, limr[1], kir[1]),
        geo_integrate(state[5], e_r[2], dt_s, limr[2], kir[2]),
    )  # fmt: skip
    arm = k.arm_m
    u = (mom[0] / arm, mom[1] / arm, mom[2], f)
    return u, new, (_ZERO4, _ZERO4, _ZERO4, _ZERO4), geo_roll_pitch(rd)


def geo_anti_windup(prev: Sequence[float], new: Sequence[float], u_realised: Sequence[float], limited: Sequence[bool], k: GeometricConsts) -> State6:
    """The mixer limited a channel: the attitude integrator of that axis keeps its value; the
    horizontal position integrators hold while roll or pitch is limited (the tilt was not
    realised), the vertical one while the thrust is."""
    hold_xy = limited[0] or limited[1]
    return (
        prev[0] if hold_xy else new[0],
        prev[1] if hold_xy else new[1],
        prev[2] if limited[3] else new[2],
        prev[3] if limited[0] else new[3],
        prev[4] if limited[1] else new[4],
        prev[5] if limited[2] else new[5],
    )


#: every pure function of this module (checked against the pure-function rules and compiled by the tests).
GEOMETRIC_FUNCTIONS = (
    geo_initial_state, geo_step, geo_anti_windup,
    geo_dot, geo_cross, geo_axpy, geo_unit_d2, geo_rotation_zyx, geo_body_rates, geo_mat_t_vec, geo_mat_t_mat,
    geo_clamp, geo_desired_force, geo_desired_attitude, geo_attitude_errors, geo_moment, geo_roll_pitch, geo_integrate,
)  # fmt: skip

SE3_GEOMETRIC = Law(
    name="se3_geometric", stage=STAGE_FULL, prefix="GEO",
    description="geometric tracking control on SE(3) (Lee, Leok & McClamroch 2010), whole stack, with optional integral terms",
    params_class=GeometricParams, consts=geometric_consts,
    initial_state=geo_initial_state, step=geo_step, anti_windup=geo_anti_windup,
    state_names=("int_ex_x", "int_ex_y", "int_ex_z", "int_er_x", "int_er_y", "int_er_z"),
    diagnostics=(), observer_default="none", reference="docs/geometric-control.md",
)  # fmt: skip
