"""Flight metrics of an in-process flight without a ``.tlog``: :class:`MetricsRecorder` is a
:data:`lab.runner.TickHook` that keeps, every tick, what the FC's per-tick log record and state
messages would hold, and hands it to :func:`ground.logs.metrics.flight_metrics` (the function
``smcpilot log summary`` uses), so a study flying many scenarios in-process gets the same numbers
as the summary of the same flight's log (to float32 rounding: the log stores float32).

Use::

    core = FlightCore(config_for(scenario), scenario.vehicle, home=..., plan=scenario.plan, event=...)
    rec = MetricsRecorder(core)
    simulate(core, plant_for(scenario), scenario.n_ticks, rate_hz=scenario.rate_hz, on_tick=rec.on_tick)
    m = rec.metrics(fault_starts_s=[f.start_s for f in faults])

or, instead of the explicit starts, pass the simulator's fault announcements to
:meth:`MetricsRecorder.note_event` (the same ``SIM:`` WARNING events a log holds).

Samples are in the paper frame (x north, y west, z up; FLU Euler angles), times in simulated
seconds since the first tick. The state is what the FC received (sensor noise and faults
included), as in a log.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from fc.core import FlightCore, TickOutput
from fc.flight import VehicleState
from ground.logs.metrics import RECOVER_RADIUS_M, SIGMA_WINDOW_S, divergence_from_events, fault_starts_from_events, flight_metrics
from smcpilot.errors import ConfigError
from smcpilot.protocol import FLAG_ARMED, FLAG_FAILSAFE, FLAG_LANDING

__all__ = ["MetricsRecorder"]

_NAN4 = (float("nan"),) * 4
_LANDING_BITS = FLAG_LANDING | FLAG_FAILSAFE
#: columns of a row.
_COLUMNS = 26


class MetricsRecorder:
    """Collects the samples :func:`~ground.logs.metrics.flight_metrics` needs, one row per tick
    (``on_tick`` has the :data:`lab.runner.TickHook` signature; ``every`` keeps every n-th tick)."""

    def __init__(self, core: FlightCore, every: int = 1) -> None:
        if not (isinstance(every, int) and every >= 1):
            raise ConfigError(f"MetricsRecorder: every must be an integer >= 1, got {every!r}")
        self.core = core
        self.every = every
        #: kept rows: tuples (one tick each) and arrays (many ticks, from the compiled flight), in order.
        self._rows: list[tuple[float, ...] | np.ndarray] = []
        self._n = 0
        #: events noted with :meth:`note_event`: (t_s, MAV_SEVERITY, text).
        self.events: list[tuple[float, int, str]] = []

    def note_event(self, t_s: float, severity: int, text: str) -> None:
        """Keep an event (e.g. the simulator's fault announcements, ``SIM: motor 1 at 70%`` with
        severity WARNING): :meth:`metrics` finds the fault starts and a divergence among them."""
        self.events.append((float(t_s), int(severity), str(text)))

    def on_tick(self, k: int, t_us: int, wire: tuple[float, ...], st: VehicleState, out: TickOutput, motors: tuple[float, ...]) -> None:
        """Keep tick ``k``: time, state, set-point, references, motors, flags, σ."""
        if k % self.every:
            return
        self._n += 1
        f = self.core.flight
        diag = out.pipeline.diag
        sigma = diag.sigma if diag is not None and diag.sigma is not None else _NAN4
        ref = out.pipeline.ref
        self._rows.append(
            (t_us * 1e-6, st.x_m, st.y_m, st.z_m, st.vx_mps, st.vy_mps, st.vz_mps, st.phi_rad, st.theta_rad, st.psi_rad)
            + tuple(f.target) + (f.yaw_target_rad, ref[0], ref[1], ref[2]) + tuple(motors)
            + (float(out.flags), *sigma)
        )  # fmt: skip

    def add_rows(self, rows: np.ndarray) -> None:
        """Keep rows computed elsewhere (the compiled flight, :mod:`lab.fast`), in :meth:`on_tick`'s layout (copied)."""
        self._rows.append(np.array(rows, dtype=float).reshape(-1, _COLUMNS))
        self._n += len(rows)

    def __len__(self) -> int:
        return self._n

    def rows(self) -> np.ndarray:
        """Every kept row, one per tick kept (columns as :meth:`on_tick` builds them)."""
        parts: list[np.ndarray] = []
        run: list[tuple[float, ...]] = []
        for r in self._rows:
            if isinstance(r, np.ndarray):
                if run:
                    parts.append(np.asarray(run, dtype=float).reshape(-1, _COLUMNS))
                    run = []
                parts.append(r)
            else:
                run.append(r)
        if run:
            parts.append(np.asarray(run, dtype=float).reshape(-1, _COLUMNS))
        return np.concatenate(parts) if parts else np.zeros((0, _COLUMNS))

    def arrays(self) -> dict[str, np.ndarray]:
        """The samples so far as arrays named like :func:`flight_metrics`'s arguments."""
        a = self.rows()
        flags = a[:, 21].astype(np.int64)
        return {
            "t_s": a[:, 0],
            "position_m": a[:, 1:4],
            "velocity_m_s": a[:, 4:7],
            "euler_rad": a[:, 7:10],
            "target_m": a[:, 10:13],
            "target_yaw_rad": a[:, 13],
            "euler_ref_rad": a[:, 14:17],
            "motors": a[:, 17:21],
            "armed": (flags & FLAG_ARMED) != 0,
            "landing": (flags & _LANDING_BITS) != 0,
            "sigma": a[:, 22:26],
        }

    def metrics(
        self,
        *,
        fault_starts_s: Sequence[float] | None = None,
        recover_radius_m: float = RECOVER_RADIUS_M,
        diverged_t_s: float | None = None,
        sigma_window_s: float = SIGMA_WINDOW_S,
    ) -> dict[str, Any]:
        """:func:`~ground.logs.metrics.flight_metrics` of the samples so far (the LAND speed from
        the core's configuration). Without ``fault_starts_s`` / ``diverged_t_s``, they come from
        the noted events as from a log's (:func:`~ground.logs.metrics.fault_starts_from_events`,
        :func:`~ground.logs.metrics.divergence_from_events`)."""
        if fault_starts_s is None:
            fault_starts_s = fault_starts_from_events(self.events)
        if diverged_t_s is None:
            diverged_t_s = divergence_from_events(self.events)
        d = self.arrays()
        return flight_metrics(
            d["t_s"], d["position_m"], d["target_m"], d["euler_rad"], d["euler_ref_rad"], d["motors"], d["armed"], d["landing"],
            fault_starts_s=fault_starts_s, recover_radius_m=recover_radius_m, velocity_m_s=d["velocity_m_s"],
            target_yaw_rad=d["target_yaw_rad"], sigma=d["sigma"], sigma_window_s=sigma_window_s,
            land_speed_mps=float(self.core.config.land_speed_mps), diverged_t_s=diverged_t_s,
        )  # fmt: skip
