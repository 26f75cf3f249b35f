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

import math
from typing import Any, NamedTuple

from fc.config import FcConfig
from fc.control import registry
from fc.control.base import Diagnostics
from fc.control.law import Law, LawError
from fc.mixer import Mixer, mix
from fc.pipeline import (
    PipelineInputs,
    PipelineParams,
    PipelineState,
    VehicleState,
    observer_authority,
    pipeline_params,
    pipeline_reset,
    pipeline_reset_full,
    pipeline_step_full_sensed,
    pipeline_step_sensed,
)
from smcpilot.errors import SmcpilotError
from smcpilot.frames import wrap_pi
from smcpilot.jit import say_once
from smcpilot.model import PaperModel
from smcpilot.vehicle import VehicleParams
from smcpilot.wire import accel_of_specific_force

_NAN = float("nan")
_NAN3 = (_NAN, _NAN, _NAN)
_isfinite = math.isfinite
#: builds a NamedTuple without the class call's argument handling (the wrapper is plain CPython).
_tuple_new = tuple.__new__

__all__ = ["FlightControl", "LawFault", "PipelineOutput", "VehicleState", "observer_authority"]


class LawFault(SmcpilotError):
    """The control law failed in flight: it raised, or returned a non-finite or wrong-length command.
    The FC counts it and flies the state-loss failsafe (level, descend) instead."""


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


