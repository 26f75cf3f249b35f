"""The one conversion between the vehicle's state on the wire and in the paper's frame.

On the wire (``ATTITUDE`` + ``LOCAL_POSITION_NED``, and the per-tick log) the state is 12 floats
in MAVLink's frames: roll, pitch, yaw (rad, FRD body in NED), p, q, r (rad/s about FRD axes),
x, y, z (m, NED), vx, vy, vz (m/s, NED). The flight controller flies on the paper's frame: x
north, y west, z up, ZYX Euler angles of the FLU body, and Euler-angle rates. The simulator
converts its observation to the wire with :func:`wire_of_paper`; the flight controller, the
in-process runner and the compiled flight convert back with :func:`paper_of_wire`. Both are pure
(floats and tuples), so CPython and compiled code run the same functions.
"""

from __future__ import annotations

import math

from smcpilot.frames import (
    body_rates_to_euler_rates,
    euler_flu_to_frd,
    euler_frd_to_flu,
    ned_to_nwu,
    nwu_to_ned,
    rates_flu_to_frd,
    rates_frd_to_flu,
)

__all__ = ["WIRE_FIELDS", "wire_of_paper", "paper_of_wire", "accel_of_specific_force", "WIRE_FUNCTIONS"]

#: the 12 wire values, in order.
WIRE_FIELDS = ("roll", "pitch", "yaw", "p", "q", "r", "x", "y", "z", "vx", "vy", "vz")


def wire_of_paper(
    phi: float, theta: float, psi: float, p: float, q: float, r: float,
    x: float, y: float, z: float, vx: float, vy: float, vz: float,
) -> tuple[float, float, float, float, float, float, float, float, float, float, float, float]:  # fmt: skip
    """The 12 wire values (NED/FRD) of a state in the paper's frames: Euler angles (rad) and body
    rates (rad/s) of the FLU body, position (m) and velocity (m/s) in NWU."""
    roll, pitch, yaw = euler_flu_to_frd(phi, theta, psi)
    ps, qs, rs = rates_flu_to_frd(p, q, r)
    xn, yn, zn = nwu_to_ned((x, y, z))
    vxn, vyn, vzn = nwu_to_ned((vx, vy, vz))
    return (roll, pitch, yaw, ps, qs, rs, xn, yn, zn, vxn, vyn, vzn)


def paper_of_wire(
    roll: float, pitch: float, yaw: float, ps: float, qs: float, rs: float,
    xn: float, yn: float, zn: float, vxn: float, vyn: float, vzn: float,
) -> tuple[float, float, float, float, float, float, float, float, float, float, float, float, float, float, float]:  # fmt: skip
    """The paper-frame state of the 12 wire values: x, y, z (m, NWU), vx, vy, vz (m/s), phi,
    theta, psi (rad), their rates (rad/s; Euler-angle rates), then the body rates p, q, r (rad/s,
    FLU) — the first 12 in :class:`fc.pipeline.VehicleState`'s order. NaN stays NaN."""
    phi, theta, psi = euler_frd_to_flu(roll, pitch, yaw)
    p, q, r = rates_frd_to_flu(ps, qs, rs)
    phi_d, theta_d, psi_d = body_rates_to_euler_rates(phi, theta, p, q, r)
    x, y, z = ned_to_nwu((xn, yn, zn))
    vx, vy, vz = ned_to_nwu((vxn, vyn, vzn))
    return (x, y, z, vx, vy, vz, phi, theta, psi, phi_d, theta_d, psi_d, p, q, r)


def accel_of_specific_force(
    fx: float, fy: float, fz: float, phi: float, theta: float, psi: float, g: float
) -> tuple[float, float, float]:
    """The kinematic acceleration (x'', y'', z'': m/s^2, paper frame NWU, gravity removed) of an
    accelerometer's specific force on the wire (``HIGHRES_IMU.xacc``..``zacc``: body FRD, m/s^2,
    (0, 0, -g) level at rest), rotated with the ZYX Euler angles of the FLU body (rad). The inverse
    of the simulator's :func:`sim_bridge.sensors.specific_force_frd`; NaN in, NaN out."""
    ux, uy, uz = fx, -fy, -fz  # FRD -> FLU
    sp, cp = math.sin(phi), math.cos(phi)
    st, ct = math.sin(theta), math.cos(theta)
    ss, cs = math.sin(psi), math.cos(psi)
    ax = cs * ct * ux + (cs * st * sp - ss * cp) * uy + (cs * st * cp + ss * sp) * uz
    ay = ss * ct * ux + (ss * st * sp + cs * cp) * uy + (ss * st * cp - cs * sp) * uz
    az = -st * ux + ct * sp * uy + ct * cp * uz - g
    return (ax, ay, az)


#: the pure functions (compiled with the flight kernel).
WIRE_FUNCTIONS = (wire_of_paper, paper_of_wire)
