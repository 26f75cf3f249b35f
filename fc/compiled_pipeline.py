"""The FC process's pipeline tick, compiled: state held in compiled memory, one array across.

In the FC process the pipeline (:func:`fc.pipeline.pipeline_step_sensed`: prefilters, position loop,
observer, law, mixer, anti-windup) runs once per received state. Calling its compiled twin once per
tick with the NamedTuples it takes would cost more than CPython (numba unboxes the nested
parameters and state on every call); so here the carried state and the flattened parameters live
in numba typed lists of one element (:class:`HeldPipeline`), the per-tick inputs and outputs in one
float64 array (``io``: :data:`IO_STATE` …), the law's functions by address in another (:func:`smcpilot.jit.addressed`), and the call
goes to the compiled entry point directly (no dispatch on argument types). A tick then costs a few µs
instead of the CPython pipeline's 20-30 µs, and gives the same motor commands bit for bit
(``tests/test_compiled_pipeline.py``).

:class:`fc.flight.FlightControl` uses it once :meth:`HeldPipeline.attach` succeeded; its
``pipeline_state`` then reads and writes the held state (rarely: on arming, a yaw set-point, a
landing). A tick whose law output is not finite is not kept: the caller flies it again in CPython,
which raises or reports as it always has.

The compiled code is cached on disk (numba's cache, named after a hash of every source it was
compiled from). :func:`attach_compiled` uses it when it is cached (loading takes about half a
second) or compiles it first (10-30 s once) when asked to wait; otherwise the FC flies in CPython.
"""

from __future__ import annotations

import math
import os
import time
from typing import Any

from fc import pipeline as pipeline_mod
from fc.control.law import LawFunctions
from fc.control.purity import pure_closure
from fc.pipeline import PipelineInputs, VehicleState, pipeline_step_full_sensed, pipeline_step_sensed
from smcpilot.jit import addressed, cache_index, compile_lock, compile_pure, jit_unavailable_reason, numba_module, say_once
from smcpilot.jit import compile_in_background as background_compile
from smcpilot.jit import entry_point as _entry

#: the ``io`` array: inputs (the estimate: 12 floats of :class:`fc.pipeline.VehicleState`; the
#: commander's :class:`fc.pipeline.PipelineInputs`, bools as 0/1; dt in s; the IMU's acceleration,
#: paper frame, for a law that measures it) ...
IO_STATE = 0
IO_CMD = 12
IO_DT = 20
IO_SENSED = 21
#: ... and outputs, each a 4-vector: motors, realised u, limited (0/1), S, sigma, chi_hat, u_law,
#: u_dot, references (phi_r, theta_r, psi_r, z_r), d_hat; then touchdown (0/1) and kept (1: the
#: tick's outputs were finite and its new state is held; 0: nothing changed).
IO_OUT = 24
IO_TOUCHDOWN = IO_OUT + 40
IO_KEPT = IO_OUT + 41
IO_SIZE = IO_OUT + 42

_isfinite = math.isfinite

#: numba's typed list, for the compiled twins (set by :func:`_twins`: importing this module loads no numba).
List: Any = None


def _step(ps, st, cmd, pp, dt_s, law, sensed):  # type: ignore[no-untyped-def]
    """The pipeline's tick (rebound to the whole-stack pipeline for a whole-stack law)."""
    return pipeline_step_sensed(ps, st, cmd, pp, dt_s, law, sensed)


def _step_full(ps, st, cmd, pp, dt_s, law, sensed):  # type: ignore[no-untyped-def]
    """The whole-stack pipeline's tick."""
    return pipeline_step_full_sensed(ps, st, cmd, pp, dt_s, law, sensed)


def _no_sensed(io):  # type: ignore[no-untyped-def]
    """Nothing sensed beyond the state (a law that does not measure acceleration)."""
    return ()


def _imu_sensed(io):  # type: ignore[no-untyped-def]
    """The IMU's acceleration (paper frame, m/s^2) the caller put in ``io``."""
    return (io[IO_SENSED], io[IO_SENSED + 1], io[IO_SENSED + 2])


