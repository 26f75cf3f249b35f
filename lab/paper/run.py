"""Run the paper scenario for one or more controllers and collect trajectories and metrics."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from typing import Any, Literal

from fc.control import CONTROLLER_NAMES, make_controller
from fc.control.gains import PAPER_GAINS, Gains4
from lab.closed_loop import Trajectory, simulate
from lab.paper.metrics import metrics_document, trajectory_metrics
from lab.paper.scenario import PaperScenario
from sim_bridge.plants.paper import PaperPlant
from smcpilot.errors import ConfigError
from smcpilot.model import CHANNELS, PaperModel
from smcpilot.typos import CONTROLLER_TYPOS, MODEL_TYPOS, parse_typos
from smcpilot.vehicle import DEFAULT_VEHICLE, VehicleParams

SMC_FLAVOURS = ("pid_smc", "adaptive_pid_smc")


@dataclass(frozen=True)
class PaperRunOptions:
    """How to run the scenario. Options marked PID-SMC apply to the two PID-SMC flavours only."""

    controllers: tuple[str, ...] = CONTROLLER_NAMES
    #: None: continuous-time RK4 at 1/dt_s; a number: sampled-data control at that rate.
    rate_hz: float | None = None
    dt_s: float = 1.0e-3
    #: PID-SMC: "model" (implementable) or "oracle" (the paper's, from the true acceleration).
    sigma_source: Literal["model", "oracle"] = "model"
    #: PID-SMC adaptive: chi_hat(0) for every channel (the paper's simulation: 0.5).
    chi_hat0: float = 0.5
    #: names of the paper's typos to reproduce literally (see smcpilot.typos).
    typos: frozenset[str] = frozenset()
    disturbance: bool = True
    #: PID-SMC gains (both flavours); the paper's by default.
    gains: Gains4 = PAPER_GAINS
    vehicle: VehicleParams = DEFAULT_VEHICLE
    scenario: PaperScenario = field(default_factory=PaperScenario)

    def __post_init__(self) -> None:
        unknown = [c for c in self.controllers if c not in CONTROLLER_NAMES]
        if unknown:
            raise ConfigError(f"unknown controller {unknown[0]!r}; choose from: {', '.join(CONTROLLER_NAMES)}")
        if not self.controllers:
            raise ConfigError("no controller selected")
        if not (self.chi_hat0 >= 0.0):
            raise ConfigError(f"chi_hat(0) must be >= 0, got {self.chi_hat0!r}")
        object.__setattr__(self, "typos", parse_typos(self.typos))

    def config(self) -> dict[str, Any]:
        return {
            "mode": "continuous" if self.rate_hz is None else "sampled",
            "rate_hz": self.rate_hz,
            "integration_step_s": self.dt_s,
            "sigma_source": self.sigma_source,
            "chi_hat0": self.chi_hat0,
            "literal_typos": sorted(self.typos),
            "disturbance": self.disturbance,
            "gains_changed": {
                f"{c}.{f.name}": getattr(g, f.name)
                for c, g, p in zip(CHANNELS, self.gains, PAPER_GAINS)
                for f in fields(g)
                if getattr(g, f.name) != getattr(p, f.name)
            },
            "duration_s": self.scenario.duration_s,
            "vehicle": self.vehicle.name,
        }


@dataclass
class PaperRun:
    options: PaperRunOptions
    trajectories: dict[str, Trajectory]
    wall_seconds: dict[str, float]
    model: PaperModel

    def metrics(self) -> dict[str, Any]:
        entries = {name: trajectory_metrics(tr, self.model.hover_omega_sq) for name, tr in self.trajectories.items()}
        return metrics_document(entries, self.options.config())


def build_controller(name: str, model: PaperModel, options: PaperRunOptions):
    kwargs: dict[str, Any] = {}
    if name in SMC_FLAVOURS:
        kwargs["sigma_source"] = options.sigma_source
        kwargs["typos"] = options.typos & CONTROLLER_TYPOS
        kwargs["gains"] = options.gains
        if name == "adaptive_pid_smc":
            kwargs["chi_hat0"] = (options.chi_hat0,) * 4
    return make_controller(name, model, **kwargs)


def run_paper(
    options: PaperRunOptions = PaperRunOptions(),
    progress: Callable[[str, Trajectory, float], None] | None = None,
) -> PaperRun:
    """Simulate each selected controller on the paper plant; ``progress`` is called after each."""
    model = PaperModel.from_vehicle(options.vehicle, options.typos & MODEL_TYPOS)
    plant = PaperPlant(model, disturbance=options.disturbance)
    sc = options.scenario
    trajectories: dict[str, Trajectory] = {}
    walls: dict[str, float] = {}
    for name in options.controllers:
        ctrl = build_controller(name, model, options)
        t0 = time.perf_counter()
        tr = simulate(ctrl, plant, sc.reference, sc.plant_x0, sc.duration_s, options.dt_s, options.rate_hz)
        walls[name] = time.perf_counter() - t0
        trajectories[name] = tr
        if progress is not None:
            progress(name, tr, walls[name])
    return PaperRun(options, trajectories, walls, model)
