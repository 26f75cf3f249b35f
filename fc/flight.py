"""The flight-control pipeline of one control tick, without I/O: state -> motor commands.

::

    position set-point --prefilter--> p_ref, v_ref, a_ref --position loop--> phi_d, theta_d
    phi_d, theta_d --prefilter--> (x_d, x_d', x_d'', x_d''')  \\
    yaw set-point (unwrapped) --prefilter--> psi reference      >--> control law --> u --> mixer
    altitude set-point --prefilter--> z reference              /                 (anti-windup <-)

Everything is in the paper's frame (x north, y west, z up; ZYX Euler angles; Euler-angle rates)
— the FC's MAVLink edge converts from NED/FRD with :mod:`smcpilot.frames` before calling
:meth:`FlightControl.step`. Time comes in as ``dt_s``; nothing here reads a clock. The yaw error
the law sees is wrapped to [-pi, pi), and the yaw reference runs on an unwrapped variable, so a
heading change across +-180 deg takes the short way.

The computation is the pure :func:`fc.pipeline.pipeline_step` over flat NamedTuples (the
configuration flattened once into :class:`fc.pipeline.PipelineParams`); :class:`FlightControl`
keeps its state between ticks and the commander's set-points, and is what the rest of the FC uses.
"""

from __future__ import annotations

from dataclasses import fields
from typing import NamedTuple

from fc.config import FcConfig
from fc.control import make_controller
from fc.control.base import Diagnostics
from fc.mixer import Mixer, mix
from fc.pipeline import (
    LAW_CASCADE_PID,
    LAW_PID_SMC,
    PipelineInputs,
    PipelineParams,
    PipelineState,
    VehicleState,
    pipeline_params,
    pipeline_reset,
    pipeline_step,
)
from smcpilot.frames import wrap_pi
from smcpilot.model import PaperModel
from smcpilot.vehicle import VehicleParams

_NAN = float("nan")
#: builds a NamedTuple without the class call's argument handling (the wrapper is plain CPython).
_tuple_new = tuple.__new__

__all__ = ["FlightControl", "PipelineOutput", "VehicleState"]


class PipelineOutput(NamedTuple):
    """What one step of the flight pipeline produced."""

    #: motor commands c1..c4 in [0, 1] (rotors 1 right, 2 front, 3 left, 4 rear).
    motors: tuple[float, float, float, float]
    #: inputs the motors realise (u_phi N, u_theta N, u_psi N m, u_z N).
    u: tuple[float, float, float, float]
    #: which channels the mixer limited.
    limited: tuple[bool, bool, bool, bool]
    #: the law's internals (S, sigma, chi_hat, u, u_dot), None in open-loop failsafe.
    diag: Diagnostics | None
    #: references the law tracked: (phi_r, theta_r, psi_r, z_r).
    ref: tuple[float, float, float, float]
    #: the disturbance observer's estimate d_hat (rad/s^2 x3, m/s^2; zeros without one).
    d_hat: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)


_ZERO_STATE = PipelineState(*(0.0,) * 20, (0.0,) * 12, 0, 0.0)


def observer_authority(vehicle: VehicleParams) -> tuple[float, float, float, float]:
    """Largest |d_hat| worth estimating per channel: the angular accelerations full differential thrust
    gives (rad/s^2) and 2 g vertically (m/s^2). Beyond that no input can cancel it anyway."""
    v = vehicle
    f_max = v.thrust_coeff_n_s2 * v.rotor_speed_max_radps**2
    q_max = v.drag_coeff_n_m_s2 * v.rotor_speed_max_radps**2
    return (
        2.0 * v.arm_length_m * f_max / v.ixx_kg_m2,
        2.0 * v.arm_length_m * f_max / v.iyy_kg_m2,
        4.0 * q_max / v.izz_kg_m2,
        2.0 * v.gravity_mps2,
    )