def pipeline_tick_held(ps_box, pp_box, io, law_box):  # type: ignore[no-untyped-def]
    """:func:`held_tick` with the law's functions held in ``law_box[0]`` (first-class functions:
    a tuple of functions passed as an argument would cost ~16 µs a call to unbox)."""
    return held_tick(ps_box, pp_box, io, law_box[0])


def held_tick(ps_box, pp_box, io, law):  # type: ignore[no-untyped-def]
    """One pipeline tick on the held state ``ps_box[0]`` and parameters ``pp_box[0]``, the inputs
    in ``io`` (see :data:`IO_STATE`); writes the outputs to ``io`` and keeps the new state when
    they are finite. Returns 1 when kept, 0 when not (the state is then unchanged)."""
    new, out = held_step(ps_box, pp_box, io, law)
    if held_write(io, out):
        ps_box[0] = new
        return 1
    return 0


def held_step(ps_box, pp_box, io, law):  # type: ignore[no-untyped-def]
    """The pipeline's tick on the held state and parameters and the inputs in ``io``: (new state,
    outputs), nothing written or kept (:func:`held_tick` does both; :mod:`fc.lockstep_kernel`
    keeps the state only once the tick's answer is made)."""
    st = VehicleState(
        io[0], io[1], io[2], io[3], io[4], io[5], io[6], io[7], io[8], io[9], io[10], io[11]
    )  # fmt: skip
    cmd = PipelineInputs(io[12], io[13], io[14], io[15], io[16] != 0.0, io[17] != 0.0, io[18] != 0.0, io[19])
    return _step(ps_box[0], st, cmd, pp_box[0], io[IO_DT], law, _no_sensed(io))


def held_write(io, out):  # type: ignore[no-untyped-def]
    """The pipeline's outputs ``out`` into ``io`` (:data:`IO_OUT` on, touchdown, kept); 1 when
    they are finite (the tick may be kept), else 0."""
    motors, u, limited, s, sigma, chi, u_law, u_dot, ref, touchdown, d_hat = out
    o = IO_OUT
    for i in range(4):
        io[o + i] = motors[i]
        io[o + 4 + i] = u[i]
        io[o + 8 + i] = 1.0 if limited[i] else 0.0
        io[o + 12 + i] = s[i]
        io[o + 16 + i] = sigma[i]
        io[o + 20 + i] = chi[i]
        io[o + 24 + i] = u_law[i]
        io[o + 28 + i] = u_dot[i]
        io[o + 32 + i] = ref[i]
        io[o + 36 + i] = d_hat[i]
    io[IO_TOUCHDOWN] = 1.0 if touchdown else 0.0
    kept = _isfinite(motors[0] + motors[1] + motors[2] + motors[3]) and _isfinite(u_law[0] + u_law[1] + u_law[2] + u_law[3])
    io[IO_KEPT] = 1.0 if kept else 0.0
    return 1 if kept else 0


def held_new(value):  # type: ignore[no-untyped-def]
    """A typed list holding ``value`` (compiled only: made in compiled code, as its reads and
    writes below, so that no typed-list method is compiled at run time: each would stall the
    first tick that used it for about half a second)."""
    box = List()
    box.append(value)
    return box


def held_get(box):  # type: ignore[no-untyped-def]
    """What ``box`` holds."""
    return box[0]


def held_set(box, value):  # type: ignore[no-untyped-def]
    """Hold ``value`` in ``box`` instead."""
    box[0] = value
    return 0


#: the functions compiled here beside the pipeline's own (:data:`fc.pipeline.PURE_FUNCTIONS`).
HELD_FUNCTIONS = (pipeline_tick_held, held_tick, held_step, held_write, _step, _step_full, _no_sensed, _imu_sensed, held_new, held_get, held_set)


class NotPure(Exception):
    """The law is not in the pure style (:mod:`fc.control.purity`): it flies in CPython."""


def first_line(exc: BaseException) -> str:
    """``Type: the first line of the message`` (numba's errors run to pages)."""
    lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
    return f"{type(exc).__name__}: {(lines[0] if lines else '')[:160]}"


