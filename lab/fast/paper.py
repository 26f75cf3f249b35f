"""The paper's ODE runner, compiled: :func:`lab.closed_loop.simulate`'s whole RK4 loop in one call.

``smcpilot paper`` integrates the paper's plant (:func:`sim_bridge.plants.paper.paper_plant_derivatives`)
with a controller's continuous-time form (the controller's states in the ODE) by classical RK4 at
1 ms, or runs the controller sampled (zero-order hold) with the plant alone integrated in between.
:func:`fly_continuous` and :func:`fly_sampled` are those two loops, written once in the pure style
against the same pure functions the classes call (the law's :func:`~fc.control.pid_smc.pid_smc_derivatives`,
:func:`~fc.control.sign_smc.sign_smc_output`, :func:`~fc.control.cascade_pid.cascade_pid_output`
and :func:`~fc.control.cascade_pid.cascade_pid_derivatives`, their sampled steps, the plant, the
divergence check :func:`lab.closed_loop.divergence_code`) and compiled per law family with
:func:`smcpilot.jit.compile_pure` (the name ``_closed`` / ``_sample`` bound to the family's
adapter). They write the recorded rows into preallocated arrays.

Divergence is Python's to report: the compiled loop stops *before* a step whose sample the check
rejects or whose new state is not finite, and hands the state at the start of that step to the
CPython loop, which flies the rest (so the time and the reason, an arithmetic failure included,
are CPython's own). That is enough: CPython raises only on ``cos``/``sin`` of an infinite value
(the law's ``|sigma|^delta`` cannot overflow with delta in (0, 1), its divisors are floored), and
an infinite stage state needs an infinite stage derivative, which makes the new state non-finite.

:func:`fly_compiled` is what ``simulate`` calls: None (and the reason said once) when the run
cannot be compiled — the compiled paths are off (``SMCPILOT_JIT=0``), the reference is a function
of time, the plant is not :class:`~sim_bridge.plants.paper.PaperPlant`, the controller is not one
of the three built-in classes, or numba failed.
"""

from __future__ import annotations

import math
import os
import time
from typing import Any, NamedTuple

import numpy as np

from fc.control.base import Diagnostics
from fc.control.cascade_pid import CascadePid, cascade_pid_derivatives, cascade_pid_output, cascade_pid_step
from fc.control.pid_smc import PidSmc, pid_smc_command, pid_smc_derivatives, pid_smc_step, pid_smc_step_measured
from fc.control.purity import pure_closure
from fc.control.sign_smc import SignSmc, sign_smc_output, sign_smc_step
from lab.closed_loop import divergence_code
from sim_bridge.plants.paper import PaperPlant, paper_plant_derivatives
from smcpilot.jit import cache_index, compile_pure, jit_enabled, say_once

__all__ = ["CompiledPart", "fly_compiled", "FIRST_CALL_S", "unsupported"]

_isfinite = math.isfinite
_NAN4 = (math.nan, math.nan, math.nan, math.nan)
#: wall seconds of each runner's first call in this process (compiling it, or loading it from the
#: disk cache, and the flight): (family, "continuous" | "sampled") -> s.
FIRST_CALL_S: dict[tuple[str, str], float] = {}


# -- the continuous-time closed loop of each law family (state array: 12 plant states, then the law's) --
def _closed_pid_smc(t, ya, ka, ref, pp, cp):  # type: ignore[no-untyped-def]
    """Writes d(state)/dt of the combined state ``ya`` into ``ka``; returns (u, w^2, S, sigma, chi_hat)."""
    meas = (ya[0], ya[1], ya[2], ya[3], ya[4], ya[5], ya[6], ya[7])
    y = (ya[0], ya[1], ya[2], ya[3], ya[4], ya[5], ya[6], ya[7], ya[8], ya[9], ya[10], ya[11])
    cs = (ya[12], ya[13], ya[14], ya[15], ya[16], ya[17], ya[18], ya[19], ya[20], ya[21], ya[22], ya[23])
    u = pid_smc_command(cs)
    dp, acc, w = paper_plant_derivatives(t, y, u, pp)
    dc, s, sg, chi, _ud = pid_smc_derivatives(meas, ref, cs, cp, acc, cp.oracle)
    for j in range(12):
        ka[j] = dp[j]
        ka[12 + j] = dc[j]
    return u, w, s, sg, chi


