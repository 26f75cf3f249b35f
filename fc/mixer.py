"""Motor mixer with priorities: roll/pitch authority first, then thrust, then yaw.

The law's inputs u = (u_phi [N], u_theta [N], u_psi [N m], u_z [N]) map to rotor speeds squared
by the paper's eq. (11) (:meth:`smcpilot.model.PaperModel.unmix`)::

    w1^2 = T/4 + Y - R      w3^2 = T/4 + Y + R        (rotors 1 right, 3 left)
    w2^2 = T/4 - Y - P      w4^2 = T/4 - Y + P        (rotors 2 front, 4 rear)

with T = u_z/Kp, R = u_phi/(2 Kp), P = u_theta/(2 Kp), Y = u_psi/(4 Cd). Each w_i^2 must lie in
[w_idle^2, w_max^2]. When it cannot:

1. roll and pitch (R, P) are scaled down together until they fit in the range at all;
2. the collective T/4 is moved (thrust given up) so that R and P fit around it;
3. yaw Y gets whatever room is left.

The result is the realised u (what the rotors will produce), flags saying which channels were
limited (for the law's anti-windup), and motor commands in [0, 1] by the shared thrust-linear
mapping (:mod:`smcpilot.actuators`). Plain floats: :func:`mix` is a pure function of the
vehicle's constants flattened once (:class:`MixerParams`); :class:`Mixer` wraps it.
"""

from __future__ import annotations

import math
from typing import NamedTuple

from smcpilot.vehicle import VehicleParams

_isfinite = math.isfinite


class MixerParams(NamedTuple):
    """The mixer's constants (floats): thrust and drag coefficients, the w^2 range and its span."""

    kp: float
    cd: float
    #: idle rotor speed squared, (rad/s)^2.
    lo: float
    #: largest rotor speed squared, (rad/s)^2.
    hi: float
    span: float


def mixer_params(vehicle: VehicleParams) -> MixerParams:
    lo = vehicle.rotor_speed_idle_radps**2
    hi = vehicle.rotor_speed_max_radps**2
    return MixerParams(float(vehicle.thrust_coeff_n_s2), float(vehicle.drag_coeff_n_m_s2), float(lo), float(hi), float(hi - lo))


class Mixer:
    """Priority mixer for one vehicle (the public face of :func:`mix`)."""

    def __init__(self, vehicle: VehicleParams) -> None:
        self.vehicle = vehicle
        #: the flattened constants :func:`mix` takes.
        self.params = p = mixer_params(vehicle)
        self._kp = p.kp
        self._cd = p.cd
        self._lo = p.lo
        self._hi = p.hi
        self._span = p.span

    @property
    def thrust_range_n(self) -> tuple[float, float]:
        """Total thrust at idle and at full speed, N."""
        return 4.0 * self._kp * self._lo, 4.0 * self._kp * self._hi

    def mix(
        self, u_phi: float, u_theta: float, u_psi: float, u_z: float
    ) -> tuple[tuple[float, float, float, float], tuple[float, float, float, float], tuple[bool, bool, bool, bool]]:
        """Return (motor commands c1..c4 in [0, 1], realised u, limited flags) in channel order."""
        return mix(self.params, u_phi, u_theta, u_psi, u_z)


def mix(
    p: MixerParams, u_phi: float, u_theta: float, u_psi: float, u_z: float
) -> tuple[tuple[float, float, float, float], tuple[float, float, float, float], tuple[bool, bool, bool, bool]]:
    """(motor commands c1..c4 in [0, 1], realised u, limited flags) in channel order (pure)."""
    kp, cd, lo, hi, span = p
    finite = _isfinite(u_phi) and _isfinite(u_theta) and _isfinite(u_psi) and _isfinite(u_z)
    if not finite:
        # Never pass NaN/inf to the motors: level moments, hover thrust, every channel flagged.
        u_phi = 0.0 if not _isfinite(u_phi) else u_phi
        u_theta = 0.0 if not _isfinite(u_theta) else u_theta
        u_psi = 0.0 if not _isfinite(u_psi) else u_psi
        u_z = 4.0 * kp * 0.5 * (lo + hi) if not _isfinite(u_z) else u_z
    base = 0.25 * u_z / kp
    r = 0.5 * u_phi / kp
    p_ = 0.5 * u_theta / kp
    y = 0.25 * u_psi / cd
    lim_rp = lim_z = lim_y = False
    # 1. roll/pitch must fit in half the range.
    half = 0.5 * (hi - lo)
    m = abs(r) if abs(r) > abs(p_) else abs(p_)
    if m > half:
        k = half / m
        r *= k
        p_ *= k
        lim_rp = True
        m = half
    # 2. collective so that base +- m fits.
    if base < lo + m:
        base = lo + m
        lim_z = True
    elif base > hi - m:
        base = hi - m
        lim_z = True
    # 3. yaw in the room left: rotors 1, 3 see +y with +-r; rotors 2, 4 see -y with +-p.
    ar = abs(r)
    ap = abs(p_)
    y_hi = min(hi - base - ar, base - ap - lo)
    y_lo = max(lo - base + ar, base + ap - hi)
    if y > y_hi:
        y = y_hi if y_hi >= y_lo else 0.0
        lim_y = True
    elif y < y_lo:
        y = y_lo if y_lo <= y_hi else 0.0
        lim_y = True
    w1 = base + y - r
    w2 = base - y - p_
    w3 = base + y + r
    w4 = base - y + p_
    c1 = (w1 - lo) / span
    c2 = (w2 - lo) / span
    c3 = (w3 - lo) / span
    c4 = (w4 - lo) / span
    # Rounding can leave a hair outside [0, 1].
    c1 = 0.0 if c1 < 0.0 else 1.0 if c1 > 1.0 else c1
    c2 = 0.0 if c2 < 0.0 else 1.0 if c2 > 1.0 else c2
    c3 = 0.0 if c3 < 0.0 else 1.0 if c3 > 1.0 else c3
    c4 = 0.0 if c4 < 0.0 else 1.0 if c4 > 1.0 else c4
    realised = (2.0 * kp * r, 2.0 * kp * p_, 4.0 * cd * y, 4.0 * kp * base)
    if not finite:
        return (c1, c2, c3, c4), realised, (True, True, True, True)
    return (c1, c2, c3, c4), realised, (lim_rp, lim_rp, lim_y, lim_z)
