"""The motor-command mapping shared by the flight controller and the simulator.

On the wire each motor gets a command ``c`` in [0, 1]. The mapping is linear in thrust above
idle (thrust is ``Kp omega^2``)::

    omega^2 = omega_idle^2 + c (omega_max^2 - omega_idle^2)        [(rad/s)^2]

with ``omega_idle`` = :attr:`VehicleParams.rotor_speed_idle_radps` and ``omega_max`` =
:attr:`VehicleParams.rotor_speed_max_radps`. A disarmed vehicle commands omega = 0.

A command outside [0, 1] is clamped (+inf -> 1, -inf -> 0) and NaN is treated as 0, so a bad
float command never crashes the plant. Rotor numbering is the paper's (see
:mod:`smcpilot.model`): 1 right, 2 front, 3 left, 4 rear.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from smcpilot.vehicle import VehicleParams

_sqrt = math.sqrt

Quad = tuple[float, float, float, float]


def sanitize_command(c: float) -> float:
    """Clamp a motor command to [0, 1]; NaN -> 0, +inf -> 1, -inf -> 0."""
    if c > 0.0:  # NaN compares False and falls through to 0
        return c if c < 1.0 else 1.0
    return 0.0


def command_to_omega_sq(c: float, vehicle: VehicleParams) -> float:
    """Armed motor command c (clamped to [0, 1], NaN -> 0) -> rotor speed squared, (rad/s)^2."""
    idle_sq = vehicle.rotor_speed_idle_radps * vehicle.rotor_speed_idle_radps
    max_sq = vehicle.rotor_speed_max_radps * vehicle.rotor_speed_max_radps
    return idle_sq + sanitize_command(c) * (max_sq - idle_sq)


def omega_sq_to_command(w_sq: float, vehicle: VehicleParams) -> float:
    """Rotor speed squared [(rad/s)^2] -> motor command in [0, 1] (clamped; NaN -> 0).

    Inverse of :func:`command_to_omega_sq` inside [idle^2, max^2]; below idle gives 0, above max
    gives 1.
    """
    idle_sq = vehicle.rotor_speed_idle_radps * vehicle.rotor_speed_idle_radps
    max_sq = vehicle.rotor_speed_max_radps * vehicle.rotor_speed_max_radps
    return sanitize_command((w_sq - idle_sq) / (max_sq - idle_sq))


def command_to_omega_radps(c: float, vehicle: VehicleParams) -> float:
    """Armed motor command c -> steady-state rotor speed [rad/s] in [idle, max]."""
    return _sqrt(command_to_omega_sq(c, vehicle))


def commands_to_omega_sq(commands: Sequence[float], vehicle: VehicleParams, armed: bool = True) -> Quad:
    """Four motor commands -> four rotor speeds squared [(rad/s)^2]; all zero when disarmed."""
    if not armed:
        return (0.0, 0.0, 0.0, 0.0)
    idle_sq = vehicle.rotor_speed_idle_radps * vehicle.rotor_speed_idle_radps
    span_sq = vehicle.rotor_speed_max_radps * vehicle.rotor_speed_max_radps - idle_sq
    c1, c2, c3, c4 = commands
    return (
        idle_sq + sanitize_command(c1) * span_sq,
        idle_sq + sanitize_command(c2) * span_sq,
        idle_sq + sanitize_command(c3) * span_sq,
        idle_sq + sanitize_command(c4) * span_sq,
    )


def omega_sq_to_commands(w_sq: Sequence[float], vehicle: VehicleParams) -> Quad:
    """Four rotor speeds squared [(rad/s)^2] -> four motor commands, each clamped to [0, 1]."""
    idle_sq = vehicle.rotor_speed_idle_radps * vehicle.rotor_speed_idle_radps
    inv_span = 1.0 / (vehicle.rotor_speed_max_radps * vehicle.rotor_speed_max_radps - idle_sq)
    w1, w2, w3, w4 = w_sq
    return (
        sanitize_command((w1 - idle_sq) * inv_span),
        sanitize_command((w2 - idle_sq) * inv_span),
        sanitize_command((w3 - idle_sq) * inv_span),
        sanitize_command((w4 - idle_sq) * inv_span),
    )


def hover_command(vehicle: VehicleParams) -> float:
    """The command that holds level hover with all four rotors equal (clamped to [0, 1])."""
    return omega_sq_to_command(vehicle.hover_omega_sq, vehicle)