class FlightControl:
    """Set-point tracking for one vehicle: prefilters, position loop, law, mixer, anti-windup.

    A thin stateful wrapper: the tick is :func:`fc.pipeline.pipeline_step` on the flattened
    configuration (``params``) and the carried state (``pipeline_state``).
    """

    def __init__(self, config: FcConfig, vehicle: VehicleParams) -> None:
        self.config = config
        self.vehicle = vehicle
        self.model = PaperModel.from_vehicle(vehicle)
        self.mixer = Mixer(vehicle)
        self.law = self._make_law(config)
        #: the configuration, vehicle and law flattened for :func:`fc.pipeline.pipeline_step`.
        self.params: PipelineParams = pipeline_params(config, vehicle, self.law)
        self.armed = False
        self.landing = False
        #: False in ALT_HOLD: level attitude, no horizontal position control.
        self.position_hold = True
        #: horizontal speed limit override (DO_CHANGE_SPEED), m/s; None: the config's.
        self.speed_xy_mps: float | None = None
        # Set-point (paper frame) and the unwrapped yaw target.
        self.target = (0.0, 0.0, 0.0)
        self._psi_target = 0.0
        #: prefilter states, integrators, the law's state, the landed timer.
        self.pipeline_state: PipelineState = _ZERO_STATE

    def reconfigure(self, config: FcConfig) -> None:
        """Apply new settings between control steps; the law keeps its state (same layout)."""
        old = self.config
        self.config = config
        law_keys = ("gains", "adaptation", "controller", "disturbance_estimate", "dob_bandwidth_att_radps", "dob_bandwidth_z_radps", "dob_motor_lag",
                    "cascade")
        if any(getattr(config, k) != getattr(old, k) for k in law_keys):
            n = self.pipeline_state.law_n
            self.law = self._make_law(config)
            if n != len(self.law.state_names) and self.armed:
                # another controller type: restart its state where we are
                self.pipeline_state = self.pipeline_state._replace(law_n=0)
        self.params = pipeline_params(config, self.vehicle, self.law)

    def _make_law(self, cfg: FcConfig):
        opts: dict = {}
        if cfg.controller in ("adaptive_pid_smc", "pid_smc"):
            wa, wy, wz = cfg.dob_bandwidth_att_radps, cfg.dob_bandwidth_yaw_radps, cfg.dob_bandwidth_z_radps
            opts = {
                "gains": cfg.gains, "adaptation": cfg.adaptation, "chi_hat0": (cfg.chi_hat0,) * 4,
                "disturbance_estimate": cfg.disturbance_estimate,
                "observer_bandwidth_radps": (wa, wa, wy, wz),
                "observer_motor_tau_s": self.vehicle.motor_time_constant_s if cfg.dob_motor_lag else 0.0,
                "observer_d_max": observer_authority(self.vehicle),
            }  # fmt: skip
        elif cfg.controller == "cascade_pid":
            opts = {f.name: getattr(cfg.cascade, f.name) for f in fields(cfg.cascade)}
        return make_controller(cfg.controller, self.model, **opts)

    # -- commands ------------------------------------------------------------------------------
    def arm(self, st: VehicleState) -> None:
        """Arm at the current state: references start where the vehicle is, the law at hover trim."""
        self.pipeline_state = pipeline_reset(st, self.params)
        self._psi_target = st.psi_rad
        self.target = (st.x_m, st.y_m, st.z_m)
        self.armed = True
        self.landing = False

    def disarm(self) -> None:
        self.armed = False
        self.landing = False
        self.position_hold = True
        self.speed_xy_mps = None

    def set_target(self, x_m: float, y_m: float, z_m: float, yaw_rad: float | None = None) -> None:
        """New position set-point (paper frame) and, optionally, heading (any angle; wrapped)."""
        self.target = (x_m, y_m, z_m)
        self.landing = False
        if yaw_rad is not None:
            ref = self.pipeline_state.psi_r
            self._psi_target = ref + wrap_pi(yaw_rad - ref)

    def land(self) -> None:
        """Descend at ``land_speed_mps`` over the current horizontal reference; disarm on touchdown."""
        self.landing = True
        self.landed_s = 0.0

    @property
    def landed_s(self) -> float:
        """Time settled on the ground while landing, s."""
        return self.pipeline_state.landed_s

    @landed_s.setter
    def landed_s(self, value: float) -> None:
        self.pipeline_state = self.pipeline_state._replace(landed_s=value)

    @property
    def yaw_target_rad(self) -> float:
        return wrap_pi(self._psi_target)

    @property
    def law_state(self) -> tuple[float, ...]:
        ps = self.pipeline_state
        n = ps.law_n
        return ps.law if n == 12 else ps.law[:n]

    # -- the tick -------------------------------------------------------------------------------
    def step(self, st: VehicleState, dt_s: float) -> PipelineOutput:
        """One control tick of ``dt_s`` seconds. Disarmed: motors stopped."""
        if not self.armed:
            return PipelineOutput((0.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0), (False,) * 4, None, (_NAN,) * 4)
        p = self.params
        tx, ty, tz = self.target
        vxy = self.speed_xy_mps
        cmd = _tuple_new(PipelineInputs, (
            tx, ty, tz, self._psi_target, True, self.landing, self.position_hold, p.speed_max_xy_mps if vxy is None else vxy
        ))  # fmt: skip
        self.pipeline_state, (motors, u, limited, s, sigma, chi, u_law, u_dot, ref, touchdown, d_hat) = pipeline_step(
            self.pipeline_state, st, cmd, p, dt_s
        )
        kind = p.law_kind
        if kind == LAW_PID_SMC:
            diag = Diagnostics(s, sigma, chi, u_law, u_dot)
        elif kind == LAW_CASCADE_PID:
            diag = Diagnostics(None, None, None, u_law, None)
        else:
            diag = Diagnostics(None, sigma, None, u_law, None)
        if touchdown:
            self.disarm()
        return PipelineOutput(motors, u, limited, diag, ref, d_hat)

    def failsafe_step(self) -> PipelineOutput:
        """Open loop (no state): level, thrust a fraction of hover, no yaw. Used when the state is lost."""
        if not self.armed:
            return PipelineOutput((0.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0), (False,) * 4, None, (_NAN,) * 4)
        thrust = self.config.failsafe_thrust_fraction * self.vehicle.weight_n
        motors, realised, limited = mix(self.params.mixer, 0.0, 0.0, 0.0, thrust)
        return PipelineOutput(motors, realised, limited, None, (0.0, 0.0, _NAN, _NAN))
