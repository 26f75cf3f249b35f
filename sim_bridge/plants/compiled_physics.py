"""The simulator process's physics, compiled: every vehicle's steps of a control period in one call.

Between two control periods the simulator integrates each vehicle's rigid body for a few physics
steps (:meth:`sim_bridge.plants.rigid_body.RigidBodyPlant.step`: one or more RK4 sub-steps of
:func:`~sim_bridge.plants.rigid_body.rigid_body_substep` each, and the heading's turns). In CPython
that costs about 9 µs a physics step and vehicle; called once per sub-step from Python, a compiled
sub-step would save little (its tuples are unboxed on every call). Here one compiled call flies all
the steps of all the vehicles: the per-vehicle inputs and the state go in one float64 array
(a row per vehicle, :data:`IO_STATE` ...), the flattened constants in another, and the call goes
to the compiled entry point directly.

It flies only what it can fly the same, bit for bit, as :meth:`RigidBodyPlant.step` would: a span
in which nothing drawn or timed acts on the physics (no gust process, in the environment or a
fault; no timed fault starting or stopping; the wind and the faults' constant forces, torques,
rotor efficiencies and the paper's disturbances are fine). Otherwise :meth:`CompiledPhysics.fly`
says so and the caller steps the plants in Python, as before. A span whose physics becomes
non-finite is handed back with the step and vehicle that failed; the caller raises as the plant
would have (``tests/test_compiled_physics.py``).

A lockstep swarm flies one vehicle a call, and then makes its state datagram:
:meth:`CompiledPhysics.fly_state` does both in one compiled call (:mod:`sim_bridge.fused_state`)
when the observation is the truth (:func:`plain_observation`), leaving the plant as :meth:`fly`
and :meth:`PlantBase.observe` would (``tests/test_fused_state.py``).

The compiled code is cached on disk (numba's cache, named after a hash of every source it was
compiled from): :func:`load` uses it when it is cached or compiles it first (a few seconds once)
when asked to; ``python -m sim_bridge.plants.compiled_physics`` compiles it ahead.
"""

from __future__ import annotations

import math
import os
import sys
import time
from collections.abc import Sequence
from typing import Any

from sim_bridge.environment import Environment
from sim_bridge.faults import SimFaults
from sim_bridge.plants import rigid_body as rb
from sim_bridge.plants.rigid_body import (
    RigidBodyParams,
    RigidBodyPlant,
    StepInput,
    heading_turns,
    rigid_body_substep_lag,
    rigid_body_targets,
    rotor_lag,
)
from sim_bridge.sensors import SensorNoise
from smcpilot.errors import DivergenceError
from smcpilot.jit import cache_index, compile_pure, entry_point, jit_unavailable_reason, say_once

#: a vehicle's row of the ``io`` array: the 17 states (in and out), the motor commands (4, in [0, 1]),
#: armed (0/1), active (0: not stepped), the force (world NWU, N) and torque (body FLU, N m) held
#: over the span, the rotor efficiencies (4), the paper's disturbances (0/1), the heading's whole
#: turns and its value at the start (rad; both in and out), the last step's acceleration (world,
#: m/s^2; out), the sub-steps a physics step and their length (s); the truth's Euler angles at the
#: end (ZYX of FLU in NWU, rad, roll and yaw in [-pi, pi); out, of the fused call only:
#: :mod:`sim_bridge.fused_state`).
IO_STATE = 0
IO_CMD = 17
IO_ARMED = 21
IO_ACTIVE = 22
IO_FORCE = 23
IO_TORQUE = 26
IO_EFF = 29
IO_PAPER = 33
IO_TURNS = 34
IO_PSI = 35
IO_ACCEL = 36
IO_NSUB = 39
IO_H = 40
IO_EULER = 41
IO_SIZE = 44
#: a vehicle's row of the constants: :class:`RigidBodyParams` with ground contact as 0/1 and its
#: ``deriv`` tuple (12 floats) after the first 13 fields.
PP_SIZE = 25
#: what the call returns: the physics steps completed; if fewer than asked, the failing vehicle's
#: row and the time at the end of the failing sub-step (s) in ``out``.
OUT_SIZE = 2



