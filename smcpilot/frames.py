"""Frame conversions: the one module that knows about NED/FRD and the paper's NWU/FLU frames.

Frames
------
Inside the project everything is in the paper's frames:

- inertial **NWU**: x north, y west, z up;
- body **FLU**: x forward, y left, z up;
- ZYX Euler angles (phi roll, theta pitch, psi yaw) with ``R = Rz(psi) Ry(theta) Rx(phi)``
  mapping body FLU vectors to world NWU vectors; thrust acts along body +z.

MAVLink uses inertial **NED** (x north, y east, z down) and body **FRD** (x forward, y right,
z down). Both pairs differ by a rotation of pi about x, ``Rx(pi) = diag(1, -1, -1)``, so::

    x_nwu = x_ned,  y_nwu = -y_ned,  z_nwu = -z_ned         (positions, velocities, forces)
    v_flu = (v_frd.x, -v_frd.y, -v_frd.z)                   (body vectors)
    phi_flu = phi_frd,  theta_flu = -theta_frd,  psi_flu = -psi_frd
    p_flu = p_frd,  q_flu = -q_frd,  r_flu = -r_frd
    R_nwu = Rx(pi) R_ned Rx(pi),  q_nwu = (w, x, -y, -z) of q_ned

Every function takes and returns plain floats or tuples of floats (they sit in hot paths).
Quaternions are ``(w, x, y, z)``, scalar first, Hamilton convention, and rotate body vectors
into the world frame: ``v_world = q * v_body * conj(q)``.
"""

from __future__ import annotations

import math

_sin = math.sin
_cos = math.cos
_atan2 = math.atan2
_asin = math.asin
_sqrt = math.sqrt
_copysign = math.copysign

_PI = math.pi
_TWO_PI = 2.0 * math.pi

#: |sin(theta)| above which euler_from_quat treats the attitude as gimbal-locked.
_GIMBAL_LOCK_SIN = 1.0 - 1.0e-14

#: Smallest |cos(theta)| used when dividing by cos(theta) (Euler-rate singularity at +-90 deg).
COS_THETA_MIN = 1.0e-6

Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]


# -- angles ----------------------------------------------------------------------------------------
def wrap_pi(angle_rad: float) -> float:
    """Wrap an angle [rad] to [-pi, pi). Non-finite input is returned unchanged (NaN stays NaN)."""
    if not math.isfinite(angle_rad):
        return angle_rad
    if -_PI <= angle_rad < _PI:
        return angle_rad
    a = (angle_rad + _PI) % _TWO_PI - _PI
    # Float modulo can round up to exactly 2 pi for tiny negative arguments.
    if a >= _PI:
        a -= _TWO_PI
    if a < -_PI:  # pragma: no cover - defensive, not reachable with IEEE doubles
        a = -_PI
    return a


# -- inertial vectors: NED <-> NWU -----------------------------------------------------------------
def ned_to_nwu(v_ned: tuple[float, float, float]) -> Vec3:
    """World vector NED (north, east, down) -> NWU (north, west, up). Any unit."""
    return (v_ned[0], -v_ned[1], -v_ned[2])


def nwu_to_ned(v_nwu: tuple[float, float, float]) -> Vec3:
    """World vector NWU (north, west, up) -> NED (north, east, down). Any unit."""
    return (v_nwu[0], -v_nwu[1], -v_nwu[2])


# -- body vectors: FRD <-> FLU ---------------------------------------------------------------------
def frd_to_flu(v_frd: tuple[float, float, float]) -> Vec3:
    """Body vector FRD (forward, right, down) -> FLU (forward, left, up). Any unit."""
    return (v_frd[0], -v_frd[1], -v_frd[2])


def flu_to_frd(v_flu: tuple[float, float, float]) -> Vec3:
    """Body vector FLU (forward, left, up) -> FRD (forward, right, down). Any unit."""
    return (v_flu[0], -v_flu[1], -v_flu[2])


def euler_frd_to_flu(phi_rad: float, theta_rad: float, psi_rad: float) -> Vec3:
    """ZYX Euler angles [rad] of FRD body in NED -> of FLU body in NWU: (phi, -theta, -psi)."""
    return (phi_rad, -theta_rad, -psi_rad)


def euler_flu_to_frd(phi_rad: float, theta_rad: float, psi_rad: float) -> Vec3:
    """ZYX Euler angles [rad] of FLU body in NWU -> of FRD body in NED: (phi, -theta, -psi)."""
    return (phi_rad, -theta_rad, -psi_rad)


