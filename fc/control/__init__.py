"""Control laws: the corrected PID-SMC (known-bound and adaptive) and two baselines.

All implement :class:`fc.control.base.Controller`; :func:`make_controller` builds one by name.
"""

from __future__ import annotations

from typing import Any

from fc.control import base, cascade_pid, pid_smc, sign_smc
from fc.control.base import Controller, Diagnostics, constant_reference
from fc.control.cascade_pid import CascadePid, CascadePidParams
from fc.control.gains import PAPER_GAINS, ChannelGains
from fc.control.pid_smc import AdaptationBounds, PidSmc, PidSmcParams
from fc.control.sign_smc import SignSmc, SignSmcParams
from smcpilot import model as _model
from smcpilot.errors import ConfigError
from smcpilot.model import PaperModel
from smcpilot.protocol import CONTROLLER_NAMES

#: the laws' pure functions (module level, tuples in and out; what the flight pipeline calls and
#: what a compiler such as numba's ``njit`` takes unchanged), with the model equations they use.
LAW_FUNCTIONS = (
    pid_smc.pid_smc_law,
    pid_smc.pid_smc_step,
    pid_smc.pid_smc_step_measured,
    pid_smc.pid_smc_integrate,
    pid_smc.pid_smc_anti_windup,
    pid_smc.pid_smc_initial_state,
    pid_smc._channel,
    pid_smc._chi_rate,
    cascade_pid.cascade_pid_output,
    cascade_pid.cascade_pid_step,
    cascade_pid._cascade_channel,
    cascade_pid._rate_channel,
    cascade_pid._clamp,
    cascade_pid.lowpass_step,
    cascade_pid.cascade_pid_anti_windup,
    sign_smc.sign_smc_output,
    sign_smc.sign_smc_step,
    sign_smc._sign_channel,
    base.integrators_anti_windup,
    _model.unmix,
    _model.omega_bar,
    _model.omega_bar_of_inputs,
    _model.drift,
    _model.drift_rates,
    _model.tilt_cos,
)


def make_controller(name: str, model: PaperModel, **options: Any) -> Controller:
    """Build a controller by name.

    ``options`` go to the controller's parameter dataclass (e.g. ``sigma_source="oracle"``,
    ``chi_hat0=(0, 0, 0, 0)``, ``gains=...`` for the PID-SMC flavours).
    """
    try:
        if name == "pid_smc":
            return PidSmc(model, PidSmcParams(adaptive=False, **options))
        if name == "adaptive_pid_smc":
            return PidSmc(model, PidSmcParams(adaptive=True, **options))
        if name == "sign_smc":
            return SignSmc(model, SignSmcParams(**options))
        if name == "cascade_pid":
            return CascadePid(model, CascadePidParams(**options))
    except TypeError as exc:  # an option this controller does not have
        raise ConfigError(f"controller {name!r}: {exc}") from None
    raise ConfigError(f"unknown controller {name!r}; choose from: {', '.join(CONTROLLER_NAMES)}")


__all__ = [
    "AdaptationBounds",
    "CONTROLLER_NAMES",
    "CascadePid",
    "CascadePidParams",
    "ChannelGains",
    "Controller",
    "Diagnostics",
    "LAW_FUNCTIONS",
    "PAPER_GAINS",
    "PidSmc",
    "PidSmcParams",
    "SignSmc",
    "SignSmcParams",
    "constant_reference",
    "make_controller",
]