def _params_of(pp, i):  # type: ignore[no-untyped-def]
    """Row ``i`` of the constants as :class:`RigidBodyParams`."""
    return RigidBodyParams(
        pp[i, 0], pp[i, 1], pp[i, 2], pp[i, 3], pp[i, 4], pp[i, 5], pp[i, 6], pp[i, 7], pp[i, 8], pp[i, 9], pp[i, 10],
        pp[i, 11], pp[i, 12] != 0.0,
        (pp[i, 13], pp[i, 14], pp[i, 15], pp[i, 16], pp[i, 17], pp[i, 18], pp[i, 19], pp[i, 20], pp[i, 21], pp[i, 22],
         pp[i, 23], pp[i, 24]),
    )  # fmt: skip


def physics_span(io, pp, t_us0, dt_us, dt_s, n_steps, out):  # type: ignore[no-untyped-def]
    """Fly ``n_steps`` physics steps of ``dt_s`` seconds from ``t_us0`` µs (the k-th at
    ``(t_us0 + k dt_us) 1e-6`` s, as the simulator's clock counts) for every active row of ``io``,
    as :meth:`RigidBodyPlant.step` does: the steps outside, the vehicles inside. Returns the steps
    completed (``n_steps``: all; else the vehicle ``out[0]`` became non-finite at ``out[1]`` s and
    its row holds the state before the failing sub-step)."""
    n_veh = io.shape[0]
    for k in range(n_steps):
        t_s = (t_us0 + k * dt_us) * 1e-6
        for i in range(n_veh):
            if io[i, IO_ACTIVE] == 0.0:
                continue
            p = _params_of(pp, i)
            s = (io[i, 0], io[i, 1], io[i, 2], io[i, 3], io[i, 4], io[i, 5], io[i, 6], io[i, 7], io[i, 8], io[i, 9],
                 io[i, 10], io[i, 11], io[i, 12], io[i, 13], io[i, 14], io[i, 15], io[i, 16])  # fmt: skip
            targets = rigid_body_targets((io[i, IO_CMD], io[i, IO_CMD + 1], io[i, IO_CMD + 2], io[i, IO_CMD + 3]), io[i, IO_ARMED] != 0.0, p)
            force = (io[i, IO_FORCE], io[i, IO_FORCE + 1], io[i, IO_FORCE + 2])
            torque = (io[i, IO_TORQUE], io[i, IO_TORQUE + 1], io[i, IO_TORQUE + 2])
            eff = (io[i, IO_EFF], io[i, IO_EFF + 1], io[i, IO_EFF + 2], io[i, IO_EFF + 3])
            paper = io[i, IO_PAPER] != 0.0
            turns = io[i, IO_TURNS]
            psi0 = io[i, IO_PSI]
            n_sub = int(io[i, IO_NSUB])
            h = io[i, IO_H]
            accel = (io[i, IO_ACCEL], io[i, IO_ACCEL + 1], io[i, IO_ACCEL + 2])
            e_half = rotor_lag(h, p)
            for j in range(n_sub):
                t = t_s + j * h
                s, accel_j, ok = rigid_body_substep_lag(s, targets, force, torque, t, h, p, StepInput(eff, paper, turns), e_half,
                                                        psi0 if paper else 0.0)  # fmt: skip
                if not ok:  # as step() leaves it: the state before this sub-step, the turns so far
                    for m in range(17):
                        io[i, m] = s[m]
                    io[i, IO_ACCEL] = accel[0]
                    io[i, IO_ACCEL + 1] = accel[1]
                    io[i, IO_ACCEL + 2] = accel[2]
                    io[i, IO_TURNS] = turns
                    out[0] = i
                    out[1] = t + h
                    return k
                accel = accel_j
                psi0, turns = heading_turns(s, psi0, turns)
            for m in range(17):
                io[i, m] = s[m]
            io[i, IO_ACCEL] = accel[0]
            io[i, IO_ACCEL + 1] = accel[1]
            io[i, IO_ACCEL + 2] = accel[2]
            io[i, IO_TURNS] = turns
            io[i, IO_PSI] = psi0
    return n_steps


#: this module's functions compiled with the plant's.
SPAN_FUNCTIONS = (physics_span, _params_of)


def params_row(p: RigidBodyParams) -> tuple[float, ...]:
    """:class:`RigidBodyParams` flattened as a row of the constants (:data:`PP_SIZE` floats)."""
    return (*p[:12], 1.0 if p.ground_contact else 0.0, *p.deriv)