def _closed_sign_smc(t, ya, ka, ref, pp, cp):  # type: ignore[no-untyped-def]
    meas = (ya[0], ya[1], ya[2], ya[3], ya[4], ya[5], ya[6], ya[7])
    y = (ya[0], ya[1], ya[2], ya[3], ya[4], ya[5], ya[6], ya[7], ya[8], ya[9], ya[10], ya[11])
    cs = (ya[12], ya[13], ya[14], ya[15])
    u, e, s = sign_smc_output(meas, ref, cs, cp)
    dp, _acc, w = paper_plant_derivatives(t, y, u, pp)
    for j in range(12):
        ka[j] = dp[j]
    for j in range(4):
        ka[12 + j] = e[j]
    return u, w, _NAN4, s, _NAN4


def _closed_cascade_pid(t, ya, ka, ref, pp, cp):  # type: ignore[no-untyped-def]
    meas = (ya[0], ya[1], ya[2], ya[3], ya[4], ya[5], ya[6], ya[7])
    y = (ya[0], ya[1], ya[2], ya[3], ya[4], ya[5], ya[6], ya[7], ya[8], ya[9], ya[10], ya[11])
    cs = (ya[12], ya[13], ya[14], ya[15], ya[16], ya[17], ya[18], ya[19], ya[20], ya[21])
    u, e = cascade_pid_output(meas, ref, cs, cp)
    dc = cascade_pid_derivatives(meas, cs, e, cp)
    dp, _acc, w = paper_plant_derivatives(t, y, u, pp)
    for j in range(12):
        ka[j] = dp[j]
    for j in range(10):
        ka[12 + j] = dc[j]
    return u, w, _NAN4, _NAN4, _NAN4


def _closed(t, ya, ka, ref, pp, cp):  # type: ignore[no-untyped-def]
    """The family's closed loop (bound per family when compiled; the PID-SMC's by default)."""
    return _closed_pid_smc(t, ya, ka, ref, pp, cp)


# -- the sampled form of each law family: (u, new state, S, sigma, chi_hat) --------------------------
def _sample_pid_smc(meas, ref, c, dt_s, acc, use_acc, cp):  # type: ignore[no-untyped-def]
    if use_acc and cp.oracle:
        u, new, d = pid_smc_step_measured(meas, ref, c, dt_s, cp, acc)
    else:
        u, new, d = pid_smc_step(meas, ref, c, dt_s, cp)
    return u, new, d.s, d.sigma, d.chi_hat


def _sample_sign_smc(meas, ref, c, dt_s, acc, use_acc, cp):  # type: ignore[no-untyped-def]
    u, new, s = sign_smc_step(meas, ref, c, dt_s, cp)
    return u, new, _NAN4, s, _NAN4


def _sample_cascade_pid(meas, ref, c, dt_s, acc, use_acc, cp):  # type: ignore[no-untyped-def]
    u, new = cascade_pid_step(meas, ref, c, dt_s, cp)
    return u, new, _NAN4, _NAN4, _NAN4


def _sample(meas, ref, c, dt_s, acc, use_acc, cp):  # type: ignore[no-untyped-def]
    """The family's sampled step (bound per family when compiled; the PID-SMC's by default)."""
    return _sample_pid_smc(meas, ref, c, dt_s, acc, use_acc, cp)