def law_function_types(law: Any, flight: Any) -> tuple[Any, LawFunctions]:
    """The numba type of a law's compiled functions as first-class functions, and the functions
    by address (:func:`smcpilot.jit.addressed`): so a compiled caller is typed (and cached) for
    the law's signatures rather than for its dispatchers (which numba does not cache).
    ``law``: the compiled twins of the law's functions; ``flight``: a
    :class:`fc.flight.FlightControl` flying that law (its parameters and state give the types)."""
    numba = numba_module()
    types = numba.types
    typeof = numba.typeof
    ps = flight.pipeline_state
    f64 = types.float64
    k_t = typeof(flight.params.law)
    state_t = typeof(ps.law)
    v4 = types.UniTuple(f64, 4)
    sensed = 3 if flight.measures_accel else 0  # the IMU's acceleration follows the state in meas
    if flight.law.full_stack:
        init_args = (typeof(VehicleState(*(0.0,) * 12)), k_t)
        step_args = (types.UniTuple(f64, 12 + sensed), types.UniTuple(f64, 16), state_t, f64, k_t, v4, typeof(ps.u_prev))
    else:
        init_args = (types.UniTuple(f64, 8), k_t)
        step_args = (types.UniTuple(f64, 8 + sensed), types.UniTuple(f64, 16), state_t, f64, k_t, v4, typeof(ps.u_prev))
    sigs = []
    for fn, fargs in ((law.initial_state, init_args), (law.step, step_args)):
        fn.compile(fargs)
        sigs.append(fn.overloads[fargs].signature)
    new_t = sigs[1].return_type[1]
    aw_args = (state_t, new_t, v4, types.UniTuple(types.boolean, 4), k_t)
    law.anti_windup.compile(aw_args)
    sigs.append(law.anti_windup.overloads[aw_args].signature)
    law_t = types.NamedTuple(tuple(types.FunctionType(s) for s in sigs), LawFunctions)
    return law_t, LawFunctions(*(addressed(fn, s) for fn, s in zip(law, sigs)))


_TWINS: dict[tuple, dict[Any, Any]] = {}


def _twins(flight: Any) -> dict[Any, Any]:
    """The compiled twins of this module's functions, the pipeline's and the flight's law's
    (made once per process and law)."""
    global List
    key = law_key(flight)
    found = _TWINS.get(key)
    if found is None:
        from numba.typed import List

        from fc import estimate as estimate_mod
        from fc import lockstep_kernel as plain_mod
        from fc import state_kernel as state_mod
        from fc.commander import ground_armed_count
        from fc.modes.base import watch_holds

        # the lockstep kernel calls the same compiled step (fc.lockstep_kernel), with the state's
        # decoder, the answer's encoder and the estimate
        plain = (*plain_mod.PLAIN_FUNCTIONS, *state_mod.KERNEL_FUNCTIONS, *estimate_mod.PURE_FUNCTIONS, watch_holds, ground_armed_count)
        fns, problems = pure_closure((*HELD_FUNCTIONS, *pipeline_mod.PURE_FUNCTIONS, *flight.law_functions))
        more, _more_problems = pure_closure(plain)  # (byte and array work, as fc.state_kernel's: tests/test_lockstep_kernel.py)
        fns = (*fns, *(f for f in more if f not in fns))
        own = tuple(f"{f.__name__} " for f in HELD_FUNCTIONS)  # (this module's use range and typed lists, compiled only)
        problems = [p for p in problems if not p.startswith(own)]
        if problems:  # (the pipeline's functions are pure: these are the law's)
            raise NotPure(f"the law {flight.law.name} is not in the pure style ({problems[0]})")
        step = _step_full if flight.law.full_stack else _step
        sensed = _imu_sensed if flight.measures_accel else _no_sensed
        twins = compile_pure(fns, rebind={held_step: {"_step": step, "_no_sensed": sensed}, pipeline_tick_held: {}})
        found = _TWINS[key] = twins
    return found


