"""The simulator's active faults: timed faults of the scenario plus the live ``SIM_*`` parameters.

One :class:`SimFaults` per plant (built by :mod:`sim_bridge.build`, so the simulator process and
the in-process runner fly the same faults with the same random streams). It is evaluated at
simulated time, never the wall clock:

- per physics step (:meth:`SimFaults.advance`, called by the plant before each integration step
  starting at ``t_s``) it publishes the four rotor efficiencies :attr:`~SimFaults.motor_eff`, the
  extra force :attr:`~SimFaults.force_world_n` (world NWU, N) and torque
  :attr:`~SimFaults.torque_body_n_m` (body FLU, N m) — step forces and torques plus gusts — and
  whether the paper's disturbances act (:attr:`~SimFaults.paper_disturbance`);
- per observation (:meth:`SimFaults.observe`, the plant's noisy observation at the control rate)
  it applies the sensor faults;
- every fault start and stop is recorded as a :class:`FaultEvent` (time, MAVLink severity,
  ``"SIM: motor 1 at 70%"``) for the caller to announce (:meth:`SimFaults.take_events`).

Timing: a timed fault acts on the physics steps and the observations whose time ``t`` satisfies
``start_s <= t < stop_s`` (to within :data:`TIME_EPS_S`, far below a physics step), so it starts
and stops on the physics step that begins at its time. A live parameter change acts from the
simulated time it is applied at (the next physics step, the next observation).

Combining faults: the efficiencies of several motor faults on one rotor multiply (timed ones and
``SIM_ENGINE_MUL``/``SIM_MOT_OFF``); step forces and torques add, and so do gusts; several sensor
faults on one sensor apply in the order delay, stuck, bias, noise, dropout.

Sensor faults (values in the sensor's wire frame, converted once with :mod:`smcpilot.frames`):

- **stuck**: the sensor's value at the first observation of the fault, held;
- **bias**: added (gyro rad/s FRD, accel m/s^2 NED, attitude rad roll/pitch/yaw FRD, position m
  NED, velocity m/s NED);
- **noise**: extra white Gaussian noise of that std per axis, from the faults' own stream;
- **dropout**: NaN in the sensor's fields (the simulator keeps sending, the FC sees "not measured");
- **delay**: the sensor's value from ``delay`` seconds ago, from a ring buffer of the last
  :data:`smcpilot.faults.MAX_DELAY_S` seconds of observations (one per control tick): the newest
  observation at least ``delay`` old; before the buffer reaches that far back, the oldest.

Attitude faults act on the Euler angles (roll and yaw re-wrapped to [-pi, pi)) and the quaternion
is recomputed from them. Gusts are first-order Gauss-Markov processes discretised exactly as in
:mod:`sim_bridge.environment` (stationary start when the gust starts).

Randomness: two ``random.Random`` streams of their own (gusts, sensor noise), seeded from the
scenario seed by name, independent of the environment's streams: enabling or changing a fault
never changes the environment's wind, gust or sensor-noise draws.
"""

from __future__ import annotations

import math
import random
from collections.abc import Sequence
from dataclasses import replace
from typing import Any, NamedTuple

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from sim_bridge.sensors import VehicleObservation
from smcpilot.faults import (
    MAX_DELAY_S,
    SENSOR_FAULT_PARAM,
    SENSORS,
    SIM_GUST_TAU_S,
    SIM_PARAMS,
    FaultError,
    FaultSpec,
    check_sim_param,
    motor_efficiencies,
    sensor_fault_from_params,
    sim_param,
)
from smcpilot.frames import euler_frd_to_flu, frd_to_flu, ned_to_nwu, quat_from_euler, rates_frd_to_flu, wrap_pi

__all__ = ["FaultEvent", "SimFaults", "TIME_EPS_S", "SEVERITY_START", "SEVERITY_STOP", "SEVERITY_REJECTED"]