def _record(i, t, y, ref, u, w, s, sg, chi, o_t, o_x, o_r, o_u, o_w, o_s, o_sg, o_chi):  # type: ignore[no-untyped-def]
    """Row ``i`` of the record: time, the 12 plant states (``y``'s leading ones), x_d per channel,
    u, w^2 and the diagnostics."""
    o_t[i] = t
    for j in range(12):
        o_x[i, j] = y[j]
    o_r[i, 0] = ref[0]
    o_r[i, 1] = ref[4]
    o_r[i, 2] = ref[8]
    o_r[i, 3] = ref[12]
    for j in range(4):
        o_u[i, j] = u[j]
        o_w[i, j] = w[j]
        o_s[i, j] = s[j]
        o_sg[i, j] = sg[j]
        o_chi[i, j] = chi[j]


def fly_continuous(ya, ref, pp, cp, n_steps, h, k1, k2, k3, k4, yt, o_t, o_x, o_r, o_u, o_w, o_s, o_sg, o_chi):  # type: ignore[no-untyped-def]
    """:func:`lab.closed_loop.simulate`'s continuous-time loop from step 0: plant and law states in
    ``ya`` (updated), one RK4 step of ``h`` a sample. Returns the number of steps flown and
    recorded: ``n_steps + 1``, or fewer when the next step is Python's (``ya`` then holds its
    starting state)."""
    n = ya.shape[0]
    h2 = 0.5 * h
    h6 = h / 6.0
    for i in range(n_steps + 1):
        t = i * h
        u, w, s, sg, chi = _closed(t, ya, k1, ref, pp, cp)
        if divergence_code(ya, u) != 0:
            return i
        _record(i, t, ya, ref, u, w, s, sg, chi, o_t, o_x, o_r, o_u, o_w, o_s, o_sg, o_chi)
        if i == n_steps:
            break
        for j in range(n):
            yt[j] = ya[j] + h2 * k1[j]
        _closed(t + h2, yt, k2, ref, pp, cp)
        for j in range(n):
            yt[j] = ya[j] + h2 * k2[j]
        _closed(t + h2, yt, k3, ref, pp, cp)
        for j in range(n):
            yt[j] = ya[j] + h * k3[j]
        _closed(t + h, yt, k4, ref, pp, cp)
        finite = True
        for j in range(n):
            v = ya[j] + h6 * (k1[j] + 2.0 * (k2[j] + k3[j]) + k4[j])
            yt[j] = v
            if not _isfinite(v):
                finite = False
        if not finite:
            return i
        for j in range(n):
            ya[j] = yt[j]
    return n_steps + 1