def rates_frd_to_flu(p_radps: float, q_radps: float, r_radps: float) -> Vec3:
    """Body rates [rad/s] about FRD axes -> about FLU axes: (p, -q, -r)."""
    return (p_radps, -q_radps, -r_radps)


def rates_flu_to_frd(p_radps: float, q_radps: float, r_radps: float) -> Vec3:
    """Body rates [rad/s] about FLU axes -> about FRD axes: (p, -q, -r)."""
    return (p_radps, -q_radps, -r_radps)


def quat_ned_frd_to_nwu_flu(q: tuple[float, float, float, float]) -> Quat:
    """Attitude quaternion (w,x,y,z) of FRD body in NED -> of FLU body in NWU: (w, x, -y, -z)."""
    return (q[0], q[1], -q[2], -q[3])


def quat_nwu_flu_to_ned_frd(q: tuple[float, float, float, float]) -> Quat:
    """Attitude quaternion (w,x,y,z) of FLU body in NWU -> of FRD body in NED: (w, x, -y, -z)."""
    return (q[0], q[1], -q[2], -q[3])


# -- body rates <-> Euler-angle rates --------------------------------------------------------------
def body_rates_to_euler_rates(
    phi_rad: float, theta_rad: float, p_radps: float, q_radps: float, r_radps: float
) -> Vec3:
    """Body rates (p, q, r) [rad/s] -> Euler-angle rates (phi', theta', psi') [rad/s], ZYX.

    Works in any frame pair where R = Rz(psi) Ry(theta) Rx(phi) maps body to world (FLU/NWU or
    FRD/NED, with that pair's angles and rates)::

        phi'   = p + (q sin(phi) + r cos(phi)) tan(theta)
        theta' = q cos(phi) - r sin(phi)
        psi'   = (q sin(phi) + r cos(phi)) / cos(theta)

    Near theta = +-90 deg, |cos(theta)| is held at :data:`COS_THETA_MIN` (sign kept), so the
    result stays finite but large.
    """
    sp = _sin(phi_rad)
    cp = _cos(phi_rad)
    ct = _cos(theta_rad)
    if -COS_THETA_MIN < ct < COS_THETA_MIN:
        ct = _copysign(COS_THETA_MIN, ct)
    st = _sin(theta_rad)
    a = q_radps * sp + r_radps * cp
    return (p_radps + a * st / ct, q_radps * cp - r_radps * sp, a / ct)


def euler_rates_to_body_rates(
    phi_rad: float, theta_rad: float, phi_dot_radps: float, theta_dot_radps: float, psi_dot_radps: float
) -> Vec3:
    """Euler-angle rates (phi', theta', psi') [rad/s] -> body rates (p, q, r) [rad/s], ZYX::

        p = phi' - sin(theta) psi'
        q = cos(phi) theta' + sin(phi) cos(theta) psi'
        r = -sin(phi) theta' + cos(phi) cos(theta) psi'

    Same frame remark as :func:`body_rates_to_euler_rates`; no singularity.
    """
    sp = _sin(phi_rad)
    cp = _cos(phi_rad)
    st = _sin(theta_rad)
    ct = _cos(theta_rad)
    return (
        phi_dot_radps - st * psi_dot_radps,
        cp * theta_dot_radps + sp * ct * psi_dot_radps,
        -sp * theta_dot_radps + cp * ct * psi_dot_radps,
    )


# -- quaternions -----------------------------------------------------------------------------------
def quat_from_euler(phi_rad: float, theta_rad: float, psi_rad: float) -> Quat:
    """ZYX Euler angles [rad] -> unit quaternion (w, x, y, z) of R = Rz(psi) Ry(theta) Rx(phi).

    The quaternion maps body to world (FLU -> NWU for the paper's angles). Its sign is not
    normalised: q and -q are the same rotation.
    """
    hp = 0.5 * phi_rad
    ht = 0.5 * theta_rad
    hs = 0.5 * psi_rad
    cr, sr = _cos(hp), _sin(hp)
    cp, sp = _cos(ht), _sin(ht)
    cy, sy = _cos(hs), _sin(hs)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


