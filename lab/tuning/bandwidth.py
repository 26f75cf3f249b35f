"""Closed-loop roll bandwidth and noise-to-motor RMS of each attitude law, at hover, in-process.

What runs is the flight controller's own tick (:class:`fc.flight.FlightControl` around the pure
:func:`fc.pipeline.pipeline_step`: prefilters, the law, the observer, the mixer, anti-windup) on
the rigid-body plant (:class:`sim_bridge.plants.rigid_body.RigidBodyPlant`, 1 kHz physics, motor
lag, limits), with the state and the motor commands through the float32 NED/FRD wire round trip
of :mod:`lab.runner`. Simulated time only.

**Bandwidth.** The vehicle hovers at 3 m in ALT_HOLD (no horizontal position loop, level
references). The roll reference is injected at the attitude-reference level: the roll/pitch
reference prefilters are frozen (bandwidth 0, so they only integrate their own state) and their
state is set before every tick to ``(r(t), 0, 0)``, so the law tracks ``x_d = r(t)`` with
``x_d' = x_d'' = x_d''' = 0``. That measures the *feedback* loop — what sets disturbance rejection
and how much sensor noise reaches the motors — not the feed-forward of the reference's derivatives
(with a perfect feed-forward every law would track any smooth reference). For each frequency f
the law tracks ``r(t) = A sin(2 pi f t)`` for a few cycles after a settling time, and the first
harmonic of the measured roll over whole cycles gives the gain |phi/r| and the phase; the -3 dB
bandwidth is where the gain first falls below 1/sqrt(2) (log-interpolated between grid points).
The step rise time (10 % to 90 %) is of a roll step of the same amplitude, references as above.

**Noise to motors.** The full flight controller (position hold) at hover at 3 m with the
scenario's ``--noise`` sensor noise (:data:`smcpilot.scenario.DEFAULT_NOISE_STD`); the figure is
the RMS deviation of the four motor commands from their means (in % of the full command range)
over the measuring window, averaged over the motors.

``python -m lab.tuning.bandwidth`` prints the table for the FC's three laws at their defaults.
"""

from __future__ import annotations

import argparse
import json
import math
import struct
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

from fc.config import FcConfig
from fc.flight import FlightControl, PipelineOutput
from lab.runner import state_of_wire, wire_values
from sim_bridge.build import make_plant
from sim_bridge.plants.rigid_body import RigidBodyPlant
from smcpilot.lawref import law_argument
from smcpilot.scenario import EnvironmentSpec
from smcpilot.vehicle import DEFAULT_VEHICLE, VehicleParams

_f32x4 = struct.Struct("<4f")
#: the laws compared, as the FC names them.
LAWS = ("adaptive_pid_smc", "pid_smc", "cascade_pid")
#: frequencies of the sweep, Hz.
DEFAULT_FREQS_HZ = (0.25, 0.35, 0.5, 0.6, 0.7, 0.85, 1.0, 1.25, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0, 12.0, 16.0, 20.0, 25.0, 32.0)
HOVER_ALT_M = 3.0


@dataclass(frozen=True)
class Hover:
    """How the hover flights are flown."""

    #: control rate, Hz, and physics rate, Hz (a whole multiple).
    rate_hz: float = 500.0
    physics_hz: float = 1000.0
    #: roll amplitude of the sweep and the step, rad.
    amplitude_rad: float = 0.05
    #: settling time before each measurement, s.
    settle_s: float = 1.0
    #: cycles measured per frequency (after ``lead_cycles`` dropped).
    cycles: int = 4
    lead_cycles: int = 2
    #: noise measurement: window, s, and seed of the noise stream.
    noise_s: float = 10.0
    seed: int = 1

    def __post_init__(self) -> None:
        for name in ("rate_hz", "physics_hz", "amplitude_rad", "settle_s", "noise_s"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0.0):
                raise ValueError(f"Hover.{name} must be a finite number > 0, got {v!r}")
        if self.cycles < 1 or self.lead_cycles < 0:
            raise ValueError("Hover.cycles must be >= 1 and lead_cycles >= 0")
        ratio = self.physics_hz / self.rate_hz
        if abs(ratio - round(ratio)) > 1e-9:
            raise ValueError(f"physics_hz {self.physics_hz:g} must be a whole multiple of rate_hz {self.rate_hz:g}")


#: called before each tick with the tick's time (s); returns the roll reference (rad) or None (no injection).
RollRef = Callable[[float], float | None]