def fly_sampled(ya, c, ref, pp, cp, n_steps, h, substeps, k1, k2, k3, k4, yt, o_t, o_x, o_r, o_u, o_w, o_s, o_sg, o_chi):  # type: ignore[no-untyped-def]
    """:func:`lab.closed_loop.simulate`'s sampled-data loop from step 0: the law steps every
    ``substeps`` steps (its state ``c``), the plant (``ya``, updated) takes RK4 steps of ``h`` with
    the input held. Returns (steps flown and recorded, the law's state, the held u, S, sigma,
    chi_hat), all as they stand at the start of the first step not flown."""
    dt_ctrl = substeps * h
    h2 = 0.5 * h
    h6 = h / 6.0
    u = _NAN4
    s = _NAN4
    sg = _NAN4
    chi = _NAN4
    for i in range(n_steps + 1):
        t = i * h
        y = (ya[0], ya[1], ya[2], ya[3], ya[4], ya[5], ya[6], ya[7], ya[8], ya[9], ya[10], ya[11])
        meas = (ya[0], ya[1], ya[2], ya[3], ya[4], ya[5], ya[6], ya[7])
        un = u
        cn = c
        sn = s
        sgn = sg
        chin = chi
        if i % substeps == 0:
            if i == 0:
                un, cn, sn, sgn, chin = _sample(meas, ref, c, dt_ctrl, _NAN4, False, cp)
            else:
                acc = paper_plant_derivatives(t, y, u, pp)[1]
                un, cn, sn, sgn, chin = _sample(meas, ref, c, dt_ctrl, acc, True, cp)
        k1t, _acc, w = paper_plant_derivatives(t, y, un, pp)
        if divergence_code(y, un) != 0:
            return i, c, u, s, sg, chi
        _record(i, t, y, ref, un, w, sn, sgn, chin, o_t, o_x, o_r, o_u, o_w, o_s, o_sg, o_chi)
        if i == n_steps:
            break
        for j in range(12):
            k1[j] = k1t[j]
            yt[j] = ya[j] + h2 * k1t[j]
        k2t = paper_plant_derivatives(t + h2, (yt[0], yt[1], yt[2], yt[3], yt[4], yt[5], yt[6], yt[7], yt[8], yt[9], yt[10], yt[11]), un, pp)[0]
        for j in range(12):
            k2[j] = k2t[j]
            yt[j] = ya[j] + h2 * k2t[j]
        k3t = paper_plant_derivatives(t + h2, (yt[0], yt[1], yt[2], yt[3], yt[4], yt[5], yt[6], yt[7], yt[8], yt[9], yt[10], yt[11]), un, pp)[0]
        for j in range(12):
            k3[j] = k3t[j]
            yt[j] = ya[j] + h * k3t[j]
        k4t = paper_plant_derivatives(t + h, (yt[0], yt[1], yt[2], yt[3], yt[4], yt[5], yt[6], yt[7], yt[8], yt[9], yt[10], yt[11]), un, pp)[0]
        finite = True
        for j in range(12):
            v = ya[j] + h6 * (k1[j] + 2.0 * (k2[j] + k3[j]) + k4t[j])
            yt[j] = v
            if not _isfinite(v):
                finite = False
        if not finite:
            return i, c, u, s, sg, chi
        for j in range(12):
            ya[j] = yt[j]
        u = un
        c = cn
        s = sn
        sg = sgn
        chi = chin
    return n_steps + 1, c, u, s, sg, chi


#: the runners' own functions (compiled with the laws', the plant's and the divergence check).
RUNNER_FUNCTIONS = (fly_continuous, fly_sampled, _record, _closed, _sample)

#: per law family: the classes, the closed loop, the sampled step, which diagnostics exist (S, sigma, chi_hat).
_FAMILIES: dict[str, tuple[tuple[type, ...], Any, Any, tuple[bool, bool, bool]]] = {
    "pid_smc": ((PidSmc,), _closed_pid_smc, _sample_pid_smc, (True, True, True)),
    "sign_smc": ((SignSmc,), _closed_sign_smc, _sample_sign_smc, (False, True, False)),
    "cascade_pid": ((CascadePid,), _closed_cascade_pid, _sample_cascade_pid, (False, False, False)),
}


def _family(controller: object) -> str | None:
    for name, (classes, _c, _s, _d) in _FAMILIES.items():
        if type(controller) in classes:
            return name
    return None


class _Runners(NamedTuple):
    continuous: Any
    sampled: Any


_RUNNERS: dict[str, _Runners | None] = {}


def _runners(family: str) -> _Runners:
    r = _RUNNERS.get(family)
    if r is None:
        _classes, closed, sample, _diag = _FAMILIES[family]
        fns, _problems = pure_closure((*RUNNER_FUNCTIONS, closed, sample, divergence_code, paper_plant_derivatives))
        twins = compile_pure(fns, rebind={fly_continuous: {"_closed": closed}, fly_sampled: {"_sample": sample}})
        r = _RUNNERS[family] = _Runners(twins[fly_continuous], twins[fly_sampled])
    return r


def unsupported(controller: object, plant: object, reference: object) -> str | None:
    """Why this run cannot be compiled (None: it can), with the compiled paths on."""
    if callable(reference):
        return "the reference is a function of time"
    if type(plant) is not PaperPlant:
        return f"the plant is {type(plant).__name__}, not the paper's plant"
    if _family(controller) is None:
        return f"the controller {getattr(controller, 'name', '?')} ({type(controller).__name__}) has no compiled form"
    return None