#: Times within this of a fault's start or stop count as reached (simulated time is a sum of steps).
TIME_EPS_S = 1e-7
#: MAVLink severities of the announcements: a fault starts, stops, a parameter change is refused.
SEVERITY_START = mavlink.MAV_SEVERITY_WARNING
SEVERITY_STOP = mavlink.MAV_SEVERITY_INFO
SEVERITY_REJECTED = mavlink.MAV_SEVERITY_ERROR
#: Prefix of every announcement.
PREFIX = "SIM: "

_NAN = math.nan
_NAN3 = (_NAN, _NAN, _NAN)
_NAN4 = (_NAN, _NAN, _NAN, _NAN)
_ONES4 = (1.0, 1.0, 1.0, 1.0)
_ZERO3 = (0.0, 0.0, 0.0)
_INF = math.inf
_exp = math.exp
_sqrt = math.sqrt
#: sensor -> index of its field in VehicleObservation.
_FIELD = {"gyro": 4, "accel": 5, "attitude": 3, "position": 1, "velocity": 2}
#: order in which several faults of one sensor apply.
_MODE_ORDER = {"delay": 0, "stuck": 1, "bias": 2, "noise": 3, "dropout": 4}
#: delay ring buffer: observations kept (MAX_DELAY_S at the highest control rate, 1 kHz, and a margin).
_BUFFER = int(MAX_DELAY_S * 1000) + 4


class FaultEvent(NamedTuple):
    """A fault started or stopped (or a live change was refused): simulated time, severity, text."""

    #: simulated time of the physics step or observation it acted on first, s (whole microseconds).
    t_s: float
    #: MAV_SEVERITY_*: WARNING for a start, INFO for a stop, ERROR for a refused parameter.
    severity: int
    #: the STATUSTEXT, e.g. ``SIM: motor 1 at 70%``.
    text: str


def _to_paper_frame(sensor: str, v: tuple[float, float, float]) -> tuple[float, float, float]:
    """A wire-frame sensor vector (NED / FRD) in the paper's frames (NWU / FLU)."""
    if sensor == "gyro":
        return rates_frd_to_flu(v[0], v[1], v[2])
    if sensor == "attitude":
        return euler_frd_to_flu(v[0], v[1], v[2])
    return ned_to_nwu(v)


class _SensorFault:
    """One acting sensor fault, prepared: the vector in the paper's frames, the held value."""

    __slots__ = ("spec", "order", "vec", "held")

    def __init__(self, spec: FaultSpec) -> None:
        self.spec = spec
        self.order = _MODE_ORDER[spec.mode]
        v = _to_paper_frame(spec.sensor, spec.value)
        if spec.mode == "noise":
            v = (abs(v[0]), abs(v[1]), abs(v[2]))
        self.vec = v
        #: stuck: the value held (None until the first observation of the fault).
        self.held: tuple[float, float, float] | None = None


class _Gust:
    """One gust's Gauss-Markov state: force N, E (world NED, N) and torque x, y, z (body FRD, N m)."""

    __slots__ = ("spec", "force_std", "torque_std", "tau_s", "state", "last_h", "a", "b")

    def __init__(self, spec: FaultSpec, rng: random.Random) -> None:
        self.spec = spec
        self.force_std = spec.force_std_n
        self.torque_std = spec.torque_std_n_m
        self.tau_s = spec.tau_s
        g = rng.gauss
        fs, ts = self.force_std, self.torque_std
        self.state = [
            g(0.0, fs) if fs > 0.0 else 0.0, g(0.0, fs) if fs > 0.0 else 0.0,
            g(0.0, ts) if ts > 0.0 else 0.0, g(0.0, ts) if ts > 0.0 else 0.0, g(0.0, ts) if ts > 0.0 else 0.0,
        ]  # fmt: skip
        self.last_h = -1.0
        self.a = 0.0
        self.b = 0.0

    def advance(self, h: float, rng: random.Random) -> None:
        if h != self.last_h:
            self.a = _exp(-h / self.tau_s)
            self.b = _sqrt(max(0.0, 1.0 - self.a * self.a))
            self.last_h = h
        a, b, g, st = self.a, self.b, rng.gauss, self.state
        fs, ts = self.force_std, self.torque_std
        if fs > 0.0:
            st[0] = a * st[0] + b * g(0.0, fs)
            st[1] = a * st[1] + b * g(0.0, fs)
        if ts > 0.0:
            st[2] = a * st[2] + b * g(0.0, ts)
            st[3] = a * st[3] + b * g(0.0, ts)
            st[4] = a * st[4] + b * g(0.0, ts)


