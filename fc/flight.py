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
"""

from __future__ import annotations

from typing import NamedTuple

from fc.config import FcConfig
from fc.control import make_controller
from fc.control.base import Diagnostics
from fc.mixer import Mixer
from fc.position import position_step
from fc.prefilter import prefilter_step
from smcpilot.frames import wrap_pi
from smcpilot.model import PaperModel
from smcpilot.vehicle import VehicleParams

_NAN = float("nan")


class VehicleState(NamedTuple):
    """Estimated vehicle state in the paper frame (m, m/s, rad, rad/s; Euler-angle rates)."""

    x_m: float
    y_m: float
    z_m: float
    vx_mps: float
    vy_mps: float
    vz_mps: float
    phi_rad: float
    theta_rad: float
    psi_rad: float
    phi_dot_radps: float
    theta_dot_radps: float
    psi_dot_radps: float


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


class FlightControl:
    """Set-point tracking for one vehicle: prefilters, position loop, law, mixer, anti-windup."""

    def __init__(self, config: FcConfig, vehicle: VehicleParams) -> None:
        self.config = config
        self.vehicle = vehicle
        self.model = PaperModel.from_vehicle(vehicle)
        self.mixer = Mixer(vehicle)
        self.law = self._make_law(config)
        self._g = vehicle.gravity_mps2
        self.armed = False
        self.landing = False
        self.landed_s = 0.0
        #: False in ALT_HOLD: level attitude, no horizontal position control.
        self.position_hold = True
        #: horizontal speed limit override (DO_CHANGE_SPEED), m/s; None: the config's.
        self.speed_xy_mps: float | None = None
        # Set-point (paper frame) and the unwrapped yaw target.
        self.target = (0.0, 0.0, 0.0)
        self._psi_target = 0.0
        # Prefilter states: position (x, y, z) and yaw as (value, rate, accel); roll/pitch refs.
        self._pf = [[0.0, 0.0, 0.0] for _ in range(3)]
        self._yaw = [0.0, 0.0, 0.0]
        self._att = [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]
        self._int_xy = [0.0, 0.0]
        self._law_state: tuple[float, ...] = ()
        self._ref16 = [0.0] * 16

    def reconfigure(self, config: FcConfig) -> None:
        """Apply new settings between control steps; the law keeps its state (same layout)."""
        old = self.config
        self.config = config
        if (config.gains, config.adaptation, config.controller) != (old.gains, old.adaptation, old.controller):
            state = self._law_state
            self.law = self._make_law(config)
            if len(state) == len(self.law.state_names):
                self._law_state = state
            elif self.armed:  # another controller type: restart its state where we are
                self._law_state = ()

    def _make_law(self, cfg: FcConfig):
        opts: dict = {}
        if cfg.controller in ("adaptive_pid_smc", "pid_smc"):
            opts = {"gains": cfg.gains, "adaptation": cfg.adaptation, "chi_hat0": (cfg.chi_hat0,) * 4}
        return make_controller(cfg.controller, self.model, **opts)

    # -- commands ------------------------------------------------------------------------------
    def arm(self, st: VehicleState) -> None:
        """Arm at the current state: references start where the vehicle is, the law at hover trim."""
        for i, (p, v) in enumerate(((st.x_m, st.vx_mps), (st.y_m, st.vy_mps), (st.z_m, st.vz_mps))):
            self._pf[i] = [p, v, 0.0]
        self._yaw = [st.psi_rad, 0.0, 0.0]
        self._psi_target = st.psi_rad
        self._att = [[st.phi_rad, 0.0, 0.0], [st.theta_rad, 0.0, 0.0]]
        self._int_xy = [0.0, 0.0]
        self.target = (st.x_m, st.y_m, st.z_m)
        self._law_state = tuple(self.law.initial_state((0.0, 0.0, 0.0, 0.0, st.psi_rad, 0.0, st.z_m, 0.0)))
        self.armed = True
        self.landing = False
        self.landed_s = 0.0

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
            ref = self._yaw[0]
            self._psi_target = ref + wrap_pi(yaw_rad - ref)

    def land(self) -> None:
        """Descend at ``land_speed_mps`` over the current horizontal reference; disarm on touchdown."""
        self.landing = True
        self.landed_s = 0.0

    @property
    def yaw_target_rad(self) -> float:
        return wrap_pi(self._psi_target)

    @property
    def law_state(self) -> tuple[float, ...]:
        return self._law_state

    # -- the tick -------------------------------------------------------------------------------
    def step(self, st: VehicleState, dt_s: float) -> PipelineOutput:
        """One control tick of ``dt_s`` seconds. Disarmed: motors stopped."""
        if not self.armed:
            return PipelineOutput((0.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0), (False,) * 4, None, (_NAN,) * 4)
        if not self._law_state:
            self._law_state = tuple(self.law.initial_state((st.phi_rad, 0.0, st.theta_rad, 0.0, st.psi_rad, 0.0, st.z_m, 0.0)))
        cfg = self.config
        # 1. Position/altitude references.
        w = cfg.pos_filter_omega_radps
        amax = cfg.accel_ref_max_mps2
        tx, ty, tz = self.target
        vz_max = cfg.speed_max_z_mps
        if self.landing:
            tz = st.z_m - 10.0  # keep descending until touchdown
            vz_max = cfg.land_speed_mps
        px = self._pf[0]
        py = self._pf[1]
        pz = self._pf[2]
        vxy = cfg.speed_max_xy_mps if self.speed_xy_mps is None else self.speed_xy_mps
        if not self.position_hold:
            # ALT_HOLD: the horizontal references follow the vehicle, so position hold can resume smoothly.
            px[0], px[1], px[2] = st.x_m, st.vx_mps, 0.0
            py[0], py[1], py[2] = st.y_m, st.vy_mps, 0.0
            tx, ty = st.x_m, st.y_m
        x_r, vx_r, ax_r, _ = prefilter_step(px[0], px[1], px[2], tx, w, dt_s, vxy, amax)
        y_r, vy_r, ay_r, _ = prefilter_step(py[0], py[1], py[2], ty, w, dt_s, vxy, amax)
        z_r, vz_r, az_r, jz_r = prefilter_step(pz[0], pz[1], pz[2], tz, w, dt_s, vz_max, amax)
        self._pf[0] = [x_r, vx_r, ax_r]
        self._pf[1] = [y_r, vy_r, ay_r]
        self._pf[2] = [z_r, vz_r, az_r]
        # 2. Outer loop -> attitude set-points.
        phi_d, theta_d, ix, iy = position_step(
            cfg.position, self._g, st.x_m, st.y_m, st.vx_mps, st.vy_mps, x_r, y_r, vx_r, vy_r, ax_r, ay_r, az_r,
            st.psi_rad, self._int_xy[0], self._int_xy[1], dt_s,
        )  # fmt: skip
        if not self.position_hold:
            phi_d = theta_d = 0.0
            self._int_xy = [0.0, 0.0]
        elif st.z_m < cfg.land_detect_height_m and (self.landing or z_r < cfg.land_detect_height_m):
            # On (or at) the ground the horizontal loop has no authority: do not wind up or tilt.
            phi_d = theta_d = 0.0
        else:
            self._int_xy = [ix, iy]
        wa = cfg.att_filter_omega_radps
        a0, a1 = self._att
        phi_r, phi_v, phi_a, phi_j = prefilter_step(a0[0], a0[1], a0[2], phi_d, wa, dt_s)
        th_r, th_v, th_a, th_j = prefilter_step(a1[0], a1[1], a1[2], theta_d, wa, dt_s)
        self._att = [[phi_r, phi_v, phi_a], [th_r, th_v, th_a]]
        yw = self._yaw
        psi_r, psi_v, psi_a, psi_j = prefilter_step(
            yw[0], yw[1], yw[2], self._psi_target, cfg.yaw_filter_omega_radps, dt_s, cfg.yaw_rate_max_radps
        )
        self._yaw = [psi_r, psi_v, psi_a]
        # 3. The law, on the wrapped yaw error.
        ref = self._ref16
        ref[0], ref[1], ref[2], ref[3] = phi_r, phi_v, phi_a, phi_j
        ref[4], ref[5], ref[6], ref[7] = th_r, th_v, th_a, th_j
        ref[8], ref[9], ref[10], ref[11] = psi_r, psi_v, psi_a, psi_j
        ref[12], ref[13], ref[14], ref[15] = z_r, vz_r, az_r, jz_r
        meas = (
            st.phi_rad, st.phi_dot_radps, st.theta_rad, st.theta_dot_radps,
            psi_r + wrap_pi(st.psi_rad - psi_r), st.psi_dot_radps, st.z_m, st.vz_mps,
        )  # fmt: skip
        prev = self._law_state
        u, new, diag = self.law.step(meas, ref, prev, dt_s)
        # 4. Mixer with priorities, and the realised inputs fed back (anti-windup).
        motors, realised, limited = self.mixer.mix(u[0], u[1], u[2], u[3])
        if self.landing and st.z_m < 3.0 * cfg.land_detect_height_m:
            # Ground contact is not a disturbance to learn: freeze the z channel's integrators.
            limited = (limited[0], limited[1], limited[2], True)
        if limited[0] or limited[1] or limited[2] or limited[3]:
            new = self.law.anti_windup(prev, new, realised, limited)
        self._law_state = new
        # 5. Touchdown while landing -> disarm.
        if self.landing:
            if st.z_m < cfg.land_detect_height_m and abs(st.vz_mps) < 0.2:
                self.landed_s += dt_s
                if self.landed_s >= cfg.land_detect_s:
                    self.disarm()
            else:
                self.landed_s = 0.0
        return PipelineOutput(motors, realised, limited, diag, (phi_r, th_r, psi_r, z_r))

    def failsafe_step(self) -> PipelineOutput:
        """Open loop (no state): level, thrust a fraction of hover, no yaw. Used when the state is lost."""
        if not self.armed:
            return PipelineOutput((0.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0), (False,) * 4, None, (_NAN,) * 4)
        thrust = self.config.failsafe_thrust_fraction * self.vehicle.weight_n
        motors, realised, limited = self.mixer.mix(0.0, 0.0, 0.0, thrust)
        return PipelineOutput(motors, realised, limited, None, (0.0, 0.0, _NAN, _NAN))