class CompiledPart:
    """What the compiled loop flew: ``n`` recorded rows, and the state at the start of step ``n``
    (for the CPython loop to go on from, unless ``done``)."""

    def __init__(self, rows: dict[str, np.ndarray | None], n: int, done: bool, y: list[float], c: tuple[float, ...] | None,
                 u: tuple[float, ...] | None, diag: Diagnostics | None) -> None:  # fmt: skip
        self.rows = rows
        self.n = n
        self.done = done
        self.y = y
        self.c = c
        self.u = u
        self.diag = diag


def fly_compiled(
    controller: Any, plant: Any, ref: tuple[float, ...], y0: list[float], c0: list[float], n_steps: int, h: float, substeps: int | None
) -> CompiledPart | None:
    """Fly ``simulate``'s loop compiled from step 0 (``substeps``: None continuous, else the
    sampled form's steps a control period); None when it cannot (said once why)."""
    if not jit_enabled():
        return None
    why = unsupported(controller, plant, ref)
    family = _family(controller)
    if why is None and family is not None and _RUNNERS.get(family, 0) is None:
        why = "compiling it failed before in this process"
    if why is not None or family is None:
        say_once(f"the paper's ODE runner flies in CPython ({why})")
        return None
    mode = "continuous" if substeps is None else "sampled"
    try:
        runners = _runners(family)
    except Exception as exc:
        _RUNNERS[family] = None
        say_once(f"the paper's ODE runner flies in CPython (numba: {type(exc).__name__}: {str(exc).splitlines()[0][:160] if str(exc) else ''})")
        return None
    fly = runners.continuous if substeps is None else runners.sampled
    rows = n_steps + 1
    nx = len(y0)
    n_all = nx + len(c0) if substeps is None else nx
    ya = np.array(y0 + c0 if substeps is None else y0, dtype=np.float64)
    work = [np.zeros(n_all) for _ in range(5)]
    o_t = np.zeros(rows)
    o_x = np.zeros((rows, nx))
    o4 = [np.zeros((rows, 4)) for _ in range(6)]
    pp = plant.consts
    cp = controller.consts
    first = (family, mode) not in FIRST_CALL_S
    what = f"the paper's ODE runner ({mode}) for {family}"
    if first:
        index = cache_index(fly)
        if index is None or not os.path.exists(index):
            say_once(f"compiling {what} (once after an install or a change; cached on disk)...")
    misses = sum(fly.stats.cache_misses.values()) if first else 0
    t0 = time.perf_counter()
    try:
        if substeps is None:
            n = fly(ya, ref, pp, cp, n_steps, h, *work, o_t, o_x, *o4)
            c = u = None
            diag = None
        else:
            n, c, u, s, sg, chi = fly(ya, tuple(c0), ref, pp, cp, n_steps, h, substeps, *work, o_t, o_x, *o4)
    except Exception as exc:  # numba could not type or compile it
        _RUNNERS[family] = None
        say_once(f"the paper's ODE runner flies in CPython (numba: {type(exc).__name__}: {(str(exc).splitlines() or [''])[0][:160]})")
        return None
    if first:
        FIRST_CALL_S[(family, mode)] = time.perf_counter() - t0
        if sum(fly.stats.cache_misses.values()) > misses:
            say_once(f"compiling {what} took {time.perf_counter() - t0:.1f} s")
    has_s, has_sg, has_chi = _FAMILIES[family][3]
    if substeps is not None:
        if n == 0:
            c, u, diag = tuple(c0), None, None
        else:
            diag = Diagnostics(s if has_s else None, sg if has_sg else None, chi if has_chi else None, tuple(u), None)  # type: ignore[arg-type]
    out: dict[str, np.ndarray | None] = {
        "t": o_t[:n], "x": o_x[:n], "x_ref": o4[0][:n], "u": o4[1][:n], "w_sq": o4[2][:n],
        "s": o4[3][:n] if has_s else None, "sigma": o4[4][:n] if has_sg else None, "chi_hat": o4[5][:n] if has_chi else None,
    }  # fmt: skip
    return CompiledPart(out, n, n == rows, ya.tolist(), c, u, diag)
