"""Exception classes shared by every part of smcpilot.

Each error says what was wrong in words a user can act on; the CLI prints the message and exits
non-zero instead of showing a traceback.
"""

from __future__ import annotations


class SmcpilotError(Exception):
    """Base class of every error smcpilot raises on purpose."""


class ConfigError(SmcpilotError, ValueError):
    """A parameter, option or configuration file is invalid (the message names the key)."""


class InvalidGainError(ConfigError):
    """A controller gain is outside its valid range (e.g. kd = 0, c2 = 0, delta outside (0, 1))."""


class ScenarioError(ConfigError):
    """A scenario is invalid or its file is unreadable (the message names the file and key).

    Defined here so :mod:`smcpilot.faults` (whose :class:`~smcpilot.faults.FaultError` is one) and
    :mod:`smcpilot.scenario` (which re-exports it) do not import each other in a circle."""


class VehicleFileError(ConfigError):
    """A vehicle TOML file is unreadable or has a missing, unknown or out-of-range key."""


class DivergenceError(SmcpilotError):
    """A simulation left the region where the model is meaningful (NaN, inf or huge states)."""

    def __init__(self, message: str, time_s: float) -> None:
        super().__init__(message)
        self.time_s = time_s


class EndpointError(ConfigError):
    """A MAVLink endpoint URL (``udp:HOST:PORT``, ``udpout:HOST:PORT``, ``udpin:HOST:PORT``) is invalid."""


class LinkError(SmcpilotError):
    """A MAVLink link could not be opened or was used after it was closed."""


class LinkClosedError(LinkError):
    """A MAVLink link was used after :meth:`close`."""


class TlogError(SmcpilotError):
    """A telemetry log (``.tlog``) could not be written or read."""


class TlogFormatError(TlogError):
    """A ``.tlog`` file is not a sequence of (8-byte timestamp, valid MAVLink packet) records."""


class WatchdogError(SmcpilotError):
    """A peer (the simulator, the flight controller) went silent for longer than its watchdog."""


class RateMismatchError(ConfigError):
    """Lockstep: the simulator's state period is not the flight controller's control period."""


class ParamError(ConfigError):
    """A flight-controller parameter name or value is invalid (unknown name, out of range, not
    finite, not a whole number), or a parameter file is broken (the message names the line)."""
