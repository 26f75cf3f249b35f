"""Outer position loop (not in the paper; spec §6): position set-point -> (phi_d, theta_d).

Paper frame (x north, y west, z up). Horizontal acceleration demand::

    a = a_ref + kp (p_ref - p) + kd (v_ref - v) + ki int (p_ref - p) dt

limited to ``accel_max_mps2`` in norm, then turned into the attitude that points the thrust
along ``A = (a_x, a_y, g + z_ref'')``::

    phi_d   = asin((a_x sin psi - a_y cos psi) / |A|)
    theta_d = atan2(a_x cos psi + a_y sin psi, g + z_ref'')

both limited to ``tilt_max_rad``. Altitude is flown by the law's z channel directly.

Anti-windup: the vehicle's authority is ``a_lim = min(accel_max, g tan(tilt_max))`` (the demand
is limited in norm to ``accel_max``, the attitude to ``tilt_max``); the integral term is clamped
to it (or to ``int_limit_mps2`` if smaller), ``|ki int| <= min(int_limit, a_lim)``, and integrates
by condition: while the demand exceeds a_lim an axis integrates only when its error would reduce
the demand (``e a <= 0``). So a steady force the vehicle can hold (|F|/m < a_lim) leaves no offset: the
integral term alone can take up to a_lim. The default gains are ArduCopter's position controller
(``PSC_POSXY_P`` 1 -> ``PSC_VELXY_P`` 2, ``PSC_VELXY_I`` 1, ``PSC_VELXY_D`` 0.5) in this loop's
form, without the velocity D term's acceleration-error part (derivation in docs/baselines.md):
poles -1 +- 1j and -0.5 rad/s.

:func:`position_step` is pure: it reads the gains by name, from the validated
:class:`PositionGains` or from its flattened :class:`PositionLoopParams` (NamedTuple of floats,
what the pure flight pipeline passes, with tan(tilt_max) computed once).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

from smcpilot.errors import ConfigError

_sin = math.sin
_cos = math.cos
_asin = math.asin
_atan2 = math.atan2
_sqrt = math.sqrt
_tan = math.tan


@dataclass(frozen=True)
class PositionGains:
    """Gains and limits of the horizontal position loop."""

    #: proportional gain on position error, 1/s^2 (ArduCopter: P_vel P_pos + I_vel = 3).
    kp_1ps2: float = 3.0
    #: gain on velocity error, 1/s (ArduCopter: P_vel + D_vel P_pos = 2.5).
    kd_1ps: float = 2.5
    #: integral gain on position error, 1/s^3 (ArduCopter: I_vel P_pos = 1).
    ki_1ps3: float = 1.0
    #: largest |integral contribution|, m/s^2; the clamp in force is the smaller of this and the
    #: vehicle's authority min(accel_max, g tan(tilt_max)).
    int_limit_mps2: float = 10.0
    #: largest horizontal acceleration demand, m/s^2.
    accel_max_mps2: float = 5.0
    #: largest commanded roll or pitch, rad.
    tilt_max_rad: float = 0.6

    def __post_init__(self) -> None:
        for name in ("kp_1ps2", "kd_1ps", "ki_1ps3", "int_limit_mps2", "accel_max_mps2", "tilt_max_rad"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0.0:
                raise ConfigError(f"position gain {name} must be a finite number >= 0, got {v!r}")
        if not 0.0 < self.tilt_max_rad < 1.4:
            raise ConfigError(f"tilt_max_rad must lie in (0, 1.4) rad, got {self.tilt_max_rad}")

    @property
    def tan_tilt_max(self) -> float:
        """tan(tilt_max_rad)."""
        return _tan(self.tilt_max_rad)

    def flat(self) -> PositionLoopParams:
        """The gains as a :class:`PositionLoopParams` of floats."""
        return PositionLoopParams(
            float(self.kp_1ps2), float(self.kd_1ps), float(self.ki_1ps3),
            float(self.int_limit_mps2), float(self.accel_max_mps2), float(self.tilt_max_rad),
            float(self.tan_tilt_max),
        )  # fmt: skip


class PositionLoopParams(NamedTuple):
    """:class:`PositionGains` flattened (same names, floats)."""

    kp_1ps2: float
    kd_1ps: float
    ki_1ps3: float
    int_limit_mps2: float
    accel_max_mps2: float
    tilt_max_rad: float
    #: tan(tilt_max_rad), once (the loop's authority).
    tan_tilt_max: float


def position_step(
    g: PositionGains | PositionLoopParams,
    gravity_mps2: float,
    x: float,
    y: float,
    vx: float,
    vy: float,
    x_ref: float,
    y_ref: float,
    vx_ref: float,
    vy_ref: float,
    ax_ref: float,
    ay_ref: float,
    az_ref: float,
    psi: float,
    int_x: float,
    int_y: float,
    dt_s: float,
) -> tuple[float, float, float, float]:
    """One step of the loop; returns (phi_d [rad], theta_d [rad], new int_x, new int_y)."""
    ex = x_ref - x
    ey = y_ref - y
    ax = ax_ref + g.kp_1ps2 * ex + g.kd_1ps * (vx_ref - vx) + g.ki_1ps3 * int_x
    ay = ay_ref + g.kp_1ps2 * ey + g.kd_1ps * (vy_ref - vy) + g.ki_1ps3 * int_y
    norm = _sqrt(ax * ax + ay * ay)
    tmax = g.tilt_max_rad
    amax = g.accel_max_mps2
    a_lim = gravity_mps2 * g.tan_tilt_max  # the vehicle's authority: the smaller of the two limits
    if amax < a_lim:
        a_lim = amax
    saturated = norm > a_lim
    # Conditional integration: while saturated, an axis integrates only if that unwinds the demand.
    if not saturated or ex * ax <= 0.0:
        int_x += ex * dt_s
    if not saturated or ey * ay <= 0.0:
        int_y += ey * dt_s
    ilim = g.int_limit_mps2 if g.int_limit_mps2 < a_lim else a_lim
    lim = ilim / g.ki_1ps3 if g.ki_1ps3 > 0.0 else 0.0
    if int_x > lim:
        int_x = lim
    elif int_x < -lim:
        int_x = -lim
    if int_y > lim:
        int_y = lim
    elif int_y < -lim:
        int_y = -lim
    if norm > amax:
        k = amax / norm
        ax *= k
        ay *= k
    az = gravity_mps2 + az_ref
    if az < 0.1 * gravity_mps2:
        az = 0.1 * gravity_mps2
    sp = _sin(psi)
    cp = _cos(psi)
    a_norm = _sqrt(ax * ax + ay * ay + az * az)
    s = (ax * sp - ay * cp) / a_norm
    phi_d = _asin(s if -1.0 < s < 1.0 else (1.0 if s > 0 else -1.0))
    theta_d = _atan2(ax * cp + ay * sp, az)
    if phi_d > tmax:
        phi_d = tmax
    elif phi_d < -tmax:
        phi_d = -tmax
    if theta_d > tmax:
        theta_d = tmax
    elif theta_d < -tmax:
        theta_d = -tmax
    return phi_d, theta_d, int_x, int_y