def euler_from_quat(q: tuple[float, float, float, float]) -> Vec3:
    """Quaternion (w, x, y, z), body -> world -> ZYX Euler angles (phi, theta, psi) [rad].

    phi and psi are in [-pi, pi] (atan2), theta in [-pi/2, pi/2]. The quaternion need not be
    exactly unit (it is normalised here). At theta = +-90 deg (gimbal lock, |sin theta| within
    1e-14 of 1) phi and psi are not unique: phi = 0 is returned and psi carries the rotation, so
    the triple still reproduces the rotation.
    """
    w, x, y, z = q
    n2 = w * w + x * x + y * y + z * z
    if n2 != 1.0 and n2 > 0.0:
        inv = 1.0 / _sqrt(n2)
        w *= inv
        x *= inv
        y *= inv
        z *= inv
    s = 2.0 * (w * y - z * x)
    if s >= _GIMBAL_LOCK_SIN or s <= -_GIMBAL_LOCK_SIN:
        # theta = +-90 deg: only phi -+ psi is defined; report phi = 0 and put it all in psi.
        return (
            0.0,
            _asin(1.0 if s > 1.0 else (-1.0 if s < -1.0 else s)),
            _atan2(2.0 * (w * z - x * y), 1.0 - 2.0 * (x * x + z * z)),
        )
    return (
        _atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y)),
        _asin(s),
        _atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z)),
    )


def euler_from_quat_heading(q: tuple[float, float, float, float], psi_rad: float) -> Vec3:
    """:func:`euler_from_quat` of a quaternion whose squared norm is exactly 1.0 (which it then
    does not normalise), given its heading ``atan2(2 (w z + x y), 1 - 2 (y^2 + z^2))`` computed
    already: the same three angles, one ``atan2`` fewer."""
    w, x, y, z = q
    s = 2.0 * (w * y - z * x)
    if s >= _GIMBAL_LOCK_SIN or s <= -_GIMBAL_LOCK_SIN:
        return euler_from_quat(q)
    return (_atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y)), _asin(s), psi_rad)


def quat_multiply(a: tuple[float, float, float, float], b: tuple[float, float, float, float]) -> Quat:
    """Hamilton product a * b of quaternions (w, x, y, z): rotate by b, then by a."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


def quat_conjugate(q: tuple[float, float, float, float]) -> Quat:
    """Conjugate (w, -x, -y, -z): the inverse rotation of a unit quaternion."""
    return (q[0], -q[1], -q[2], -q[3])


def quat_normalize(q: tuple[float, float, float, float]) -> Quat:
    """q / |q|. Raises ZeroDivisionError for the zero quaternion."""
    w, x, y, z = q
    inv = 1.0 / _sqrt(w * w + x * x + y * y + z * z)
    return (w * inv, x * inv, y * inv, z * inv)


def quat_rotate(q: tuple[float, float, float, float], v: tuple[float, float, float]) -> Vec3:
    """Rotate vector v by unit quaternion q: q * v * conj(q) (body -> world for an attitude q)."""
    w, x, y, z = q
    vx, vy, vz = v
    # t = 2 (q_vec x v); v' = v + w t + q_vec x t
    tx = 2.0 * (y * vz - z * vy)
    ty = 2.0 * (z * vx - x * vz)
    tz = 2.0 * (x * vy - y * vx)
    return (
        vx + w * tx + (y * tz - z * ty),
        vy + w * ty + (z * tx - x * tz),
        vz + w * tz + (x * ty - y * tx),
    )


def quat_rotate_inverse(q: tuple[float, float, float, float], v: tuple[float, float, float]) -> Vec3:
    """Rotate vector v by conj(q) (world -> body for an attitude q)."""
    return quat_rotate((q[0], -q[1], -q[2], -q[3]), v)


def rotation_matrix_from_euler(phi_rad: float, theta_rad: float, psi_rad: float) -> tuple[Vec3, Vec3, Vec3]:
    """R = Rz(psi) Ry(theta) Rx(phi) as three row tuples (body -> world)."""
    sp, cp = _sin(phi_rad), _cos(phi_rad)
    st, ct = _sin(theta_rad), _cos(theta_rad)
    ss, cs = _sin(psi_rad), _cos(psi_rad)
    return (
        (ct * cs, sp * st * cs - cp * ss, cp * st * cs + sp * ss),
        (ct * ss, sp * st * ss + cp * cs, cp * st * ss - sp * cs),
        (-st, sp * ct, cp * ct),
    )