def steady(plant: Any, t_end_s: float) -> str | None:
    """Why ``plant`` cannot be flown compiled up to simulated time ``t_end_s`` (None: it can): only a
    rigid body, and nothing drawn or timed acting on its physics before then."""
    if type(plant) is not RigidBodyPlant:
        return f"the {type(plant).__name__} plant is stepped in Python"
    if plant.env.gusts_enabled:
        return "gusts are drawn in Python"
    faults = plant.faults
    if faults is not None and faults.quiet_until() <= t_end_s:
        return "a fault acts on the physics in this span"
    return None


def plain_observation(plant: Any) -> str | None:
    """Why ``plant``'s next observation might not be its truth (None: it is, unless a sensor fault
    starts at that very observation, which :meth:`CompiledPhysics.fly_state` checks after): only
    an :class:`Environment` without sensor noise, and no faults or :class:`SimFaults` with no
    sensor fault acting."""
    env = plant.env
    if type(env) is not Environment or type(env.sensors) is not SensorNoise or env.sensors.enabled:
        return "the environment's sensors add noise"
    faults = plant.faults
    if faults is not None and (type(faults) is not SimFaults or faults.sensing):
        return "a sensor fault acts"
    return None


_TWINS: dict[str, Any] = {}


def _twins() -> dict[Any, Any]:
    found = _TWINS.get("span")
    if found is None:
        found = _TWINS["span"] = compile_pure((*SPAN_FUNCTIONS, *rb.PURE_FUNCTIONS))
    return found