#: a source of acting faults: ("timed", index in the scenario) or ("live", key).
_Source = tuple[str, object]


class SimFaults:
    """Timed faults plus live ``SIM_*`` parameters, evaluated at simulated time (see the module doc).

    Args:
        faults: the scenario's timed faults.
        seed: the scenario seed; the gust and sensor-noise streams of the faults are seeded from it.
    """

    def __init__(self, faults: Sequence[FaultSpec] = (), seed: int = 0) -> None:
        for i, f in enumerate(faults):
            if not isinstance(f, FaultSpec):
                raise FaultError(f"fault[{i + 1}] must be a FaultSpec, got {f!r}")
        self.faults: tuple[FaultSpec, ...] = tuple(faults)
        self.seed = int(seed)
        self._gust_rng = random.Random(f"smcpilot.faults.gust:{self.seed}")
        self._noise_rng = random.Random(f"smcpilot.faults.noise:{self.seed}")
        #: the live parameter values, in SIM_PARAMS order.
        self._params: dict[str, float] = {p.name: p.default for p in SIM_PARAMS}
        #: faults started and stopped so far (SIM_SUMMARY).
        self.started = 0
        self.stopped = 0
        #: announcements not yet taken.
        self.events: list[FaultEvent] = []
        #: rotors 1..4 thrust factors (a new tuple only when they change).
        self.motor_eff: tuple[float, float, float, float] = _ONES4
        #: extra force, world NWU, N, and torque, body FLU, N m, for the current step.
        self.force_world_n: tuple[float, float, float] = _ZERO3
        self.torque_body_n_m: tuple[float, float, float] = _ZERO3
        #: whether a fault switches the paper's disturbances on.
        self.paper_disturbance = False
        #: whether force_world_n / torque_body_n_m are to be added (any step force, torque or gust).
        self.forces_on = False
        #: whether anything acts on the physics (efficiency, force, torque, paper disturbance).
        self.physics_on = False
        #: whether any sensor fault acts.
        self.sensing = False
        self.reset()

    # -- state ------------------------------------------------------------------------------------
    def reset(self) -> None:
        """Back to the start of a flight: no timed fault acting, no history (live values kept)."""
        self._timed_active: set[int] = set()
        self._live: dict[str, FaultSpec] = self._live_faults(self._params, 0.0)
        self._gusts: dict[_Source, _Gust] = {}
        self._sensor_objs: dict[_Source, _SensorFault] = {}
        self._buf: list[VehicleObservation | None] = [None] * _BUFFER
        self._buf_n = 0  # observations pushed so far
        self._last_obs_t = -_INF
        self._next_s = min((f.start_s for f in self.faults), default=_INF)
        self._rebuild()

    @property
    def params(self) -> dict[str, float]:
        """The live parameter values by name (a copy)."""
        return dict(self._params)

    def param_value(self, name: str) -> float:
        """The value in force of the ``SIM_*`` parameter ``name`` (FaultError for an unknown name)."""
        sim_param(name)
        return self._params[name]

    @property
    def active(self) -> tuple[FaultSpec, ...]:
        """The faults acting now: timed ones (scenario order) and the live parameters'."""
        return tuple(self.faults[i] for i in sorted(self._timed_active)) + tuple(self._live.values())

    def take_events(self) -> list[FaultEvent]:
        """The announcements since the last call (oldest first)."""
        ev = self.events
        self.events = []
        return ev

    # -- live parameters --------------------------------------------------------------------------
    def set_param(self, name: str, value: float, t_s: float) -> float:
        """Set the ``SIM_*`` parameter ``name`` at simulated time ``t_s``; returns the value in force.

        :class:`FaultError` with the reason (unknown name, NaN, out of range, or a combination
        that is no valid fault, e.g. a negative noise std); the old value then stays. Faults that
        start or stop with the change are announced like timed ones.
        """
        v = check_sim_param(name, value)
        new = dict(self._params)
        new[name] = v
        live = self._live_faults(new, t_s)
        old = self._live
        for key in _LIVE_KEYS:
            a, b = old.get(key), live.get(key)
            if a is not None and b is not None and _same_live(a, b):
                live[key] = a  # unchanged: it goes on (a stuck sensor keeps its value, a gust its state)
            elif b is not None:
                self._announce(t_s, True, b)
            elif a is not None:
                self._announce(t_s, False, a)
        self._params = new
        self._live = live
        self._rebuild()
        return v

    @staticmethod
    def _live_faults(p: dict[str, float], t_s: float) -> dict[str, FaultSpec]:
        """The faults the parameter values ``p`` describe, by key (FaultError for an invalid pair)."""
        out: dict[str, FaultSpec] = {}
        eff = motor_efficiencies(p["SIM_ENGINE_MUL"], int(p["SIM_ENGINE_FAIL"]), int(p["SIM_MOT_OFF"]))
        for i, e in enumerate(eff):
            if e != 1.0:
                out[f"motor{i + 1}"] = FaultSpec("motor", start_s=t_s, motor=i + 1, efficiency=e)
        for sensor in SENSORS:
            name = SENSOR_FAULT_PARAM[sensor]
            spec = sensor_fault_from_params(sensor, int(p[name]), p[name + "_V"], t_s)
            if spec is not None:
                out[sensor] = spec
        f = (p["SIM_DIST_FN"], p["SIM_DIST_FE"], p["SIM_DIST_FD"])
        if f != _ZERO3:
            out["force"] = FaultSpec("force", start_s=t_s, force_ned_n=f)
        tq = (p["SIM_DIST_TX"], p["SIM_DIST_TY"], p["SIM_DIST_TZ"])
        if tq != _ZERO3:
            out["torque"] = FaultSpec("torque", start_s=t_s, torque_frd_n_m=tq)
        if p["SIM_GUST_F"] > 0.0 or p["SIM_GUST_T"] > 0.0:
            out["gust"] = FaultSpec("gust", start_s=t_s, force_std_n=p["SIM_GUST_F"], torque_std_n_m=p["SIM_GUST_T"], tau_s=SIM_GUST_TAU_S)
        if p["SIM_PAPER_DIST"] >= 1.0:
            out["paper"] = FaultSpec("paper_disturbance", start_s=t_s)
        return out

    def reject(self, t_s: float, reason: str) -> None:
        """Record a refused parameter change as an announcement (severity ERROR)."""
        self.events.append(FaultEvent(t_s, SEVERITY_REJECTED, PREFIX + reason))

    # -- per physics step ---------------------------------------------------------------------------
    def quiet_until(self) -> float:
        """The simulated time (s) before which :meth:`advance` changes nothing: no gust process to
        draw, and no timed fault due to start or stop (-inf while a gust acts). What acts meanwhile
        (:attr:`motor_eff`, :attr:`force_world_n` ...) stays as it is, unless a live parameter changes."""
        if self._gusts:
            return -_INF
        return self._next_s - TIME_EPS_S

    def advance(self, t_s: float, h: float) -> None:
        """Evaluate the faults for the physics step of ``h`` seconds starting at ``t_s``.

        Updates :attr:`motor_eff`, :attr:`force_world_n`, :attr:`torque_body_n_m`,
        :attr:`paper_disturbance` and :attr:`physics_on` (False: nothing acts on the physics).
        """
        if t_s >= self._next_s - TIME_EPS_S:
            self._update(t_s)
        gusts = self._gusts
        if gusts:
            rng = self._gust_rng
            sf = self._step_force
            st = self._step_torque
            fn, fe, tx, ty, tz = 0.0, 0.0, 0.0, 0.0, 0.0
            for g in gusts.values():
                g.advance(h, rng)
                s = g.state
                fn += s[0]
                fe += s[1]
                tx += s[2]
                ty += s[3]
                tz += s[4]
            fw = ned_to_nwu((fn, fe, 0.0))
            tb = frd_to_flu((tx, ty, tz))
            self.force_world_n = (sf[0] + fw[0], sf[1] + fw[1], sf[2] + fw[2])
            self.torque_body_n_m = (st[0] + tb[0], st[1] + tb[1], st[2] + tb[2])

    def _update(self, t_s: float) -> None:
        """Start and stop the timed faults whose times ``t_s`` has reached."""
        eps = TIME_EPS_S
        changed = False
        nxt = _INF
        for i, f in enumerate(self.faults):
            on = f.start_s - eps <= t_s < f.stop_s - eps
            if on != (i in self._timed_active):
                changed = True
                if on:
                    self._timed_active.add(i)
                else:
                    self._timed_active.discard(i)
                self._announce(t_s, on, f)
            if f.start_s - eps > t_s:
                nxt = min(nxt, f.start_s)
            elif f.stop_s - eps > t_s:
                nxt = min(nxt, f.stop_s)
        self._next_s = nxt
        if changed:
            self._rebuild()

    def _announce(self, t_s: float, start: bool, f: FaultSpec) -> None:
        t_s = round(t_s, 6)  # the simulator's clock counts whole microseconds; t_s is a float sum of steps
        if start:
            self.started += 1
            self.events.append(FaultEvent(t_s, SEVERITY_START, PREFIX + f.describe()))
        else:
            self.stopped += 1
            self.events.append(FaultEvent(t_s, SEVERITY_STOP, PREFIX + f.describe_stop()))

    def _acting(self) -> list[tuple[_Source, FaultSpec]]:
        return [(("timed", i), self.faults[i]) for i in sorted(self._timed_active)] + [
            (("live", k), f) for k, f in self._live.items()
        ]

    def _rebuild(self) -> None:
        """Recompute what acts from the acting faults (on a start, a stop or a live change)."""
        eff = [1.0, 1.0, 1.0, 1.0]
        force = [0.0, 0.0, 0.0]
        torque = [0.0, 0.0, 0.0]
        paper = False
        gusts: dict[_Source, _Gust] = {}
        sensor_objs: dict[_Source, _SensorFault] = {}
        for src, f in self._acting():
            k = f.kind
            if k == "motor":
                eff[f.motor - 1] *= f.efficiency
            elif k == "force":
                fw = ned_to_nwu(f.force_ned_n)
                force = [force[0] + fw[0], force[1] + fw[1], force[2] + fw[2]]
            elif k == "torque":
                tb = frd_to_flu(f.torque_frd_n_m)
                torque = [torque[0] + tb[0], torque[1] + tb[1], torque[2] + tb[2]]
            elif k == "gust":
                old_g = self._gusts.get(src)
                gusts[src] = old_g if old_g is not None and old_g.spec == f else _Gust(f, self._gust_rng)
            elif k == "paper_disturbance":
                paper = True
            else:
                old_s = self._sensor_objs.get(src)
                sensor_objs[src] = old_s if old_s is not None and old_s.spec == f else _SensorFault(f)
        self._gusts = gusts
        self._sensor_objs = sensor_objs
        by_sensor: dict[str, list[_SensorFault]] = {}
        for obj in sensor_objs.values():
            by_sensor.setdefault(obj.spec.sensor, []).append(obj)
        self._by_sensor = [(s, sorted(by_sensor[s], key=lambda o: o.order)) for s in SENSORS if s in by_sensor]
        e4 = (eff[0], eff[1], eff[2], eff[3])
        if e4 == _ONES4:
            self.motor_eff = _ONES4
        elif e4 != self.motor_eff:
            self.motor_eff = e4
        self._step_force = (force[0], force[1], force[2])
        self._step_torque = (torque[0], torque[1], torque[2])
        self.force_world_n = self._step_force
        self.torque_body_n_m = self._step_torque
        self.paper_disturbance = paper
        self.forces_on = bool(gusts) or self._step_force != _ZERO3 or self._step_torque != _ZERO3
        self.physics_on = self.forces_on or paper or self.motor_eff is not _ONES4
        self.sensing = bool(self._by_sensor)

    # -- per observation -----------------------------------------------------------------------------
    def observe(self, obs: VehicleObservation) -> VehicleObservation:
        """The observation as the faulty sensors report it (``obs`` itself when none acts).

        Call once per new observation (the plant caches it): it also feeds the delay buffer.
        """
        t = obs.t_s
        if t != self._last_obs_t:
            self._last_obs_t = t
            self._buf[self._buf_n % _BUFFER] = obs
            self._buf_n += 1
            if t >= self._next_s - TIME_EPS_S:
                self._update(t)
        if not self.sensing:
            return obs
        fields: list[Any] = list(obs)
        for sensor, objs in self._by_sensor:
            idx = _FIELD[sensor]
            v: Any = fields[idx]
            for o in objs:
                mode = o.spec.mode
                if mode == "delay":
                    v = self._delayed(t, o.spec.delay_s)[idx]
                elif mode == "stuck":
                    if o.held is None:
                        o.held = v
                    v = o.held
                elif mode == "bias":
                    b = o.vec
                    v = (v[0] + b[0], v[1] + b[1], v[2] + b[2])
                elif mode == "noise":
                    g = self._noise_rng.gauss
                    s = o.vec
                    v = (v[0] + g(0.0, s[0]) if s[0] > 0.0 else v[0], v[1] + g(0.0, s[1]) if s[1] > 0.0 else v[1],
                         v[2] + g(0.0, s[2]) if s[2] > 0.0 else v[2])  # fmt: skip
                else:  # dropout
                    v = _NAN3
            if sensor == "attitude":
                if v is _NAN3:
                    fields[7] = _NAN4
                else:
                    v = (wrap_pi(v[0]), v[1], wrap_pi(v[2]))
                    fields[7] = quat_from_euler(v[0], v[1], v[2])
            fields[idx] = v
        return VehicleObservation(*fields)

    def _delayed(self, t_s: float, delay_s: float) -> VehicleObservation:
        """The newest buffered observation at least ``delay_s`` older than ``t_s`` (else the oldest)."""
        buf, n = self._buf, self._buf_n
        lo = max(0, n - _BUFFER)  # oldest kept, by push number
        hi = n - 1
        limit = t_s - delay_s + TIME_EPS_S
        oldest = buf[lo % _BUFFER]
        assert oldest is not None
        if oldest.t_s > limit:
            return oldest
        while lo < hi:  # the last push number whose time <= limit
            mid = (lo + hi + 1) // 2
            o = buf[mid % _BUFFER]
            assert o is not None
            if o.t_s <= limit:
                lo = mid
            else:
                hi = mid - 1
        found = buf[lo % _BUFFER]
        assert found is not None
        return found


_LIVE_KEYS = ("motor1", "motor2", "motor3", "motor4", *SENSORS, "force", "torque", "gust", "paper")


def _same_live(a: FaultSpec, b: FaultSpec) -> bool:
    """The same live fault except for when it was set (an unchanged fault goes on as it was)."""
    return replace(a, start_s=0.0) == replace(b, start_s=0.0)
