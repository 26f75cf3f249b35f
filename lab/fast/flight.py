"""The compiled in-process flight: the kernel flies the plain ticks, Python the eventful ones.

:func:`fast_simulate` flies like :func:`lab.runner.simulate` (which calls it by default): a
flight is continuous ticks between discrete events, so the compiled kernel
(:func:`lab.fast.kernel.fly_span`) flies tick after tick until something discrete is due — a plan
step, a fault starting or stopping, the mode's watched condition (:meth:`fc.modes.base.FlightMode.watch`),
the disarm delay, a touchdown, a law failure, the end — and returns *before* that tick; Python
flies it with the ordinary objects (:class:`fc.core.FlightCore`, the plant, the faults, the event
sinks), then the kernel goes on. The state moves between the live objects and the kernel's
arrays at each hand-over (:class:`_Bridge`), so the objects are exactly what a CPython flight
leaves: the same motor commands, events, records and random streams, bit for bit
(``tests/test_fast.py``).

What the kernel cannot fly goes through Python a tick at a time, said once per reason: a plant
other than the rigid body, a control law not in the pure style, a tick hook (``on_tick``) other
than a metrics recorder, sensor faults or fault gusts acting, the state-loss failsafe, a law
failure, a mode that does something every tick.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from fc import estimate as estimate_mod
from fc import mixer as mixer_mod
from fc import pipeline as pipeline_mod
from fc import position as position_mod
from fc.commander import CommanderInput
from fc.control.base import Diagnostics
from fc.control.law import LawFunctions
from fc.control.purity import law_problems, pure_closure
from fc.core import FlightCore, TickOutput
from fc.estimate import EST_DEAD_RECKONING, EST_OK
from fc.flight import PipelineOutput, VehicleState
from fc.modes.base import WATCH_ALWAYS
from ground.logs.metrics import score_compiled
from lab.fast import kernel as kernel_mod
from lab.fast.mt import MT_FUNCTIONS, mt_export, mt_import
from sim_bridge.faults import TIME_EPS_S
from sim_bridge.plants import rigid_body
from sim_bridge.plants.rigid_body import RigidBodyPlant, StepInput
from sim_bridge.sensors import VehicleObservation
from smcpilot.errors import DivergenceError
from smcpilot.faults import MAX_DELAY_S, SENSORS
from smcpilot.frames import quat_from_euler
from smcpilot.jit import JIT_ENV, compile_pure, jit_enabled, numba_module, say_once
from smcpilot.jit import cache_index as _cache_index

__all__ = ["FastRecord", "fast_simulate", "fast_unsupported", "compiled_kernel"]

#: the compiled kernel's own share of this process's flying: [calls, ticks flown, wall seconds]
#: (``smcpilot bench batch`` splits a flight's time with it).
KERNEL_TIME = [0, 0, 0.0]

_ONES4 = (1.0, 1.0, 1.0, 1.0)
_NAN4 = (math.nan,) * 4
#: the kernel flies at most this many ticks a call (a ``stop()`` check and progress in between):
#: 20 simulated seconds at 500 Hz, some 10-25 ms of wall time.
CHUNK_TICKS = 10000


@dataclass(frozen=True)
class FastRecord:
    """Rows for a :class:`lab.metrics.MetricsRecorder`: every ``every`` ticks, of the true state
    (``truth``: what the vehicle did, after the wire's float32 round trip) or of the received one."""

    recorder: Any
    every: int = 1
    truth: bool = False


#: the compiled kernels of this process (numba dispatchers), by the law's functions and the kind of law.
_KERNELS: dict[tuple, Any] = {}

#: what the kernel calls every tick, compiled into it rather than called (the pipeline's step,
#: the estimate, the position loop, the mixer, the RK4 step): a call copies its tuple arguments
#: (the pipeline's parameters and state are some hundreds of floats) and stops the optimiser at its
#: edge. About a quarter off a tick (the robustness study's flights of the adaptive PID-SMC: 1.6
#: against 2.1 µs, the same bits); the law's own functions stay calls, direct ones (kernel._kernel_law).
KERNEL_INLINE = (
    pipeline_mod.pipeline_step_sensed, pipeline_mod.pipeline_step_full_sensed, pipeline_mod.actuate,
    position_mod.position_step, mixer_mod.mix, estimate_mod.estimate_step, rigid_body.rigid_body_substep_lag,
)


def compiled_kernel(law_functions: LawFunctions, full_stack: bool, measures_accel: bool = False) -> Any:
    """The compiled kernel for a law's functions (compiled once per process and law; numba's
    cache keeps the compiled pieces on disk): a whole-stack law's pipeline, and the IMU's
    acceleration in the law's ``meas`` for a law that measures it."""
    key = (tuple(law_functions), full_stack, measures_accel)
    k = _KERNELS.get(key)
    if k is None:
        roots = (
            *kernel_mod.KERNEL_FUNCTIONS, *pipeline_mod.PURE_FUNCTIONS, *estimate_mod.PURE_FUNCTIONS,
            *rigid_body.PURE_FUNCTIONS, *MT_FUNCTIONS, *law_functions,
        )  # fmt: skip
        fns, _problems = pure_closure(roots)
        # the kernel calls the pipeline's step directly (no forwarding function in between: each
        # level copies the pipeline's parameters and state, some hundreds of floats, a tick)
        fly: dict[str, Any] = {}
        if measures_accel:
            fly["_sensed"] = kernel_mod._sensed_imu
        if full_stack:
            fly["pipeline_step_sensed"] = pipeline_mod.pipeline_step_full_sensed
        # the law's functions called directly, as constants (kernel_mod._kernel_law, inlined)
        rebind: dict[Callable[..., Any], Any] = {kernel_mod._kernel_law: {"_LAW": law_functions}}
        if fly:
            rebind[kernel_mod.fly_span] = fly
        twins = compile_pure(fns, rebind=rebind, inline=(*KERNEL_INLINE, kernel_mod._kernel_law))
        k = _KERNELS[key] = twins[kernel_mod.fly_span]
        # a process that flies compiled scores its flights compiled too (the σ low-pass's loop)
        score_compiled()
    return k


_ENTRIES: dict[tuple, Callable[..., Any] | None] = {}


def _entry_point(kernel: Any, args: tuple, flight: Any) -> Callable[..., Any]:
    """The kernel's compiled entry point for ``args`` (see :meth:`_Bridge._call`): compiled (or
    loaded from numba's cache) once per process for their types; raises
    :class:`KernelUnavailable` if numba cannot compile it."""
    quick = (id(kernel), _type_key(args))
    found: Any = _ENTRIES.get(quick, _MISSING)
    if found is _MISSING:
        typeof = numba_module().typeof
        sig = tuple(typeof(a) for a in args)
        key = (id(kernel), sig)
        found = _ENTRIES.get(key, _MISSING)
        if found is _MISSING:
            what = f"the flight kernel for the law {flight.law.name}"
            index = _cache_index(kernel)
            if index is not None and not os.path.exists(index):
                say_once(f"compiling {what} (once after an install or a change; cached on disk)...")
            t0 = time.perf_counter()
            try:
                kernel.compile(sig)
            except Exception as exc:  # the law is in the pure style but numba cannot type it (e.g. its state's shape changes)
                _ENTRIES[key] = _ENTRIES[quick] = None
                raise KernelUnavailable(_first_line(exc)) from None
            if kernel.stats.cache_misses.get(sig):
                say_once(f"compiled {what} in {time.perf_counter() - t0:.1f} s")
            found = _ENTRIES[key] = kernel.overloads[sig].entry_point  # (no dispatch: the types are known)
        _ENTRIES[quick] = found
    if found is None:
        raise KernelUnavailable("compiling it failed before in this process")
    return found  # type: ignore[no-any-return]


_MISSING = object()
_INT64 = (-(2**63), 2**63)


def _type_key(x: Any) -> Any:
    """What decides numba's type of ``x``, found much faster than ``numba.typeof`` (a kernel's
    arguments, some 60 values with nested NamedTuples, take ~1 ms to type: a campaign flight's
    twentieth). Equal keys, equal types: floats, booleans, ints within int64, tuples by their class
    and items, arrays by dtype, dimensions, layout and flags; anything else by its numba type."""
    t = type(x)
    if t is float or t is bool:
        return t
    if t is int:
        return t if _INT64[0] <= x < _INT64[1] else ("int", x >= 0)
    if isinstance(x, tuple):
        return (t, *[_type_key(v) for v in x])
    if t is np.ndarray:
        f = x.flags
        return (t, x.dtype.str, x.ndim, f.c_contiguous, f.f_contiguous, f.writeable, f.aligned)
    from smcpilot.jit import numba_module

    return ("typeof", numba_module().typeof(x))


class KernelUnavailable(Exception):
    """numba could not compile the kernel for this flight's law (the flight goes on in CPython)."""


def _first_line(exc: BaseException) -> str:
    lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
    return f"{type(exc).__name__}: {(lines[0] if lines else '')[:160]}"


_LAW_PROBLEMS: dict[tuple[str, int], list[str]] = {}


def fast_unsupported(core: FlightCore, plant: object, physics_hz: float, rate_hz: float, *, compile_new: bool = True) -> str | None:
    """Why this flight cannot use the compiled kernel at all (None: it can). Without
    ``compile_new``, a plug-in law whose kernel is not compiled yet flies in CPython: compiling it
    (10–30 s) would cost more than one flight saves, and a law being written changes often;
    campaigns (many flights) and ``SMCPILOT_JIT=1`` compile it. Says once why a law flies in CPython."""
    if not jit_enabled():
        return "compiled path off"
    if type(plant) is not RigidBodyPlant:
        return f"the plant is {type(plant).__name__}, not the rigid body"
    substeps = int(round(physics_hz / rate_hz))
    if substeps < 1 or abs(substeps * rate_hz - physics_hz) > 1e-9 * physics_hz:
        return "the physics rate is not a whole multiple of the control rate"
    if 1.0 / physics_hz > plant.max_step_s * (1.0 + 1e-9):
        return "the physics step is longer than the plant's largest step"
    law = core.flight.law
    problems = _LAW_PROBLEMS.get((law.name, id(law)))
    if problems is None:
        problems = _LAW_PROBLEMS[(law.name, id(law))] = law_problems(law)
    if problems:
        why = f"the control law {law.name} is not in the pure style ({problems[0]})"
        fast_note(why)
        return why
    if not compile_new and law.origin != "built-in" and os.environ.get(JIT_ENV, "").strip() != "1":
        index = _cache_index(compiled_kernel(core.flight.law_functions, law.full_stack, core.flight.measures_accel))
        if index is None or not os.path.exists(index):
            why = (f"the law {law.name} has no compiled kernel yet (compiling takes 10-30 s once; "
                   f"campaigns do it, or set {JIT_ENV}=1)")  # fmt: skip
            fast_note(why)
            return why
    return None


class _Bridge:
    """The kernel's arrays for one flight, and the moves between them and the live objects."""

    def __init__(self, core: FlightCore, plant: RigidBodyPlant, *, rate_hz: float, physics_hz: float, record: FastRecord | None,
                 log: Any = None) -> None:  # fmt: skip
        self.core = core
        self.plant = plant
        self.substeps = int(round(physics_hz / rate_hz))
        self.dt_phys = 1.0 / physics_hz
        self.step_us = int(round(self.dt_phys * 1e6))
        self.tick_us = self.step_us * self.substeps
        self.record = record
        self.log = log
        self.lg = np.zeros((CHUNK_TICKS + 1, kernel_mod.LOG_COLUMNS) if log is not None else (1, kernel_mod.LOG_COLUMNS))
        env = plant.env
        self.env = env
        self.faults = plant.faults
        self.plant_s = np.zeros(17)
        self.plant_f = np.zeros(6)
        self.env_f = np.zeros(4)
        self.gust = np.zeros(6)
        self.io = np.zeros(7, dtype=np.int64)
        #: the faults' gusts (rows of lab.fast.kernel.FG_COLUMNS) and sensor-fault program.
        self.fg = np.zeros((8, kernel_mod.FG_COLUMNS))
        self.sp = np.zeros((5, 5, 4))
        #: the kernel's scratch for a batch of Gaussian draws (15 sensor noises, 6 gusts, 5 per fault gust).
        self.zb = np.zeros(max(16, 5 * len(self.fg)))
        self.sn = np.zeros(5, dtype=np.int64)
        self.io_f = np.zeros(2)
        self.obs = np.zeros(17)
        self.fc_f = np.zeros(2)
        # a span of n ticks records at most n // every + 1 rows
        self.rec = np.zeros((CHUNK_TICKS // record.every + 2 if record is not None else 1, kernel_mod.ROW_COLUMNS))
        p = env.params
        self.gust_std = tuple(float(v) for v in env._std)
        self.gusts_on = bool(env.gusts_enabled)
        n = p.sensor_noise
        self.noise_on = bool(env.sensors.enabled)
        self.noise_std = (float(n.attitude_std_rad), float(n.body_rate_std_radps), float(n.position_std_m),
                          float(n.velocity_std_mps), float(n.accel_std_mps2))  # fmt: skip
        self._gust_rng: Any = env._gust_rng
        self._noise_rng: Any = env.sensors._rng
        self._empty_mt = (np.zeros(625, dtype=np.int64), np.zeros(2))
        f = self.faults
        self._delay_starts = tuple(sorted(x.start_s for x in f.faults if getattr(x, "mode", None) == "delay")) if f is not None else ()
        self.kernel = compiled_kernel(core.flight.law_functions, core.flight.law.full_stack, core.flight.measures_accel)
        self.imu_on = bool(core.flight.measures_accel)
        self.g_plant = float(plant.vehicle.gravity_mps2)
        self._entry: Callable[..., Any] | None = None

    # -- can the next tick be flown by the kernel, and for how many ticks ---------------------------
    def ticks_allowed(self, t_us: int, want: int) -> int:
        """How many ticks from ``t_us`` the kernel may fly (0: fly the next one in Python)."""
        core = self.core
        if core.ticks == 0 or core.failsafe or core.law_failed or core.estimate_status > EST_DEAD_RECKONING:
            return 0
        if core.flight.armed and core.commander.current.watch().kind == WATCH_ALWAYS:
            return 0
        f = self.faults
        n = want
        if f is not None:
            if f.events:
                return 0
            if f.sensing and not self._sensor_program(f):
                return 0  # a delay fault, or a stuck sensor before its first observation
            limit_s = f._next_s
            for d in self._delay_starts:
                if d > t_us * 1e-6:
                    limit_s = min(limit_s, d - MAX_DELAY_S)
            if limit_s < math.inf:
                # whole ticks that end (observation and every physics step included) before the limit
                end_us = (limit_s - TIME_EPS_S - 2e-6) * 1e6
                n = min(n, max(0, int((end_us - t_us) // self.tick_us)))
        return n

    def _sensor_program(self, f: Any) -> bool:
        """The acting sensor faults as the kernel's program (``self.sp``/``self.sn``); False: one
        of them is not for the kernel."""
        sp, sn = self.sp, self.sn
        sn[:] = 0
        for sensor, objs in f._by_sensor:
            si = SENSORS.index(sensor)
            if len(objs) > sp.shape[1]:
                return False
            for oi, o in enumerate(objs):
                mode = o.spec.mode
                if mode == "stuck":
                    if o.held is None:
                        return False
                    sp[si, oi] = (kernel_mod.SF_STUCK, *o.held)
                elif mode in ("bias", "noise"):
                    sp[si, oi] = (kernel_mod.SF_BIAS if mode == "bias" else kernel_mod.SF_NOISE, *o.vec)
                elif mode == "dropout":
                    sp[si, oi] = (kernel_mod.SF_DROPOUT, 0.0, 0.0, 0.0)
                else:
                    return False
            sn[si] = len(objs)
        return True

    # -- the moves ----------------------------------------------------------------------------------
    def fly(self, t_us: int, k: int, n: int) -> tuple[int, int, int]:
        """Fly up to ``n`` ticks in the kernel from tick ``k`` at ``t_us``: (ticks flown, code, t_us after)."""
        core, plant, env = self.core, self.plant, self.env
        flight = core.flight
        c = core.commander
        plant_s, plant_f = self.plant_s, self.plant_f
        plant_s[:] = plant._s
        plant_f[0] = plant._psi
        plant_f[1] = plant._input.psi_turns
        plant_f[2:5] = plant._accel
        plant_f[5] = plant._t_s
        env_paper = env.paper_disturbance
        f = self.faults
        gusts = list(f._gusts.values()) if f is not None else []
        if f is not None and f.physics_on:
            eff = f.motor_eff
            paper = env_paper or f.paper_disturbance
            add_forces = f.forces_on
            ff, ft = (f._step_force, f._step_torque) if gusts else (f.force_world_n, f.torque_body_n_m)
        else:
            eff, paper, add_forces, ff, ft = _ONES4, env_paper, False, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)
        if len(gusts) > len(self.fg):
            self.fg = np.zeros((len(gusts), kernel_mod.FG_COLUMNS))
            self.zb = np.zeros(max(16, 5 * len(gusts)))
        fg = self.fg
        for i, g in enumerate(gusts):
            fg[i, 0:5] = g.state
            fg[i, 5:11] = (g.force_std, g.torque_std, g.tau_s, g.last_h, g.a, g.b)
        fgmt, fggs = mt_export(f._gust_rng) if (gusts and f is not None) else self._empty_mt
        sensing = f is not None and f.sensing
        if not sensing:
            self.sn[:] = 0
        fnmt, fngs = mt_export(f._noise_rng) if (sensing and f is not None) else self._empty_mt
        self.env_f[:] = (env._last_dt_s, env._a, env._b, env.params.gust_time_constant_s)
        wind = env.params.wind_force_n if self.gusts_on else env.force_world_n
        self.gust[:] = env._gust
        gmt, ggs = mt_export(self._gust_rng) if self.gusts_on else self._empty_mt
        nmt, ngs = mt_export(self._noise_rng) if self.noise_on else self._empty_mt
        cmd, armed = flight.pipeline_inputs(), flight.armed
        self.fc_f[0] = core.config.disarm_delay_s
        self.fc_f[1] = c.ground_armed_s
        io = self.io
        io[:] = 0
        io[6] = core._est_missing
        plan = core.plan
        plan_next = plan.next_t_s
        rec = self.record
        t_call = time.perf_counter()
        ps, es, out, est = self._call(
            flight.params, flight.pipeline_state, cmd, armed, flight.position_hold, core.config.period_s,
            core._est_params, core._est, core.t0_us, self.fc_f, tuple(core.commander.current.watch()) if armed else (0, 0.0, 0.0, 0.0, 0.0),
            plan_next, plant_s, plant_f, plant.params, eff, paper, self.env_f, wind, add_forces, ff, ft,
            self.gust, self.gust_std, self.gusts_on, self.noise_std, self.noise_on, gmt, ggs, nmt, ngs,
            t_us, self.step_us, self.substeps, self.dt_phys, n, self.rec, rec.every if rec is not None else 0,
            rec.truth if rec is not None else False, k, "sigma" in flight.law.diagnostics, io, self.io_f, self.obs,
            self.log is not None, self.lg, flight._diag_mask, int(c.current.number),
            fg, len(gusts), fgmt, fggs, self.sp, self.sn, fnmt, fngs, core.estimate_status, self.zb, self.imu_on, self.g_plant,
        )  # fmt: skip
        flown, code, n_rec, t_after = int(io[0]), int(io[1]), int(io[2]), int(io[3])
        kt = KERNEL_TIME
        kt[0] += 1
        kt[1] += flown
        kt[2] += time.perf_counter() - t_call
        # back into the live objects
        if self.gusts_on:
            mt_import(self._gust_rng, gmt, ggs)
            env._gust = [float(v) for v in self.gust]
            env._last_dt_s, env._a, env._b = float(self.env_f[0]), float(self.env_f[1]), float(self.env_f[2])
            env._publish()
        if self.noise_on:
            mt_import(self._noise_rng, nmt, ngs)
        if gusts:
            assert f is not None
            mt_import(f._gust_rng, fgmt, fggs)
            for i, g in enumerate(gusts):
                g.state = [float(v) for v in fg[i, 0:5]]
                g.last_h, g.a, g.b = float(fg[i, 8]), float(fg[i, 9]), float(fg[i, 10])
        if sensing:
            assert f is not None
            mt_import(f._noise_rng, fnmt, fngs)
        if flown or code == kernel_mod.SPAN_DIVERGED:
            plant._s = tuple(float(v) for v in plant_s)
            plant._psi = float(plant_f[0])
            plant._accel = (float(plant_f[2]), float(plant_f[3]), float(plant_f[4]))
            plant._t_s = float(plant_f[5])
            plant._input = StepInput(eff, paper, float(plant_f[1]))
            plant._obs_cache = None
        diverged = code == kernel_mod.SPAN_DIVERGED
        if flown or diverged:
            last_us = t_after if diverged else t_after - self.tick_us
            core.ticks += flown + diverged
            core.t_us = last_us
            core._est = es
            state = VehicleState(*est)
            core.state = state
            c.observe(CommanderInput(state, True, False, es, core.estimate_status == EST_OK))
            c.resume((last_us - core.t0_us) * 1e-6, float(self.io_f[1]))
            core.states_missing += int(io[4])
            core.dead_reckoning_ticks += int(io[5])
            core._est_missing = int(io[6])
            flight.pipeline_state = ps
            core.last = self._tick_output(out)
            if n_rec and rec is not None:
                rec.recorder.add_rows(self.rec[:n_rec])
            if self.log is not None:
                self.log.on_rows(self.lg[: flown + diverged])
        if diverged:
            raise DivergenceError("rigid-body plant state became non-finite", float(self.io_f[0]))
        if code in (kernel_mod.SPAN_EVENT, kernel_mod.SPAN_OVERFLOW):
            self._hand_over()
        return flown, code, t_after

    def _call(self, *args: Any) -> Any:
        """The kernel, on these arguments (compiled for their types, :func:`_entry_point`)."""
        entry = self._entry
        if entry is None:
            entry = self._entry = _entry_point(self.kernel, args, self.core.flight)
        return entry(*args)

    def _tick_output(self, out: tuple) -> TickOutput:
        core = self.core
        f = core.flight
        motors, u, limited, s, sigma, chi, u_law, u_dot, ref, _touchdown, d_hat = out
        if f.armed:
            sm, gm, cm, dm = f._diag_mask
            diag = Diagnostics(s if sm else None, sigma if gm else None, chi if cm else None, u_law, u_dot if dm else None)
            po = PipelineOutput(motors, u, limited, diag, ref, d_hat)
        else:
            po = PipelineOutput((0.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0), (False,) * 4, None, _NAN4)
        return TickOutput(po.motors, f.armed, core.flags(), int(core.commander.current.number), po, ())

    def _hand_over(self) -> None:
        """The observation the kernel drew for the tick it stopped before becomes the plant's."""
        o = self.obs
        plant = self.plant
        s = plant._s
        euler = (float(o[7]), float(o[8]), float(o[9]))
        f = self.faults
        sensing = f is not None and f.sensing
        if sensing and self.sn[SENSORS.index("attitude")]:
            quat = _NAN4 if o[16] != 0.0 else quat_from_euler(*euler)
        elif self.noise_on and self.noise_std[0] > 0.0:
            quat = quat_from_euler(*euler)
        else:
            quat = (s[6], s[7], s[8], s[9])
        obs = VehicleObservation(
            float(o[0]), (float(o[1]), float(o[2]), float(o[3])), (float(o[4]), float(o[5]), float(o[6])), euler,
            (float(o[10]), float(o[11]), float(o[12])), (float(o[13]), float(o[14]), float(o[15])), (s[13], s[14], s[15], s[16]), quat,
        )  # fmt: skip
        if f is not None and not sensing:
            obs = f.observe(obs)  # the sensors are healthy: it keeps its history (delay faults) and clock
        plant._obs_cache = obs  # (with sensor faults acting, the kernel applied them)


def fast_simulate(
    core: FlightCore,
    plant: RigidBodyPlant,
    n_ticks: int,
    *,
    rate_hz: float,
    physics_hz: float,
    py_tick: Callable[[int, int], int],
    stop: Callable[[], bool] | None,
    record: FastRecord | None,
    log: Any = None,
) -> int:
    """Fly ``n_ticks`` ticks: the kernel where it can, ``py_tick(k, t_us) -> t_us after`` (one tick
    in Python, the CPython runner's own) where it cannot. Returns the ticks flown."""
    bridge = _Bridge(core, plant, rate_hz=rate_hz, physics_hz=physics_hz, record=record, log=log)
    t_us = 0
    k = 0
    python_run = 0
    compiled = True
    while k < n_ticks:
        n = bridge.ticks_allowed(t_us, min(CHUNK_TICKS, n_ticks - k)) if (python_run == 0 and compiled) else 0
        if n > 0:
            try:
                flown, code, t_us = bridge.fly(t_us, k, n)
            except KernelUnavailable as exc:  # raised before the kernel ran: nothing has changed
                fast_note(f"the control law {core.flight.law.name} could not be compiled ({exc})")
                compiled = False
                continue
            k += flown
            if code == kernel_mod.SPAN_DONE:
                if stop is not None and stop():
                    return k
                continue
            # the next tick is eventful: Python flies it (with the observation the kernel drew)
            if flown == 0:
                python_run = 8  # it stopped at once: a few ticks in Python before trying again
        t_us = py_tick(k, t_us)
        k += 1
        if python_run:
            python_run -= 1
        if stop is not None and stop():
            return k
    return k


def fast_note(why: str) -> None:
    say_once(f"flying in CPython: {why}")