class HeldPipeline:
    """A flight's pipeline state and parameters in compiled memory, and its compiled tick.

    Made by :func:`attach_compiled`; :class:`fc.flight.FlightControl` calls :meth:`tick` and goes
    through :meth:`state` / :meth:`set_state` for its ``pipeline_state``."""

    def __init__(self, entry: Any, ps_box: Any, pp_box: Any, law_box: Any, law_key: tuple, access: tuple) -> None:
        import numpy as np

        self._entry = entry
        #: compiled entry points: the state's get and set, the parameters' set.
        self._get_ps, self._set_ps, self._set_pp = access
        self._law = law_box
        self._ps = ps_box
        self._pp = pp_box
        #: the law (its functions, whole-stack, measures acceleration) this was compiled for.
        self.law_key = law_key
        #: the per-tick inputs and outputs (:data:`IO_STATE` ...).
        self.io = np.zeros(IO_SIZE)
        #: ticks flown compiled.
        self.ticks = 0
        #: numba's types of the held state's, the parameters' and the law's boxes (for
        #: :func:`plain_entry`, compiled with the same ones).
        self.box_types: tuple = ()

    def state(self) -> Any:
        return self._get_ps(self._ps)

    def set_state(self, ps: Any) -> None:
        self._set_ps(self._ps, ps)

    def set_params(self, pp: Any) -> None:
        """New flattened parameters (same law); raises if their types changed."""
        self._set_pp(self._pp, pp)

    def tick(self, st: tuple, cmd: tuple, dt_s: float, sensed: tuple) -> list[float] | None:
        """One tick: the outputs from ``io[IO_OUT]`` on (a list), or None when the law's output
        was not finite (nothing kept)."""
        io = self.io
        io[0:12] = st
        io[12:20] = cmd
        io[IO_DT] = dt_s
        if sensed:
            io[IO_SENSED : IO_SENSED + 3] = sensed
        if not self._entry(self._ps, self._pp, io, self._law):
            return None
        self.ticks += 1
        return io[IO_OUT : IO_TOUCHDOWN + 1].tolist()  # type: ignore[no-any-return]


def law_key(flight: Any) -> tuple:
    return (tuple(flight.law_functions), flight.law.full_stack, flight.measures_accel)


def attach_compiled(flight: Any, *, compile_new: bool) -> str | None:
    """Give ``flight`` (a :class:`fc.flight.FlightControl`) its compiled tick. Returns None when
    attached, else why not (the flight goes on in CPython). ``compile_new``: compile it now when
    it is not cached yet (10-30 s once, said on stderr); else only a cached one is used."""
    why = jit_unavailable_reason()
    if why is not None:
        return why
    law = flight.law
    try:
        twins = _twins(flight)
        held_fn = twins[pipeline_tick_held]
        index = cache_index(held_fn)
        cached = index is not None and os.path.exists(index)
        if not cached and not compile_new:
            return f"the compiled pipeline for the law {law.name} is not cached yet"
        what = f"the FC's compiled pipeline for the law {law.name}"
        if not cached:
            say_once(f"compiling {what} (once after an install or a change; cached on disk)...")
        t0 = time.perf_counter()
        numba = numba_module()
        typeof = numba.typeof
        law_t, law_fns = law_function_types(LawFunctions(*(twins[f] for f in flight.law_functions)), flight)
        box_t = numba.types.ListType
        ps_t, pp_t = typeof(flight.pipeline_state), typeof(flight.params)
        new_e = _entry(twins[held_new], (law_t,))
        law_box = new_e(law_fns)
        ps_box = _entry(twins[held_new], (ps_t,))(flight.pipeline_state)
        pp_box = _entry(twins[held_new], (pp_t,))(flight.params)
        access = (
            _entry(twins[held_get], (box_t(ps_t),)), _entry(twins[held_set], (box_t(ps_t), ps_t)),
            _entry(twins[held_set], (box_t(pp_t), pp_t)),
        )  # fmt: skip
        entry = _entry(held_fn, (box_t(ps_t), box_t(pp_t), numba.types.float64[::1], box_t(law_t)))
        if held_fn.stats.cache_misses:
            say_once(f"compiled {what} in {time.perf_counter() - t0:.1f} s")
    except NotPure as exc:
        return str(exc)
    except Exception as exc:  # numba cannot type this law (its state changes shape, say)
        return f"the law {law.name} could not be compiled ({first_line(exc)})"
    held = HeldPipeline(entry, ps_box, pp_box, law_box, law_key(flight), access)
    held.box_types = (box_t(ps_t), box_t(pp_t), box_t(law_t))
    flight.attach_held(held)
    return None


