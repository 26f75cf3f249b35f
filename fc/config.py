"""Flight-controller configuration: one frozen dataclass, units in the names, defaults here only.

The control-law gains live in :mod:`fc.control.gains` (the paper's values by default); the
position loop's in :class:`fc.position.PositionGains`. What a real flight controller adds to the
paper (spec §6) is configured here: reference prefilters, the bounded adaptive law, landing and
failsafe behaviour, telemetry rates.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

from fc.control.cascade_pid import CascadePidParams
from fc.control.gains import PAPER_GAINS, Gains4, gains_with_overrides
from fc.control.pid_smc import DISTURBANCE_ESTIMATES, AdaptationBounds
from fc.position import PositionGains
from smcpilot.errors import ConfigError
from smcpilot.lawref import law_reference_problem
from smcpilot.limits import DEFAULT_FENCE, Fence

#: the flight controller's default gains: the paper's (spec §5) with Theta = 1 on roll, pitch and yaw
#: (the altitude channel keeps 0.05: its sigma carries the position and velocity noise).
FC_GAINS: Gains4 = gains_with_overrides(PAPER_GAINS, {"phi.adapt_rate": 1.0, "theta.adapt_rate": 1.0, "psi.adapt_rate": 1.0})

#: the cascaded PID the flight controller flies (``cascade_pid``): ArduCopter's rate-controller
#: structure (rate PID with D on the measured rate and its own low-pass, a gyro low-pass, clamped
#: integrators), tuned to the PID-SMC's attitude bandwidth (docs/baselines.md).
FC_CASCADE = CascadePidParams(
    k_outer=(3.0, 3.0, 4.0, 2.0),
    k_inner=(20.0, 20.0, 12.0, 5.0),
    ki_inner=(20.0, 20.0, 8.0, 2.0),
    kd_rate=(0.2, 0.2, 0.0),
    i_max=(50.0, 50.0, 5.0, 5.0),
    gyro_filter_hz=20.0,
    d_filter_hz=20.0,
)


@dataclass(frozen=True)
class FcConfig:
    """Everything that configures the flight controller besides the vehicle."""

    #: control loop rate, Hz (in lockstep: the simulator's state rate).
    rate_hz: float = 500.0
    #: the control law: a built-in's name (adaptive_pid_smc, the default; pid_smc, cascade_pid,
    #: sign_smc), an installed plug-in's, or path/to/file.py:NAME / package.module:NAME
    #: (:mod:`fc.control.registry`).
    controller: str = "adaptive_pid_smc"
    #: values of the parameters of laws that keep theirs as MAVLink values (plug-ins, sign_smc):
    #: (full name, value) pairs, sorted by name; a parameter not here is at its default.
    law_values: tuple[tuple[str, float], ...] = ()
    #: the paper's gains, with an adaptation rate Theta of 1 instead of 0.05 on the attitude channels:
    #: at 0.05 chi_hat moves by about 0.03 during a motor fault's transient (docs/disturbance-observer.md).
    gains: Gains4 = FC_GAINS
    #: keeps chi_hat bounded under noise (spec §4): a dead zone on |sigma| above its noise floor
    #: (|sigma| averages 0.07-0.21 with the simulator's --noise), a slow leakage back to chi_hat(0)
    #: (0.02/s: bounded in a 10 min noisy hover) and a projection onto [0, 20].
    adaptation: AdaptationBounds = field(
        default_factory=lambda: AdaptationBounds(dead_zone=0.5, leakage_per_s=0.02, chi_hat_min=0.0, chi_hat_max=20.0)
    )
    #: chi_hat(0) of the adaptive law, every channel.
    chi_hat0: float = 0.5
    #: the disturbance observer in front of the law (:mod:`fc.control.observer`, ``DOB_MODE``): "none",
    #: "sigma" or "lumped" (the estimate handed to the law: the PID-SMC uses it in sigma only or
    #: added to its model's drift f), "input" (cancelled at the law's output), or "auto": the law's
    #: own default (the PID-SMC flies "input", the baselines "none"). See docs/disturbance-observer.md.
    disturbance_estimate: str = "auto"
    #: disturbance-observer bandwidth of the roll and pitch channels, rad/s.
    dob_bandwidth_att_radps: float = 40.0
    #: disturbance-observer bandwidth of the yaw channel, rad/s (low: yaw authority is small, so its
    #: compensation turns rate noise into large motor-command noise).
    dob_bandwidth_yaw_radps: float = 5.0
    #: disturbance-observer bandwidth of the altitude channel, rad/s.
    dob_bandwidth_z_radps: float = 5.0
    #: the observer models the rotors' first-order lag (the vehicle's motor time constant).
    dob_motor_lag: bool = True
    position: PositionGains = field(default_factory=PositionGains)
    #: gains and filters of the cascaded PID (``controller = "cascade_pid"``).
    cascade: CascadePidParams = FC_CASCADE
    #: bandwidth of the position and altitude reference prefilters, rad/s.
    pos_filter_omega_radps: float = 1.8
    #: largest horizontal reference speed, m/s.
    speed_max_xy_mps: float = 3.0
    #: largest vertical reference speed (climb and descent), m/s.
    speed_max_z_mps: float = 1.5
    #: largest reference acceleration (each axis), m/s^2: ArduCopter's WPNAV_ACCEL default
    #: (250 cm/s^2). With the PSC-stiff position loop, 3 m/s^2 tilted a 4 m step to 22°.
    accel_ref_max_mps2: float = 2.5
    #: bandwidth of the roll/pitch reference prefilters (outer loop -> law), rad/s.
    att_filter_omega_radps: float = 25.0
    #: bandwidth of the yaw reference prefilter, rad/s.
    yaw_filter_omega_radps: float = 2.0
    #: largest yaw reference rate, rad/s.
    yaw_rate_max_radps: float = 1.5
    #: descent speed when landing, m/s.
    land_speed_mps: float = 0.7
    #: height below which, slow and settled for ``land_detect_s``, the vehicle counts as landed, m.
    land_detect_height_m: float = 0.08
    land_detect_s: float = 0.5
    #: real time: state older than this puts the FC in failsafe (level, descend), s.
    failsafe_state_timeout_s: float = 0.1
    #: open-loop thrust during a state-loss failsafe, as a fraction of hover thrust.
    failsafe_thrust_fraction: float = 0.85
    #: a silent simulator for this long (wall seconds) ends the FC with an error.
    watchdog_s: float = 5.0
    #: rate of telemetry to ground stations (ATTITUDE, LOCAL_POSITION_NED, CHI_*, SIG_*), Hz.
    telemetry_rate_hz: float = 10.0
    #: MAVLink system id of this vehicle.
    system_id: int = 1
    #: pre-arm checks on (True) or skipped (False; the state must still be arriving).
    arming_check: bool = True
    #: disarm after this long armed on the ground without a take-off, s (0: never).
    disarm_delay_s: float = 10.0
    #: RTL climbs to at least this altitude above home before flying home, m.
    rtl_alt_m: float = 5.0
    #: a waypoint counts as reached within this distance, m.
    wp_radius_m: float = 0.3
    #: GCS-loss failsafe: 0 off, 1 RTL, 2 LAND.
    fs_gcs_enable: int = 0
    #: GCS-loss failsafe: no GCS heartbeat for this long (wall clock), s.
    fs_gcs_timeout_s: float = 5.0
    #: geofence (smcpilot.limits): targets outside it are refused; a cylinder around home.
    fence_enable: bool = DEFAULT_FENCE.enabled
    fence_radius_m: float = DEFAULT_FENCE.radius_m
    fence_alt_max_m: float = DEFAULT_FENCE.alt_max_m

    @property
    def fence(self) -> Fence:
        """The geofence every target is checked against (:func:`smcpilot.limits.target_refusal`)."""
        return Fence(self.fence_enable, self.fence_radius_m, self.fence_alt_max_m)

    def __post_init__(self) -> None:
        if self.disturbance_estimate not in DISTURBANCE_ESTIMATES + ("auto",):
            raise ConfigError(
                f"disturbance_estimate must be auto or one of {', '.join(DISTURBANCE_ESTIMATES)}, got {self.disturbance_estimate!r}"
            )
        problem = law_reference_problem(self.controller)
        if problem:
            raise ConfigError(problem)
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, (int, float)) and not isinstance(v, bool):
                if not math.isfinite(v) or v < 0.0:
                    raise ConfigError(f"FC setting {f.name} must be a finite number >= 0, got {v!r}")
        for name in (
            "rate_hz",
            "pos_filter_omega_radps",
            "att_filter_omega_radps",
            "yaw_filter_omega_radps",
            "speed_max_xy_mps",
            "speed_max_z_mps",
            "accel_ref_max_mps2",
            "yaw_rate_max_radps",
            "land_speed_mps",
            "failsafe_state_timeout_s",
            "watchdog_s",
            "telemetry_rate_hz",
            "dob_bandwidth_att_radps",
            "dob_bandwidth_yaw_radps",
            "dob_bandwidth_z_radps",
        ):
            if getattr(self, name) <= 0.0:
                raise ConfigError(f"FC setting {name} must be > 0, got {getattr(self, name)!r}")
        if not 1.0 <= self.rate_hz <= 1000.0:
            raise ConfigError(f"rate_hz must lie in [1, 1000] Hz, got {self.rate_hz}")
        if self.telemetry_rate_hz > self.rate_hz:
            raise ConfigError("telemetry_rate_hz cannot exceed the control rate")
        if not 0.0 < self.failsafe_thrust_fraction < 1.0:
            raise ConfigError(f"failsafe_thrust_fraction must lie in (0, 1), got {self.failsafe_thrust_fraction}")
        if not 1 <= self.system_id <= 255:
            raise ConfigError(f"system_id must lie in 1..255, got {self.system_id}")
        if self.fs_gcs_enable not in (0, 1, 2):
            raise ConfigError(f"fs_gcs_enable must be 0 (off), 1 (RTL) or 2 (LAND), got {self.fs_gcs_enable}")
        if self.fs_gcs_timeout_s <= 0.0 or self.wp_radius_m <= 0.0:
            raise ConfigError("fs_gcs_timeout_s and wp_radius_m must be > 0")

    @property
    def period_s(self) -> float:
        return 1.0 / self.rate_hz

    @property
    def period_us(self) -> int:
        return int(round(1e6 / self.rate_hz))
