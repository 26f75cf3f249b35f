"""The flight controller's state estimate: the state the pipeline flies on, and the hold point.

The simulator reports the state every tick (``ATTITUDE`` + ``LOCAL_POSITION_NED``); a sensor
dropout sends the dropped sensor's fields as NaN ("not measured", docs/gcs-protocol.md). The
flight core (:mod:`fc.core`) runs :func:`estimate_step` on every state, before anything else
sees it, so no NaN ever reaches the commander, the pipeline or a motor:

- **everything measured** -> the measured state itself (the same object: a clean flight flies
  bit for bit as without the estimator);
- **position and/or velocity missing** -> *dead reckoning* from the last good values: the
  velocity is held (its last good value), the position integrates the velocity,
  ``p += (v_prev + v) / 2 * dt`` (trapezoid; with a held velocity exactly ``p += v * dt``). The
  status is :data:`EST_DEAD_RECKONING` for at most ``pos_timeout_s`` (parameter ``FS_POS_TMO``);
  missing for longer — or missing before any good value was seen — is :data:`EST_POSITION_LOST`,
  and the core enters its state-loss failsafe;
- **attitude or body rates missing** -> :data:`EST_ATTITUDE_LOST` at once: nothing can fly on a
  dead-reckoned attitude (the core's state-loss failsafe).

The **hold point** is a low-pass-filtered position and yaw for the places where the commander
takes "where the vehicle is now" as a set-point (arming, take-off, LOITER/GUIDED/ALT_HOLD/LAND at
the current place, RTL's climb, AUTO's "here" items), so one noisy sample no longer decides it.
It is a first-order complementary filter aided by the measured velocity (so it does not lag a
moving vehicle): predict ``h += (v_prev + v) / 2 * dt``, then ``h += alpha * (p - h)`` with
``alpha = 1 - exp(-dt / tau)`` (``tau`` = :attr:`EstimatorConfig.hold_tau_s`, 0.2 s). Yaw the
same way with the yaw rate, the innovation wrapped to [-pi, pi). A sample-to-prediction
innovation beyond ``hold_reset_m`` (a position jump, e.g. a sensor back after a dropout) re-starts
the filter at the sample.

The filter is used only while noise is plausible: an exponential average (same ``tau``) of the
squared innovation must exceed ``hold_noise_floor_m``² (yaw: ``hold_noise_floor_rad``²);
otherwise the hold point is the sample itself. Without sensor noise the innovation is the
integration error of the prediction (< 1e-5 m even when accelerating; v·dt, ~1.4 mm, for the one
tick of a touchdown), so its average stays far below the 1 mm floor (a touchdown lifts it to
~2e-8 m² against 1e-6 m²) and a clean flight takes exactly the same set-points as before; with the simulator's ``--noise`` (0.01 m, 0.002 rad per axis) the average settles
near 3e-4 m² (3 axes), far above it. Set-point errors below a millimetre do not matter, so
filtering below the floor would buy nothing.

Everything is in the paper frame (x north, y west, z up; ZYX Euler angles and Euler-angle rates,
rad and rad/s); time is ``dt_s``, passed in. :func:`estimate_step` is pure (plain floats,
NamedTuples; listed in :data:`PURE_FUNCTIONS`, compiled by numba in tests/test_compilable.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import NamedTuple

from fc.pipeline import VehicleState
from smcpilot.errors import ConfigError
from smcpilot.frames import wrap_pi

#: ``missing`` bits: which groups of the state were not measured (non-finite) this tick.
MISSING_POSITION = 1
MISSING_VELOCITY = 2
MISSING_ATTITUDE = 4
MISSING_RATES = 8

#: every group measured: the measured state.
EST_OK = 0
#: position and/or velocity missing for at most ``pos_timeout_s``: dead reckoning.
EST_DEAD_RECKONING = 1
#: position and/or velocity missing longer (or never measured): the state-loss failsafe.
EST_POSITION_LOST = 2
#: attitude or body rates missing: the state-loss failsafe, at once.
EST_ATTITUDE_LOST = 3

#: a timeout comparison tolerance, s (the missing time is a sum of tick periods).
_TIME_EPS_S = 1e-9
_PI = math.pi


@dataclass(frozen=True)
class EstimatorConfig:
    """Settings of :func:`estimate_step` (validated; the FC parameter ``FS_POS_TMO`` sets
    :attr:`pos_timeout_s`)."""

    #: longest dead reckoning on a missing position/velocity before the state-loss failsafe, s.
    pos_timeout_s: float = 1.0
    #: time constant of the hold-point filter, s.
    hold_tau_s: float = 0.2
    #: the hold-point filter is used only while the RMS position innovation exceeds this, m.
    hold_noise_floor_m: float = 1e-3
    #: the same for yaw, rad.
    hold_noise_floor_rad: float = 1e-3
    #: an innovation larger than this re-starts the hold filter at the sample, m.
    hold_reset_m: float = 1.0

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0.0:
                raise ConfigError(f"estimator setting {f.name} must be a finite number >= 0, got {v!r}")
        for name in ("hold_tau_s", "hold_reset_m"):
            if getattr(self, name) <= 0.0:
                raise ConfigError(f"estimator setting {name} must be > 0, got {getattr(self, name)!r}")


class EstimatorParams(NamedTuple):
    """:class:`EstimatorConfig` flattened for one tick period (floats only)."""

    pos_timeout_s: float
    #: hold filter gain per tick, 1 - exp(-dt / tau).
    hold_alpha: float
    #: squared noise floors (position: sum over the 3 axes), m^2 and rad^2.
    gate_pos_m2: float
    gate_yaw_rad2: float
    #: squared re-start threshold, m^2.
    reset_m2: float


class EstimatorState(NamedTuple):
    """What :func:`estimate_step` carries from tick to tick (paper frame)."""

    #: a position / a velocity has been measured at least once.
    have_pos: bool
    have_vel: bool
    #: the latest estimate: measured, or dead-reckoned (m, m/s).
    x_m: float
    y_m: float
    z_m: float
    vx_mps: float
    vy_mps: float
    vz_mps: float
    #: the latest yaw, rad (measured; the hold point's yaw without noise).
    psi_rad: float
    #: how long the position / velocity has been missing, s (0: measured this tick).
    pos_missing_s: float
    vel_missing_s: float
    #: the hold filter holds a value (False: it starts at the next good sample).
    hold_ok: bool
    hold_x_m: float
    hold_y_m: float
    hold_z_m: float
    hold_psi_rad: float
    #: the yaw rate of the previous tick, rad/s (the trapezoid's other end).
    psi_dot_radps: float
    #: exponential averages of the squared innovations, m^2 and rad^2.
    innov_pos_m2: float
    innov_yaw_rad2: float


class HoldPoint(NamedTuple):
    """Where the vehicle is, for a set-point "here" (paper frame, m and rad)."""

    x_m: float
    y_m: float
    z_m: float
    psi_rad: float


ESTIMATOR_START = EstimatorState(False, False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


def estimator_params(config: EstimatorConfig, dt_s: float) -> EstimatorParams:
    """Flatten ``config`` for ticks of ``dt_s`` seconds."""
    floor_m = config.hold_noise_floor_m
    floor_rad = config.hold_noise_floor_rad
    return EstimatorParams(
        float(config.pos_timeout_s), 1.0 - math.exp(-dt_s / config.hold_tau_s), float(floor_m * floor_m),
        float(floor_rad * floor_rad), float(config.hold_reset_m * config.hold_reset_m),
    )  # fmt: skip


def estimate_step(
    est: EstimatorState, m: VehicleState, dt_s: float, p: EstimatorParams
) -> tuple[EstimatorState, VehicleState, int, int]:
    """One tick: ``(state, estimate, status, missing)`` of the measured state ``m`` (NaN or
    infinite fields: not measured).

    ``estimate`` is ``m`` itself when everything was measured, the dead-reckoned state otherwise
    (attitude and rates as measured); when ``status`` is :data:`EST_POSITION_LOST` or
    :data:`EST_ATTITUDE_LOST` it must not be flown (it may hold non-finite values). ``missing``
    has the ``MISSING_*`` bits. The hold point is :func:`hold_point` of the new state (computed
    only when a set-point needs it).
    """
    x, y, z, vx, vy, vz, phi, theta, psi, phi_d, theta_d, psi_d = m
    (have_pos, have_vel, ex_, ey_, ez_, evx, evy, evz, epsi, pos_missing_s, vel_missing_s, hold_ok, hx, hy, hz, hpsi,
     epsi_d, e2p, e2y) = est  # fmt: skip
    half_dt = 0.5 * dt_s
    # Everything measured (the sum of finite values is finite; one non-finite value makes it not).
    if math.isfinite(x + y + z + vx + vy + vz + phi + theta + psi + phi_d + theta_d + psi_d):
        missing = 0
        status = EST_OK
        have_pos = True
        have_vel = True
        pos_missing_s = 0.0
        vel_missing_s = 0.0
    else:
        pos_ok = math.isfinite(x) and math.isfinite(y) and math.isfinite(z)
        vel_ok = math.isfinite(vx) and math.isfinite(vy) and math.isfinite(vz)
        att_ok = math.isfinite(phi) and math.isfinite(theta) and math.isfinite(psi)
        rates_ok = math.isfinite(phi_d) and math.isfinite(theta_d) and math.isfinite(psi_d)
        missing = 0
        if not pos_ok:
            missing |= MISSING_POSITION
        if not vel_ok:
            missing |= MISSING_VELOCITY
        if not att_ok:
            missing |= MISSING_ATTITUDE
        if not rates_ok:
            missing |= MISSING_RATES
        # Velocity: measured, or held.
        if vel_ok:
            vel_missing_s = 0.0
            have_vel = True
        else:
            vx, vy, vz = evx, evy, evz
            vel_missing_s = vel_missing_s + dt_s
        # Position: measured, or integrated from the velocity (trapezoid).
        if pos_ok:
            pos_missing_s = 0.0
            have_pos = True
        else:
            x = ex_ + half_dt * (evx + vx)
            y = ey_ + half_dt * (evy + vy)
            z = ez_ + half_dt * (evz + vz)
            pos_missing_s = pos_missing_s + dt_s
        if not rates_ok:
            psi_d = epsi_d
        if not att_ok:
            psi = epsi
        if not (att_ok and rates_ok):
            status = EST_ATTITUDE_LOST
        elif not (have_pos and have_vel):
            status = EST_POSITION_LOST
        elif max(pos_missing_s, vel_missing_s) > p.pos_timeout_s + _TIME_EPS_S:
            status = EST_POSITION_LOST
        else:
            status = EST_DEAD_RECKONING
    # The hold filter (position and yaw), velocity-aided.
    if status == EST_POSITION_LOST or status == EST_ATTITUDE_LOST:
        hold_ok = False
    elif not hold_ok:
        hold_ok = True
        hx, hy, hz, hpsi = x, y, z, psi
        e2p, e2y = 0.0, 0.0
    else:
        a = p.hold_alpha
        px = hx + half_dt * (evx + vx)
        py = hy + half_dt * (evy + vy)
        pz = hz + half_dt * (evz + vz)
        ix, iy, iz = x - px, y - py, z - pz
        e2 = ix * ix + iy * iy + iz * iz
        if e2 > p.reset_m2:
            hx, hy, hz = x, y, z
            e2p = 0.0
        else:
            hx, hy, hz = px + a * ix, py + a * iy, pz + a * iz
            e2p = e2p + a * (e2 - e2p)
        ppsi = hpsi + half_dt * (epsi_d + psi_d)
        ipsi = psi - ppsi
        if not -_PI <= ipsi < _PI:
            ipsi = wrap_pi(ipsi)
        hpsi = ppsi + a * ipsi
        if not -_PI <= hpsi < _PI:
            hpsi = wrap_pi(hpsi)
        e2y = e2y + a * (ipsi * ipsi - e2y)
    new = EstimatorState(
        have_pos, have_vel, x, y, z, vx, vy, vz, psi, pos_missing_s, vel_missing_s, hold_ok, hx, hy, hz, hpsi, psi_d, e2p, e2y
    )  # fmt: skip
    if missing == 0:
        return new, m, status, missing
    return new, VehicleState(x, y, z, vx, vy, vz, m.phi_rad, m.theta_rad, m.psi_rad, m.phi_dot_radps, m.theta_dot_radps,
                             m.psi_dot_radps), status, missing  # fmt: skip


def hold_point(est: EstimatorState, p: EstimatorParams) -> HoldPoint:
    """The hold point after the tick that gave ``est``: the filtered position and yaw while the
    innovation says the samples are noisy, else the estimate's own (the sample itself)."""
    if est.hold_ok and est.innov_pos_m2 > p.gate_pos_m2:
        x, y, z = est.hold_x_m, est.hold_y_m, est.hold_z_m
    else:
        x, y, z = est.x_m, est.y_m, est.z_m
    psi = est.hold_psi_rad if (est.hold_ok and est.innov_yaw_rad2 > p.gate_yaw_rad2) else est.psi_rad
    return HoldPoint(x, y, z, psi)


#: the estimator's pure functions (checked and compiled with the pipeline's by tests/test_compilable.py).
PURE_FUNCTIONS = (estimate_step, hold_point, wrap_pi)

__all__ = [
    "EST_ATTITUDE_LOST",
    "EST_DEAD_RECKONING",
    "EST_OK",
    "EST_POSITION_LOST",
    "ESTIMATOR_START",
    "EstimatorConfig",
    "EstimatorParams",
    "EstimatorState",
    "HoldPoint",
    "MISSING_ATTITUDE",
    "MISSING_POSITION",
    "MISSING_RATES",
    "MISSING_VELOCITY",
    "estimate_step",
    "estimator_params",
    "hold_point",
]