class CompiledPhysics:
    """The compiled span and its arrays for a set of plants (rows in their order)."""

    def __init__(self, entry: Any, plants: Sequence[Any]) -> None:
        import numpy as np

        self._entry = entry
        self._np = np
        self.plants = list(plants)
        n = len(self.plants)
        #: the per-vehicle rows (:data:`IO_STATE` ...) and the constants (:func:`params_row`).
        self.io = np.zeros((n, IO_SIZE))
        self.pp = np.zeros((n, PP_SIZE))
        self.out = np.zeros(OUT_SIZE + 1)  # (the fused call's steps completed after OUT_SIZE)
        self._rows = {id(p): i for i, p in enumerate(self.plants)}
        #: per row: (state, step input, force, torque, dt) as the last span left them (None: reload
        #: the row from the plant); the rows flown last time.
        self._known: list[tuple | None] = [None] * n
        self._active: list[int] = []
        for i, p in enumerate(self.plants):
            if isinstance(p, RigidBodyPlant):
                self.pp[i] = params_row(p.params)
        #: physics steps flown compiled (each counts once however many vehicles it stepped).
        self.steps = 0
        #: the fused physics and state datagram's entry point (:mod:`sim_bridge.fused_state`; None:
        #: not loaded, :meth:`fly_state` declines).
        self.fused: Any = None

    def fly(self, plants: Sequence[Any], commands: Sequence[Sequence[float]], armed: Sequence[bool],
            t_us0: int, dt_us: int, dt_s: float, n_steps: int, *, count: bool = True) -> str | None:  # fmt: skip
        """Step ``plants`` (a subset of :attr:`plants`, in their order) ``n_steps`` physics steps as
        their :meth:`RigidBodyPlant.step` would, called once a step at ``(t_us0 + k dt_us) 1e-6`` s
        for ``dt_s`` s. Returns None when done, or why it did not fly them (nothing changed: step
        them in Python). Raises :class:`DivergenceError` as the plant does (its state and time as
        Python leaves them), with the steps completed in :attr:`DivergenceError.steps_done`.
        ``count``: add the steps flown to :attr:`steps` (a caller flying the vehicles one at a time
        counts each step once itself)."""
        t_end = (t_us0 + n_steps * dt_us) * 1e-6
        for p in plants:
            why = steady(p, t_end)
            if why is not None:
                return why
        inputs = self._load(plants, commands, armed, dt_s)
        done = self._entry(self.io, self.pp, t_us0, dt_us, dt_s, n_steps, self.out)
        if count:
            self.steps += done
        self._store(inputs, done, t_us0, dt_us, dt_s, n_steps)
        return None

    def fly_state(self, plant: Any, command: Sequence[float], armed: bool, t_us0: int, dt_us: int, dt_s: float, n_steps: int,
                  enc: Any, gravity_mps2: float, t_us: int, seq: int) -> bytes | str | None:  # fmt: skip
        """:meth:`fly` for one plant (not counted in :attr:`steps`) and its state datagram, stamped
        ``t_us`` (µs), its packets numbered from ``seq``, in one compiled call (:attr:`fused`) with
        the encoder ``enc`` (:class:`sim_bridge.state_encoder.StateEncoder`; gravity in m/s^2).

        Returns why it did not fly (a str: nothing changed, fly and make the state as before); the
        datagram (flown, and the plant's observation made as :meth:`PlantBase.observe` makes it:
        the truth, its memo and the observation cache, the faults' observation bookkeeping); or
        None (flown and observed so, but the datagram is for CPython to make,
        :meth:`sim_bridge.app.SimVehicle.make_state`: a sensor fault started at this
        observation, or a value is beyond float32). Raises :class:`DivergenceError` as :meth:`fly`."""
        fused = self.fused
        if fused is None:
            return "the fused physics and state is not loaded"
        why = plain_observation(plant)
        if why is None:
            why = steady(plant, (t_us0 + n_steps * dt_us) * 1e-6)
        if why is not None:
            return why
        inputs = self._load((plant,), (command,), (armed,), dt_s, put_commands=False)
        out = self.out
        n: int = fused(self.io, self.pp, t_us0, dt_us, dt_s, n_steps, out, inputs[0][0], command[0], command[1], command[2], command[3],
                       1.0 if armed else 0.0, enc.vin, gravity_mps2, t_us, seq, enc.sysid, enc._tail, enc.out, enc._bits, enc._f32)  # fmt: skip
        row = self._store(inputs, int(out[2]), t_us0, dt_us, dt_s, n_steps)
        # the truth as RigidBodyPlant.truth() makes it (its Euler angles compiled), then observed as
        # PlantBase.observe() does (no sensor noise: the environment gives it back)
        tru = plant.remember_truth((row[IO_EULER], row[IO_EULER + 1], row[IO_EULER + 2]))
        faults = plant.faults
        obs = tru if faults is None else faults.observe(tru)
        plant._obs_cache = obs
        if obs is not tru or not n:
            return None
        enc.made += 1
        return enc.out[:n].tobytes()

    def _load(self, plants: Sequence[Any], commands: Sequence[Sequence[float]], armed: Sequence[bool], dt_s: float, *,
              put_commands: bool = True) -> list[tuple]:  # fmt: skip
        """Put ``plants``' rows in :attr:`io` (only the commands when a row holds what the last span
        left; not even those unless ``put_commands``: the fused call puts them), the others
        inactive: (row, plant, step input, force, torque) of each."""
        io = self.io
        rows = self._rows
        known = self._known
        inputs = []
        active = []
        for p, cmd, on in zip(plants, commands, armed):
            i = rows[id(p)]
            u, force, torque = p.held_input(p._input)
            k = known[i]
            if k is not None and k[0] is p._s and k[1] == u and k[2] == force and k[3] == torque and k[4] == dt_s:
                # the row holds this plant's state as the last span left it: only the commands change
                if put_commands:
                    io[i, IO_CMD : IO_ACTIVE + 1] = (cmd[0], cmd[1], cmd[2], cmd[3], 1.0 if on else 0.0, 1.0)
            else:
                n = math.ceil(dt_s / p.max_step_s - 1e-9)
                if n < 1:
                    n = 1
                io[i, :IO_EULER] = (*p._s, cmd[0], cmd[1], cmd[2], cmd[3], 1.0 if on else 0.0, 1.0, *force, *torque, *u.motor_eff,
                                    1.0 if u.paper_disturbance else 0.0, u.psi_turns, p._psi, *p._accel, n, dt_s / n)  # fmt: skip
            inputs.append((i, p, u, force, torque))
            active.append(i)
        if active != self._active:  # the rows flown last time that are not flown now
            for i in self._active:
                if i not in active:
                    io[i, IO_ACTIVE] = 0.0
            self._active = active
        return inputs

    def _store(self, inputs: list[tuple], done: int, t_us0: int, dt_us: int, dt_s: float, n_steps: int) -> list[float]:
        """Put what the span left in :attr:`io` (``done`` steps of ``n_steps`` completed) back in
        the plants of ``inputs`` (:meth:`_load`), as their steps would have; raise
        :class:`DivergenceError` for a failed span. The last row stored, as floats."""
        io = self.io
        known = self._known
        failed = int(self.out[0]) if done < n_steps else -1
        row: list[float] = []
        for i, p, u, force, torque in inputs:
            # the steps this vehicle completed: in the failing step, those before the failing one flew it
            flown = n_steps if failed < 0 else done + 1 if i < failed else done
            if flown == 0 and i != failed:
                continue
            row = io[i].tolist()
            p._s = s = tuple(row[:17])
            p._accel = (row[IO_ACCEL], row[IO_ACCEL + 1], row[IO_ACCEL + 2])
            turns = row[IO_TURNS]
            if turns != u.psi_turns:
                u = StepInput(u.motor_eff, u.paper_disturbance, turns)
            p._input = u
            known[i] = (s, u, force, torque, dt_s) if failed < 0 else None
            if flown > 0:
                p._psi = row[IO_PSI]
                p._t_s = (t_us0 + (flown - 1) * dt_us) * 1e-6 + dt_s
                p._obs_cache = None
        if failed >= 0:
            exc = DivergenceError("rigid-body plant state became non-finite", float(self.out[1]))
            exc.steps_done = done  # type: ignore[attr-defined]
            exc.vehicle = failed  # type: ignore[attr-defined]
            raise exc
        return row


