"""Metrics of a paper-scenario run, in the JSON shape others compare against.

::

    {"scenario": "paper", "controllers": {NAME: {"diverged": bool,
       "min_omega_sq_over_hover": float,
       "channels": {"phi"|"theta"|"psi"|"z": {
          "t_sigma_below_0p01_s": float|null, "t_err_below_0p01_s": float|null,
          "err_final": float, "overshoot": float, "max_abs_u": float,
          "total_variation_u": float, "chi_hat_final": float|null}}}}}

Definitions: ``t_*`` is the time the quantity last entered the band |.| < 0.01 and stayed there
to the end (null if it never does, or has no meaning for that controller); ``err_final`` is
e = x - x_d at the end (signed); ``overshoot`` the largest excursion past the target on the far
side from the start (>= 0); ``max_abs_u`` in the channel's input unit (N or N m);
``total_variation_u`` = sum |u[k+1] - u[k]| over the 1 kHz samples; ``chi_hat_final`` only for
the adaptive controller. Extra keys (``diverged_at_s``, ``reason``) say when and why a run
diverged; values that are not finite are written as null.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from lab.closed_loop import Trajectory
from smcpilot.model import CHANNELS

BAND = 0.01

#: JSON Schema of the metrics file (draft 2020-12), shipped so others can validate their runs.
METRICS_SCHEMA: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "type": "object",
    "required": ["scenario", "controllers"],
    "properties": {
        "scenario": {"const": "paper"},
        "controllers": {
            "type": "object",
            "minProperties": 1,
            "propertyNames": {"enum": ["pid_smc", "adaptive_pid_smc", "sign_smc", "cascade_pid"]},
            "additionalProperties": {
                "type": "object",
                "required": ["diverged", "min_omega_sq_over_hover", "channels"],
                "properties": {
                    "diverged": {"type": "boolean"},
                    "min_omega_sq_over_hover": {"type": ["number", "null"]},
                    "channels": {
                        "type": "object",
                        "required": list(CHANNELS),
                        "additionalProperties": False,
                        "properties": {
                            c: {
                                "type": "object",
                                "required": [
                                    "t_sigma_below_0p01_s",
                                    "t_err_below_0p01_s",
                                    "err_final",
                                    "overshoot",
                                    "max_abs_u",
                                    "total_variation_u",
                                    "chi_hat_final",
                                ],
                                "properties": {
                                    "t_sigma_below_0p01_s": {"type": ["number", "null"], "minimum": 0},
                                    "t_err_below_0p01_s": {"type": ["number", "null"], "minimum": 0},
                                    "err_final": {"type": ["number", "null"]},
                                    "overshoot": {"type": ["number", "null"], "minimum": 0},
                                    "max_abs_u": {"type": ["number", "null"], "minimum": 0},
                                    "total_variation_u": {"type": ["number", "null"], "minimum": 0},
                                    "chi_hat_final": {"type": ["number", "null"]},
                                },
                            }
                            for c in CHANNELS
                        },
                    },
                },
            },
        },
    },
}


def _num(v: float) -> float | None:
    v = float(v)
    return v if math.isfinite(v) else None


def settle_time(t: np.ndarray, values: np.ndarray, band: float = BAND) -> float | None:
    """Time ``values`` last entered |v| < band and stayed there to the end; None if it never does."""
    outside = ~(np.abs(values) < band)  # NaN counts as outside
    if outside[-1]:
        return None
    idx = np.flatnonzero(outside)
    if idx.size == 0:
        return float(t[0])
    return float(t[idx[-1] + 1])


def overshoot(x: np.ndarray, target: float) -> float:
    """Largest excursion past ``target`` on the far side from x[0] (>= 0)."""
    side = np.sign(x[0] - target)
    if side == 0:
        return float(np.nanmax(np.abs(x - target)))
    past = (target - x) if side > 0 else (x - target)
    return float(max(np.nanmax(past), 0.0))


def trajectory_metrics(traj: Trajectory, hover_omega_sq: float) -> dict[str, Any]:
    """One controller's entry of the metrics file."""
    e = traj.errors
    channels: dict[str, Any] = {}
    for i, name in enumerate(CHANNELS):
        u = traj.u[:, i]
        channels[name] = {
            "t_sigma_below_0p01_s": settle_time(traj.t_s, traj.sigma[:, i]) if traj.sigma is not None else None,
            "t_err_below_0p01_s": settle_time(traj.t_s, e[:, i]),
            "err_final": _num(e[-1, i]),
            "overshoot": _num(overshoot(traj.x[:, 2 * i], float(traj.x_ref[0, i]))),
            "max_abs_u": _num(np.max(np.abs(u))),
            "total_variation_u": _num(np.sum(np.abs(np.diff(u)))),
            "chi_hat_final": (
                _num(traj.chi_hat[-1, i]) if traj.chi_hat is not None and traj.controller == "adaptive_pid_smc" else None
            ),
        }
    return {
        "diverged": bool(traj.diverged),
        "diverged_at_s": traj.diverged_at_s,
        "reason": traj.reason or None,
        "min_omega_sq_over_hover": _num(np.min(traj.w_sq) / hover_omega_sq),
        "channels": channels,
    }


def metrics_document(entries: dict[str, dict[str, Any]], config: dict[str, Any] | None = None) -> dict[str, Any]:
    doc: dict[str, Any] = {"scenario": "paper", "controllers": entries}
    if config is not None:
        doc["config"] = config
    return doc


def write_schema(path: str | Path) -> None:
    import json

    Path(path).write_text(json.dumps(METRICS_SCHEMA, indent=2) + "\n", encoding="utf-8")