def _hover(
    config: FcConfig,
    vehicle: VehicleParams,
    hov: Hover,
    duration_s: float,
    roll_ref: RollRef | None,
    environment: EnvironmentSpec = EnvironmentSpec(),
    on_tick: Callable[[float, tuple[float, ...], PipelineOutput, tuple[float, ...]], None] | None = None,
) -> None:
    """Fly the pipeline at hover for ``duration_s``; ``on_tick(t_s, wire, output, motors)`` each tick.

    With ``roll_ref`` the vehicle flies level references in ALT_HOLD and the roll reference is
    injected (module doc); without, it holds position at (0, 0, HOVER_ALT_M).
    """
    config = replace(config, rate_hz=hov.rate_hz)
    plant = make_plant("rigid-body", vehicle, environment, hov.seed)
    assert isinstance(plant, RigidBodyPlant)
    w_hover = math.sqrt(vehicle.hover_omega_sq)
    plant.reset((0.0, 0.0, HOVER_ALT_M), rotor_speeds_radps=(w_hover,) * 4)
    fl = FlightControl(config, vehicle)
    dt = 1.0 / hov.rate_hz
    substeps = int(round(hov.physics_hz / hov.rate_hz))
    h = 1.0 / hov.physics_hz
    fl.arm(state_of_wire(wire_values(plant.truth())))
    fl.set_target(0.0, 0.0, HOVER_ALT_M)
    if roll_ref is not None:
        fl.position_hold = False
        fl.params = fl.params._replace(att_filter_omega_radps=0.0)
    n = int(round(duration_s * hov.rate_hz))
    t = 0.0
    pack, unpack = _f32x4.pack, _f32x4.unpack
    for k in range(n):
        t = k * dt
        wire = wire_values(plant.observe())
        st = state_of_wire(wire)
        if roll_ref is not None:
            r = roll_ref(t)
            if r is not None:
                fl.pipeline_state = fl.pipeline_state._replace(phi_r=r, phi_v=0.0, phi_a=0.0)
        out = fl.step(st, dt)
        motors = unpack(pack(*out.motors))
        if on_tick is not None:
            on_tick(t, wire, out, motors)
        for i in range(substeps):
            plant.step(t + i * h, h, motors, True)


def _harmonic(t: Sequence[float], y: Sequence[float], f_hz: float) -> complex:
    """First harmonic of ``y`` at ``f_hz`` over whole cycles: the complex amplitude (sin part real)."""
    w = 2.0 * math.pi * f_hz
    n = len(t)
    mean = sum(y) / n
    s = sum((v - mean) * math.sin(w * ti) for ti, v in zip(t, y))
    c = sum((v - mean) * math.cos(w * ti) for ti, v in zip(t, y))
    return complex(2.0 * s / n, 2.0 * c / n)


def roll_frequency_response(config: FcConfig, f_hz: float, hov: Hover = Hover(), vehicle: VehicleParams = DEFAULT_VEHICLE) -> tuple[float, float]:
    """(gain |phi / phi_ref|, phase in degrees) of the roll loop at ``f_hz`` (module doc)."""
    period = 1.0 / f_hz
    t0 = hov.settle_s + hov.lead_cycles * period
    t1 = t0 + hov.cycles * period
    a = hov.amplitude_rad
    w = 2.0 * math.pi * f_hz
    ts: list[float] = []
    phis: list[float] = []
    refs: list[float] = []

    def ref(t: float) -> float:
        return 0.0 if t < hov.settle_s else a * math.sin(w * (t - hov.settle_s))

    def rec(t: float, wire: tuple[float, ...], out: PipelineOutput, motors: tuple[float, ...]) -> None:
        if t0 <= t < t1 - 0.5 / hov.rate_hz:
            ts.append(t - hov.settle_s)
            phis.append(wire[0])  # roll is the same angle in FRD and FLU
            refs.append(out.ref[0])

    _hover(config, vehicle, hov, t1 + 1.0 / hov.rate_hz, ref, on_tick=rec)
    y = _harmonic(ts, phis, f_hz)
    r = _harmonic(ts, refs, f_hz)
    g = y / r
    return abs(g), math.degrees(math.atan2(g.imag, g.real))


def bandwidth_hz(freqs: Sequence[float], gains: Sequence[float]) -> float | None:
    """Where the gain first falls below 1/sqrt(2), log-interpolated; None if it never does."""
    lim = 1.0 / math.sqrt(2.0)
    for i in range(1, len(freqs)):
        if gains[i] < lim <= gains[i - 1]:
            x0, x1 = math.log(freqs[i - 1]), math.log(freqs[i])
            y0, y1 = math.log(gains[i - 1]), math.log(gains[i])
            return math.exp(x0 + (math.log(lim) - y0) * (x1 - x0) / (y1 - y0))
    return None


def roll_step(config: FcConfig, hov: Hover = Hover(), vehicle: VehicleParams = DEFAULT_VEHICLE, duration_s: float = 1.5) -> dict[str, float | None]:
    """Step of ``hov.amplitude_rad`` in the roll reference: 10-90 % rise time (s), overshoot (%)."""
    a = hov.amplitude_rad
    ts: list[float] = []
    phis: list[float] = []

    def ref(t: float) -> float:
        return 0.0 if t < hov.settle_s else a

    def rec(t: float, wire: tuple[float, ...], out: PipelineOutput, motors: tuple[float, ...]) -> None:
        if t >= hov.settle_s:
            ts.append(t - hov.settle_s)
            phis.append(wire[0])

    _hover(config, vehicle, hov, hov.settle_s + duration_s, ref, on_tick=rec)
    t10 = next((t for t, p in zip(ts, phis) if p >= 0.1 * a), None)
    t90 = next((t for t, p in zip(ts, phis) if p >= 0.9 * a), None)
    rise = None if t10 is None or t90 is None else t90 - t10
    return {"rise_s": rise, "overshoot_pct": 100.0 * (max(phis) - a) / a}


