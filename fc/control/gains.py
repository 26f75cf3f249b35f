"""Gains of the PID-SMC, one frozen dataclass per channel, validated on construction.

Symbols are the paper's (eqs. 18-21, 33). Defaults are the paper's §VI values (spec §5); the
per-channel defaults for nu and the known bound chi differ and live in :data:`PAPER_GAINS`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields, replace
from typing import Any

from smcpilot.errors import InvalidGainError
from smcpilot.model import CHANNELS


@dataclass(frozen=True)
class ChannelGains:
    """Gains of one channel.

    S = c1 e + c2 e';  sigma = kp S + ki int S dt + kd S';
    u' = -(kd c2 g)^-1 [N + kappa sign(sigma)|sigma|^delta + nu sigma + chi sign(sigma)];
    d chi_hat/dt = adapt_rate |sigma| (adaptive flavour).
    """

    #: [c1] weight of the error e in S, 1/s (relative to c2).
    c1: float = 5.0
    #: [c2] weight of the error rate e' in S; must be > 0.
    c2: float = 0.6
    #: [kp] proportional weight of S in sigma.
    kp: float = 4.0
    #: [ki] integral weight of S in sigma, 1/s.
    ki: float = 2.0
    #: [kd] derivative weight of S in sigma, s; must be > 0.
    kd: float = 1.0
    #: [kappa] gain of the fractional-power reaching term.
    kappa: float = 15.0
    #: [delta] exponent of the reaching term, in (0, 1).
    delta: float = 0.6
    #: [nu] gain of the linear reaching term.
    nu: float = 0.3
    #: [chi] known disturbance bound used by Theorem 1 (>= |Lambda|).
    chi: float = 1.0
    #: [Theta] adaptation rate of chi_hat (Theorem 2).
    adapt_rate: float = 0.05

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise InvalidGainError(f"gain {f.name} must be a finite number, got {v!r}")
        if self.c2 <= 0.0:
            raise InvalidGainError(f"gain c2 must be > 0 (u' divides by kd c2 g), got {self.c2}")
        if self.kd <= 0.0:
            raise InvalidGainError(f"gain kd must be > 0 (u' divides by kd c2 g), got {self.kd}")
        if not 0.0 < self.delta < 1.0:
            raise InvalidGainError(f"gain delta must lie in (0, 1), got {self.delta}")
        for name in ("c1", "kp", "ki", "kappa", "nu", "chi", "adapt_rate"):
            if getattr(self, name) < 0.0:
                raise InvalidGainError(f"gain {name} must be >= 0, got {getattr(self, name)}")

    def with_(self, **changes: Any) -> ChannelGains:
        return replace(self, **changes)


Gains4 = tuple[ChannelGains, ChannelGains, ChannelGains, ChannelGains]

#: The paper's §VI gains, with the known bounds chi = [1, 1, 1.5, 3] of spec §3.
PAPER_GAINS: Gains4 = (
    ChannelGains(nu=0.3, chi=1.0),
    ChannelGains(nu=0.3, chi=1.0),
    ChannelGains(nu=0.15, chi=1.5),
    ChannelGains(nu=0.15, chi=3.0),
)


def gains_with_overrides(base: Gains4, overrides: Mapping[str, float]) -> Gains4:
    """Apply overrides such as ``{"kd": 2.0, "psi.nu": 0.2}`` (no prefix: every channel)."""
    out = list(base)
    valid = {f.name for f in fields(ChannelGains)}
    for key, value in overrides.items():
        chan, _, name = key.rpartition(".")
        if name not in valid:
            raise InvalidGainError(f"unknown gain {name!r}; known: {', '.join(sorted(valid))}")
        if chan and chan not in CHANNELS:
            raise InvalidGainError(f"unknown channel {chan!r} in {key!r}; known: {', '.join(CHANNELS)}")
        for i, c in enumerate(CHANNELS):
            if not chan or chan == c:
                out[i] = replace(out[i], **{name: float(value)})
    return (out[0], out[1], out[2], out[3])
