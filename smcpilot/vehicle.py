"""Vehicle parameters: one frozen dataclass, units in every name, defaults from the spec.

The defaults are the spec's parameter set (``docs/pid-smc.md`` §1, a widely used identification
of a small quadrotor in the paper's notation) plus the actuator limits a real vehicle has
(thrust/weight about 2, an idle speed, a first-order motor lag), which the paper's ideal plant
ignores.

Vehicles are stored as TOML with the field names below as keys, under a ``[vehicle]`` table::

    [vehicle]
    name = "my-quad"
    mass_kg = 0.486
    arm_length_m = 0.25

Keys left out take the default; an unknown key, a non-number or an out-of-range value raises
:class:`~smcpilot.errors.VehicleFileError` naming the key.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path
from typing import Any

from smcpilot.errors import VehicleFileError
from smcpilot.tomlfile import read_toml


@dataclass(frozen=True)
class VehicleParams:
    """Physical parameters of a quadrotor in the paper's notation (paper symbol in brackets).

    Frames: the paper's inertial frame with z up; body axes x forward, y left, z up.
    Rotor i produces thrust ``F_i = thrust_coeff * omega_i**2`` along body z.
    """

    name: str = "spec-default"
    #: [m] vehicle mass.
    mass_kg: float = 0.486
    #: [g] gravitational acceleration, m/s^2.
    gravity_mps2: float = 9.81
    #: [d] distance from the centre to each rotor axis.
    arm_length_m: float = 0.25
    #: [Kp] rotor thrust coefficient, N s^2 (thrust = Kp omega^2).
    thrust_coeff_n_s2: float = 2.9842e-5
    #: [Cd] rotor drag-torque coefficient, N m s^2 (torque = Cd omega^2).
    drag_coeff_n_m_s2: float = 3.2320e-7
    #: [Ix] roll moment of inertia.
    ixx_kg_m2: float = 3.8278e-3
    #: [Iy] pitch moment of inertia.
    iyy_kg_m2: float = 3.8278e-3
    #: [Iz] yaw moment of inertia.
    izz_kg_m2: float = 7.6566e-3
    #: [Kfax] aerodynamic friction torque coefficient about x, N m s^2 (torque = K phi_dot^2).
    rot_drag_x_n_m_s2: float = 5.5670e-4
    #: [Kfay] aerodynamic friction torque coefficient about y, N m s^2.
    rot_drag_y_n_m_s2: float = 5.5670e-4
    #: [Kfaz] aerodynamic friction torque coefficient about z, N m s^2.
    rot_drag_z_n_m_s2: float = 6.3540e-4
    #: [Kfdx] translational drag coefficient along x, N s/m (force = -K x_dot).
    lin_drag_x_n_s_m: float = 5.5670e-4
    #: [Kfdy] translational drag coefficient along y, N s/m.
    lin_drag_y_n_s_m: float = 5.5670e-4
    #: [Kfdz] translational drag coefficient along z, N s/m.
    lin_drag_z_n_s_m: float = 6.3540e-4
    #: [Jr] rotor (with propeller) moment of inertia about its axis.
    rotor_inertia_kg_m2: float = 2.8385e-5
    #: First-order motor lag time constant (realistic plant only).
    motor_time_constant_s: float = 0.02
    #: Maximum rotor speed (realistic plant only); the default gives thrust/weight = 2.
    rotor_speed_max_radps: float = 282.6
    #: Minimum rotor speed while armed (realistic plant only).
    rotor_speed_idle_radps: float = 50.0

    def __post_init__(self) -> None:
        for f in fields(self):
            if f.name == "name":
                if not isinstance(self.name, str) or not self.name:
                    raise VehicleFileError("vehicle key 'name' must be a non-empty string")
                continue
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise VehicleFileError(f"vehicle key {f.name!r} must be a number, got {value!r}")
            if not math.isfinite(value):
                raise VehicleFileError(f"vehicle key {f.name!r} must be finite, got {value!r}")
            if value < 0.0 or (value == 0.0 and f.name in _MUST_BE_POSITIVE):
                raise VehicleFileError(
                    f"vehicle key {f.name!r} must be {'> 0' if f.name in _MUST_BE_POSITIVE else '>= 0'},"
                    f" got {value!r}"
                )
        if self.rotor_speed_idle_radps >= self.rotor_speed_max_radps:
            raise VehicleFileError(
                "vehicle key 'rotor_speed_idle_radps' must be below 'rotor_speed_max_radps'"
            )

    # -- derived quantities -------------------------------------------------------------------
    @property
    def weight_n(self) -> float:
        """Weight m g, N."""
        return self.mass_kg * self.gravity_mps2

    @property
    def hover_omega_sq(self) -> float:
        """Rotor speed squared at hover, (rad/s)^2: m g / (4 Kp)."""
        return self.weight_n / (4.0 * self.thrust_coeff_n_s2)

    @property
    def thrust_to_weight(self) -> float:
        """Maximum total thrust over weight (realistic plant)."""
        return 4.0 * self.thrust_coeff_n_s2 * self.rotor_speed_max_radps**2 / self.weight_n

    # -- (de)serialisation ----------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any], *, source: str = "vehicle") -> VehicleParams:
        """Build from a mapping of field names; unknown keys raise naming the key and the source."""
        known = {f.name for f in fields(cls)}
        data = dict(data)
        for old, new in RENAMED_KEYS.items():  # files written before the rename still load
            if old in data:
                if new in data:
                    raise VehicleFileError(f"{source}: both {old!r} (its old name) and {new!r} given")
                data[new] = data.pop(old)
        unknown = sorted(set(data) - known)
        if unknown:
            raise VehicleFileError(
                f"{source}: unknown vehicle key {unknown[0]!r} (known keys: {', '.join(sorted(known))})"
            )
        try:
            return replace(cls(), **dict(data))
        except VehicleFileError as exc:
            raise VehicleFileError(f"{source}: {exc}") from None

    @classmethod
    def from_toml(cls, path: str | Path) -> VehicleParams:
        """Load a vehicle TOML file (keys under ``[vehicle]``)."""
        p = Path(path)
        doc = read_toml(p, VehicleFileError, "vehicle file")
        table = doc.get("vehicle")
        if not isinstance(table, dict):
            raise VehicleFileError(f"{p}: missing [vehicle] table")
        extra = sorted(set(doc) - {"vehicle"})
        if extra:
            raise VehicleFileError(f"{p}: unknown top-level table or key {extra[0]!r}")
        return cls.from_mapping(table, source=str(p))

    def to_toml(self) -> str:
        """The TOML text :meth:`from_toml` reads back to an equal object."""
        lines = ["[vehicle]"]
        for f in fields(self):
            value = getattr(self, f.name)
            lines.append(f"{f.name} = {value!r}" if f.name != "name" else f"name = {json.dumps(value, ensure_ascii=False).replace(chr(0x7F), chr(92) + 'u007f')}")
        return "\n".join(lines) + "\n"


#: Vehicle keys renamed (old -> new): rad/s is written ``radps`` everywhere.
RENAMED_KEYS = {"rotor_speed_max_rad_s": "rotor_speed_max_radps", "rotor_speed_idle_rad_s": "rotor_speed_idle_radps"}

_MUST_BE_POSITIVE = frozenset(
    {
        "mass_kg",
        "gravity_mps2",
        "arm_length_m",
        "thrust_coeff_n_s2",
        "drag_coeff_n_m_s2",
        "ixx_kg_m2",
        "iyy_kg_m2",
        "izz_kg_m2",
        "motor_time_constant_s",
        "rotor_speed_max_radps",
    }
)

#: The spec's default vehicle.
DEFAULT_VEHICLE = VehicleParams()