def noise_to_motor(config: FcConfig, hov: Hover = Hover(), vehicle: VehicleParams = DEFAULT_VEHICLE, noise_scale: float = 1.0) -> dict[str, float]:
    """Hover with the scenario's ``--noise`` (x ``noise_scale``): motor-command RMS deviation, % of full
    range (mean of the 4 motors), and the roll RMS, deg, over ``hov.noise_s`` after ``hov.settle_s``."""
    rows: list[tuple[float, ...]] = []
    rolls: list[float] = []

    def rec(t: float, wire: tuple[float, ...], out: PipelineOutput, motors: tuple[float, ...]) -> None:
        if t >= hov.settle_s + 1.0:
            rows.append(motors)
            rolls.append(wire[0])

    env = EnvironmentSpec(noise=True, noise_scale=noise_scale)
    _hover(config, vehicle, hov, hov.settle_s + 1.0 + hov.noise_s, None, env, on_tick=rec)
    n = len(rows)
    rms = 0.0
    for i in range(4):
        col = [r[i] for r in rows]
        m = sum(col) / n
        rms += math.sqrt(sum((c - m) ** 2 for c in col) / n)
    mr = sum(rolls) / n
    return {"motor_rms_pct": 100.0 * rms / 4.0, "roll_rms_deg": math.degrees(math.sqrt(sum((r - mr) ** 2 for r in rolls) / n))}


def measure(config: FcConfig, hov: Hover = Hover(), freqs: Sequence[float] = DEFAULT_FREQS_HZ, vehicle: VehicleParams = DEFAULT_VEHICLE) -> dict:
    """Everything for one configuration: the sweep, the -3 dB bandwidth, the step, the noise."""
    resp = [roll_frequency_response(config, f, hov, vehicle) for f in freqs]
    gains = [g for g, _ in resp]
    return {
        "controller": config.controller,
        "freqs_hz": list(freqs),
        "gain": gains,
        "phase_deg": [p for _, p in resp],
        "bandwidth_hz": bandwidth_hz(freqs, gains),
        "peak_gain": max(gains),
        **roll_step(config, hov, vehicle),
        **noise_to_motor(config, hov, vehicle),
    }


def _fmt(v: float | None, spec: str) -> str:
    return "-" if v is None else format(v, spec)


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m lab.tuning.bandwidth",
        description="Closed-loop roll bandwidth (-3 dB), step rise time and noise-to-motor RMS at hover of the FC's laws "
        "at their defaults, in-process on the rigid-body plant (docs/baselines.md).",
    )
    ap.add_argument("--controller", action="append", type=law_argument, metavar="LAW",
                    help=f"law to measure (repeatable; default: {', '.join(LAWS)}): any attitude-stage law, a plug-in or"
                    " path/to/file.py:NAME (a whole-stack law has no attitude reference to inject: refused)")
    ap.add_argument("--amplitude-deg", type=float, default=math.degrees(Hover.amplitude_rad), help="roll amplitude, deg (default %(default).2f)")
    ap.add_argument("--param", action="append", default=[], metavar="NAME=VALUE", help="an FC parameter over the defaults (repeatable)")
    ap.add_argument("--json", metavar="PATH", help="also write the results as JSON")
    args = ap.parse_args(argv)
    from fc.params import ParamStore
    from smcpilot.errors import SmcpilotError

    hov = Hover(amplitude_rad=math.radians(args.amplitude_deg))
    results = []
    from fc.control import registry

    for law in args.controller or LAWS:
        try:
            if registry.resolve(law).full_stack:
                raise SmcpilotError(f"{law} is a whole-stack law: its attitude reference comes from its own position loop,"
                                    " so this harness cannot inject one (docs/geometric-control.md measures it its own way)")
            store = ParamStore(FcConfig(controller=law))
            for item in args.param:
                name, _, value = item.partition("=")
                store.set(name.strip(), float(value), persist=False)
        except (SmcpilotError, ValueError) as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        results.append(measure(store.config, hov))
    print(f"roll reference amplitude {args.amplitude_deg:.2f} deg; noise: --noise at hover 3 m, {hov.noise_s:g} s")
    print(f"{'law':18} {'-3 dB Hz':>9} {'peak':>6} {'rise ms':>8} {'overshoot %':>11} {'motor RMS %':>11} {'roll RMS deg':>12}")
    for r in results:
        print(
            f"{r['controller']:18} {_fmt(r['bandwidth_hz'], '9.2f')} {r['peak_gain']:6.2f} "
            f"{_fmt(None if r['rise_s'] is None else 1e3 * r['rise_s'], '8.1f')} {r['overshoot_pct']:11.1f} "
            f"{r['motor_rms_pct']:11.3f} {r['roll_rms_deg']:12.3f}"
        )
    for r in results:
        print(f"{r['controller']}: " + " ".join(f"{f:g}:{g:.2f}/{p:.0f}" for f, g, p in zip(r["freqs_hz"], r["gain"], r["phase_deg"])))
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump(results, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