def plain_entry(flight: Any, est_state: Any, est_params: Any, *, compile_new: bool) -> Any:
    """:func:`fc.lockstep_kernel.plain_state` compiled for ``flight``'s held pipeline (attached by
    :func:`attach_compiled`) and the estimate's state and parameters: a
    :class:`fc.lockstep_kernel.PlainLockstep`, or None (not cached and not ``compile_new``, or
    not compilable: the FC flies every tick the ordinary way)."""
    from fc.lockstep_kernel import PlainLockstep, plain_state
    from smcpilot.jit import cached_entry

    held = flight._held
    if held is None or not held.box_types or jit_unavailable_reason() is not None:
        return None
    try:
        t = numba_module().types
        typeof = numba_module().typeof
        ps_t, pp_t, law_t = held.box_types
        sig = (
            t.Bytes(t.uint8, 1, "C", readonly=True), t.int64, ps_t, pp_t, t.float64[::1], law_t, typeof(est_state),
            typeof(est_params), t.float64[::1], t.int64[::1], t.float64[::1], t.uint64[::1], t.uint32[::1], t.float32[::1],
            t.int64[::1], t.uint8[::1], t.uint8[::1], t.uint8[::1],
        )  # fmt: skip
        fn = _twins(flight)[plain_state]
        index = cache_index(fn)
        cached = index is not None and os.path.exists(index)
        what = f"the FC's lockstep kernel for the law {flight.law.name}"
        if not cached and compile_new:
            say_once(f"compiling {what} (once after an install or a change; cached on disk)...")
        t0 = time.perf_counter()
        entry = cached_entry(fn, sig, compile_new=compile_new)
        if not cached and entry is not None:
            say_once(f"compiled {what} in {time.perf_counter() - t0:.1f} s")
    except Exception as exc:  # numba's typing or lowering errors: the ordinary path flies, said once
        say_once(f"fc: the lockstep kernel could not be compiled ({first_line(exc)}); every tick flies the ordinary way")
        return None
    return None if entry is None else PlainLockstep(entry)


def compile_in_background(controller: str) -> int | None:
    """Start a process that compiles (and caches) the FC's pipeline for ``controller``, unless one
    is compiling already (:func:`smcpilot.jit.compile_in_background`); its pid, or None."""
    return background_compile("fc.compiled_pipeline", controller)


def main(argv: list[str] | None = None) -> int:
    """``python -m fc.compiled_pipeline LAW``: compile and cache the FC's pipeline for LAW."""
    import argparse

    from fc.config import FcConfig
    from fc.flight import FlightControl
    from smcpilot.vehicle import DEFAULT_VEHICLE

    p = argparse.ArgumentParser(prog="python -m fc.compiled_pipeline", description=main.__doc__)
    p.add_argument("law", help="the control law (a built-in name or a plug-in, as --controller takes it)")
    args = p.parse_args(argv)
    if hasattr(os, "nice"):  # a background job: the flights running meanwhile keep their CPU
        os.nice(19)
    if compile_lock(blocking=False) is None:
        print("another process is compiling; nothing done")
        return 0
    config = FcConfig(controller=args.law)
    flight = FlightControl(config, DEFAULT_VEHICLE)
    why = attach_compiled(flight, compile_new=True)
    if why is None:
        from fc.estimate import ESTIMATOR_START, EstimatorConfig, estimator_params
        from fc.state_kernel import compiled_answer_encoder, compiled_decoder

        # what a lockstep FC loads with it: the state datagram's decoder, the answer's encoder, the kernel
        compiled_decoder(compile_new=True)
        compiled_answer_encoder(1, 1, 0, flight.diag_mask, compile_new=True)
        plain_entry(flight, ESTIMATOR_START, estimator_params(EstimatorConfig(), config.period_s), compile_new=True)
    print("compiled" if why is None else f"not compiled: {why}")
    return 0 if why is None else 1


if __name__ == "__main__":
    raise SystemExit(main())