def _sig() -> tuple:
    from numba import types

    arr2 = types.float64[:, ::1]
    return (arr2, arr2, types.int64, types.int64, types.float64, types.int64, types.float64[::1])


def load(plants: Sequence[Any], *, compile_new: bool) -> tuple[CompiledPhysics | None, str | None]:
    """The compiled physics for ``plants`` (None and why not): from the cache, or compiled first
    when ``compile_new`` (a few seconds once, said on stderr)."""
    why = jit_unavailable_reason()
    if why is not None:
        return None, why
    if not any(isinstance(p, RigidBodyPlant) for p in plants):
        return None, "no rigid-body plant"
    try:
        twins = _twins()
        fn = twins[physics_span]
        index = cache_index(fn)
        cached = index is not None and os.path.exists(index)
        if not cached and not compile_new:
            return None, "the compiled physics is not cached yet"
        t0 = time.perf_counter()
        if not cached:
            say_once("compiling the simulator's physics (once after an install or a change; cached on disk)...")
        entry = entry_point(fn, _sig())
        if not cached:
            say_once(f"compiled the simulator's physics in {time.perf_counter() - t0:.1f} s")
        return CompiledPhysics(entry, plants), None
    except Exception as exc:  # numba's typing or lowering errors: fly in Python, say why
        return None, f"the simulator's physics could not be compiled ({str(exc).splitlines()[0] if str(exc) else type(exc).__name__})"


def main(argv: list[str] | None = None) -> int:
    """``python -m sim_bridge.plants.compiled_physics``: compile and cache the simulator's physics."""
    args = sys.argv[1:] if argv is None else argv
    if args and args[0] in ("-h", "--help"):
        print("usage: python -m sim_bridge.plants.compiled_physics\n\nCompile (and cache on disk) the simulator's"
              " physics span, so later simulator processes load it instead of stepping in Python.")  # fmt: skip
        return 0
    from smcpilot.vehicle import DEFAULT_VEHICLE

    phys, why = load([RigidBodyPlant(DEFAULT_VEHICLE)], compile_new=True)
    if phys is None:
        print(f"python -m sim_bridge.plants.compiled_physics: not compiled: {why}", file=sys.stderr)
        return 1
    from sim_bridge.proximity import compiled_pair_distances
    from sim_bridge.state_encoder import compiled_encoder

    compiled_encoder(1, compile_new=True)  # (the state datagram's encoder, loaded with the physics)
    from sim_bridge.fused_state import compiled_fused

    compiled_fused(compile_new=True)  # (the lockstep swarm's physics and state datagram in one call)
    compiled_pair_distances(compile_new=True)  # (a swarm's separation check, likewise)
    print("the simulator's physics is compiled and cached")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