class FlightControl:
    """Set-point tracking for one vehicle: prefilters, position loop, law, mixer, anti-windup.

    A thin stateful wrapper: the tick is :func:`fc.pipeline.pipeline_step` (or, for a whole-stack
    law, :func:`fc.pipeline.pipeline_step_full`) on the flattened configuration (``params``), the
    law's functions (``law_functions``) and the carried state (``pipeline_state``). The law is
    ``config.controller``, resolved through :mod:`fc.control.registry` (built-in or plug-in).
    """

    def __init__(self, config: FcConfig, vehicle: VehicleParams) -> None:
        self.config = config
        self.vehicle = vehicle
        self.model = PaperModel.from_vehicle(vehicle)
        self.mixer = Mixer(vehicle)
        #: the compiled tick with the state it holds (:mod:`fc.compiled_pipeline`; None: CPython).
        self._held: Any = None
        #: the last output the compiled tick gave (its values are in ``self._held.io`` until the next tick).
        self.held_out: PipelineOutput | None = None
        self._set_law(config)
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
        self._ps: PipelineState = pipeline_reset(VehicleState(*(0.0,) * 12), self.params, self.law_functions)
        #: the law failed in flight this many times (raised, non-finite or malformed output).
        self.law_faults = 0
        #: the last law failure's message (None: none yet).
        self.last_law_fault: str | None = None

    def _set_law(self, cfg: FcConfig) -> None:
        """Resolve the law and flatten everything; on any failure nothing changes (LawError)."""
        law: Law = registry.resolve(cfg.controller)
        law_params = law.params_of(cfg) if law.params_of is not None else law.params_from_values(dict(cfg.law_values))
        try:
            params = pipeline_params(cfg, self.vehicle, law, law_params)
        except Exception as exc:  # the law's own consts(): anyone's code
            raise LawError(f"law {law.name}: its constants could not be computed: {type(exc).__name__}: {exc}") from None
        self.law = law
        self.law_params = law_params
        self.law_functions = law.functions
        self._full = law.full_stack
        self._step_fn = pipeline_step_full_sensed if self._full else pipeline_step_sensed
        #: the law measures acceleration (its meas ends with the IMU's, :attr:`Law.measures_accel`).
        self.measures_accel = bool(law.measures_accel)
        self._reset_fn = pipeline_reset_full if self._full else pipeline_reset
        self._diag_mask = tuple(name in law.diagnostics for name in ("s", "sigma", "chi_hat", "u_dot"))
        #: the configuration, vehicle and law flattened for the pipeline.
        self.params: PipelineParams = params
        held = self._held
        if held is not None:
            self._params_to_held(held)

    # -- the compiled tick ---------------------------------------------------------------------
    @property
    def pipeline_state(self) -> PipelineState:
        """Prefilter states, integrators, the law's state, the landed timer (held in compiled
        memory while the compiled tick is attached)."""
        held = self._held
        return self._ps if held is None else held.state()  # type: ignore[no-any-return]

    @pipeline_state.setter
    def pipeline_state(self, ps: PipelineState) -> None:
        held = self._held
        if held is None:
            self._ps = ps
        else:
            held.set_state(ps)

    @property
    def held_io(self) -> Any:
        """The compiled tick's inputs and outputs (:data:`fc.compiled_pipeline.IO_STATE` …; None in CPython)."""
        held = self._held
        return None if held is None else held.io

    @property
    def diag_mask(self) -> tuple[bool, bool, bool, bool]:
        """Which diagnostics the law reports: S, sigma, chi-hat, u-dot (the others are None)."""
        return self._diag_mask  # type: ignore[return-value]

    @property
    def compiled(self) -> bool:
        """The pipeline ticks compiled (:mod:`fc.compiled_pipeline`)."""
        return self._held is not None

    @property
    def compiled_ticks(self) -> int:
        """Ticks the compiled pipeline flew (0 without it)."""
        held = self._held
        return 0 if held is None else int(held.ticks)

    def attach_held(self, held: Any) -> None:
        """Tick through ``held`` (a :class:`fc.compiled_pipeline.HeldPipeline` made for this law,
        holding the current state and parameters) from now on."""
        self._held = held

    def detach_held(self, why: str) -> None:
        """Tick in CPython from now on (the state comes back from compiled memory); says why once."""
        held = self._held
        if held is None:
            return
        self._ps = held.state()
        self._held = None
        say_once(f"the FC's pipeline flies in CPython from now on: {why}")

    def _params_to_held(self, held: Any) -> None:
        from fc.compiled_pipeline import law_key

        if held.law_key != law_key(self):
            self.detach_held(f"the law is now {self.law.name}")
            return
        try:
            held.set_params(self.params)
        except Exception as exc:  # the new parameters do not fit the compiled types
            self.detach_held(f"the parameters changed shape ({type(exc).__name__})")

    def reconfigure(self, config: FcConfig) -> None:
        """Apply new settings between control steps; a law of the same name keeps its state, another
        law starts from its initial state at the next step. A law whose constants fail for these
        settings raises LawError and nothing changes."""
        old_law = self.law
        self._set_law(config)
        self.config = config
        if self.law is not old_law:
            placeholder = self._reset_fn(VehicleState(*(0.0,) * 12), self.params, self.law_functions).law
            self.pipeline_state = self.pipeline_state._replace(law=placeholder, law_init=True)

    # -- commands ------------------------------------------------------------------------------
    def arm(self, st: VehicleState) -> None:
        """Arm at the current state: references start where the vehicle is, the law at its initial state."""
        self.pipeline_state = self._reset_fn(st, self.params, self.law_functions)
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
        return self.pipeline_state.law

    # -- the tick -------------------------------------------------------------------------------
    def pipeline_inputs(self) -> PipelineInputs:
        """What the commander decided, as the pipeline reads it (armed: the pipeline runs)."""
        tx, ty, tz = self.target
        vxy = self.speed_xy_mps
        return _tuple_new(PipelineInputs, (
            tx, ty, tz, self._psi_target, True, self.landing, self.position_hold, self.params.speed_max_xy_mps if vxy is None else vxy
        ))  # fmt: skip

    def step(self, st: VehicleState, dt_s: float, accel_frd: tuple[float, float, float] | None = None) -> PipelineOutput:
        """One control tick of ``dt_s`` seconds. Disarmed: motors stopped. ``accel_frd`` is the IMU's
        specific force (body FRD, m/s^2, as ``HIGHRES_IMU`` carries it; None: no IMU this tick): a
        law that measures acceleration gets it as the kinematic acceleration, rotated with ``st``'s
        attitude (NaN without one); the others never see it.

        Raises :class:`LawFault` if the law raised or returned a non-finite or malformed command
        (the state is then unchanged; the caller flies :meth:`failsafe_step`).
        """
        if not self.armed:
            return PipelineOutput((0.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0), (False,) * 4, None, (_NAN,) * 4)
        p = self.params
        cmd = self.pipeline_inputs()
        sensed: tuple[float, ...] = ()
        if self.measures_accel:
            sensed = _NAN3 if accel_frd is None else accel_of_specific_force(*accel_frd, st.phi_rad, st.theta_rad, st.psi_rad, p.gravity_mps2)
        held = self._held
        if held is not None:
            out = held.tick(st, cmd, dt_s, sensed)
            if out is not None:  # else the law's output was not finite: CPython flies it and says why
                return self._held_output(out)
        try:
            new_state, (motors, u, limited, s, sigma, chi, u_law, u_dot, ref, touchdown, d_hat) = self._step_fn(
                self.pipeline_state, st, cmd, p, dt_s, self.law_functions, sensed
            )
            m0, m1, m2, m3 = motors
            ok = _isfinite(m0 + m1 + m2 + m3) and len(u_law) == 4 and _isfinite(u_law[0] + u_law[1] + u_law[2] + u_law[3])
        except Exception as exc:  # the law is anyone's code: any failure is counted and flown around
            self._law_fault(f"{type(exc).__name__}: {exc}")
        if not ok:
            self._law_fault(f"non-finite command u = {tuple(u_law)!r}")
        self.pipeline_state = new_state
        sm, gm, cm, dm = self._diag_mask
        diag = Diagnostics(s if sm else None, sigma if gm else None, chi if cm else None, u_law, u_dot if dm else None)
        if touchdown:
            self.disarm()
        return PipelineOutput(motors, u, limited, diag, ref, d_hat)

    def _held_output(self, o: list[float]) -> PipelineOutput:
        """The compiled tick's outputs (``fc.compiled_pipeline.IO_OUT`` on) as :meth:`step` returns them."""
        sm, gm, cm, dm = self._diag_mask
        diag = Diagnostics(
            (o[12], o[13], o[14], o[15]) if sm else None, (o[16], o[17], o[18], o[19]) if gm else None,
            (o[20], o[21], o[22], o[23]) if cm else None, (o[24], o[25], o[26], o[27]), (o[28], o[29], o[30], o[31]) if dm else None,
        )  # fmt: skip
        if o[40] != 0.0:
            self.disarm()
        out = self.held_out = PipelineOutput(
            (o[0], o[1], o[2], o[3]), (o[4], o[5], o[6], o[7]), (o[8] != 0.0, o[9] != 0.0, o[10] != 0.0, o[11] != 0.0), diag,
            (o[32], o[33], o[34], o[35]), (o[36], o[37], o[38], o[39]),
        )  # fmt: skip
        return out

    def _law_fault(self, why: str) -> None:
        self.law_faults += 1
        self.last_law_fault = f"law {self.law.name}: {why}"
        raise LawFault(self.last_law_fault)

    def failsafe_step(self) -> PipelineOutput:
        """Open loop (no state): level, thrust a fraction of hover, no yaw. Used when the state is lost."""
        if not self.armed:
            return PipelineOutput((0.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0), (False,) * 4, None, (_NAN,) * 4)
        thrust = self.config.failsafe_thrust_fraction * self.vehicle.weight_n
        motors, realised, limited = mix(self.params.mixer, 0.0, 0.0, 0.0, thrust)
        return PipelineOutput(motors, realised, limited, None, (0.0, 0.0, _NAN, _NAN))
