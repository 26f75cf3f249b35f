"""rotorpy's quadrotor parameters as our :class:`~smcpilot.vehicle.VehicleParams` (a pure converter).

rotorpy (a multirotor simulator with aerodynamics, on PyPI) describes a vehicle by a ``quad_params``
dict (``rotorpy/vehicles/*_params.py``): SI units, body frame FLU (x forward, y left, z up), rotor
i at ``rotor_pos['r<i>']`` pushing ``k_eta * omega_i**2`` up, twisting the body by
``rotor_directions[i] * k_m * omega_i**2`` about z (so -1 is a rotor turning counter-clockwise
seen from above), a first-order motor lag ``tau_m``, rotor speeds in [``rotor_speed_min``,
``rotor_speed_max``] rad/s, and quadratic frame drag ``c_D* |v| v`` plus rotor drag ``k_d``
(N per rad/s per m/s, per rotor) and induced inflow ``k_z``.

The mapping (each of our keys, from rotorpy's):

- ``mass_kg`` = mass; ``ixx/iyy/izz_kg_m2`` = Ixx/Iyy/Izz (products of inertia must be 0: ours
  has none); ``gravity_mps2`` = 9.81 (rotorpy's);
- ``arm_length_m`` = the rotors' distance from the centre (all four must agree to 1 %);
- ``thrust_coeff_n_s2`` = k_eta; ``drag_coeff_n_m_s2`` = k_m;
- ``motor_time_constant_s`` = tau_m; ``rotor_speed_max_radps`` = rotor_speed_max;
  ``rotor_speed_idle_radps`` = rotor_speed_min;
- ``lin_drag_{x,y}_n_s_m`` = c_D{x,y} * ``drag_speed_mps`` + 4 k_d omega_hover and
  ``lin_drag_z_n_s_m`` = c_Dz * ``drag_speed_mps`` + 4 k_z omega_hover: our drag is linear in the
  velocity, rotorpy's frame drag quadratic, so it is linearised at ``drag_speed_mps`` (1 m/s by
  default: the speeds of a set-point flight), and its rotor drag and inflow taken at hover;
- ``rot_drag_*`` and ``rotor_inertia_kg_m2`` = 0: rotorpy models neither rotational aero
  friction nor rotor gyroscopic torque (``k_flap`` blade flapping, if non-zero, is left out).

:func:`rotorpy_frame` says which motor order the rotors are in: PX4's quadrotor X (``quad-x``:
1 front right CCW, 2 rear left CCW, 3 front left CW, 4 rear right CW; rotorpy's
``px4_sihsim_quadx_params``) or our plus (``plus``: 1 right CW, 2 front CCW, 3 left CW, 4 rear
CCW), the ``--px4-frame`` of ``python -m fc --sim px4``; any other layout is an error naming it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from smcpilot.errors import VehicleFileError
from smcpilot.vehicle import VehicleParams

#: rotorpy's gravity (rotorpy.vehicles.multirotor), m/s^2.
ROTORPY_GRAVITY_MPS2 = 9.81
#: (x sign, y sign, counter-clockwise) of rotors 1..4, FLU, for each motor order we fly.
_LAYOUTS = {
    "quad-x": ((1, -1, True), (-1, 1, True), (1, 1, False), (-1, -1, False)),
    "plus": ((0, -1, False), (1, 0, True), (0, 1, False), (-1, 0, True)),
}


def _sign(v: float, scale: float) -> int:
    return 0 if abs(v) < 1e-3 * scale else (1 if v > 0 else -1)


def _rotors(p: Mapping[str, Any]) -> list[tuple[float, float, float]]:
    if int(p.get("num_rotors", 0)) != 4:
        raise VehicleFileError(f"rotorpy params: num_rotors must be 4 (a quadrotor), got {p.get('num_rotors')!r}")
    pos = p["rotor_pos"]
    dirs = list(p["rotor_directions"])
    return [(float(pos[f"r{i}"][0]), float(pos[f"r{i}"][1]), float(dirs[i - 1])) for i in range(1, 5)]


def rotorpy_frame(p: Mapping[str, Any]) -> str:
    """``"quad-x"`` or ``"plus"``: the motor order of rotorpy's rotors (see the module docstring)."""
    rotors = _rotors(p)
    scale = max(math.hypot(x, y) for x, y, _ in rotors)
    got = tuple((_sign(x, scale), _sign(y, scale), d < 0) for x, y, d in rotors)
    for name, layout in _LAYOUTS.items():
        if got == layout:
            return name
    raise VehicleFileError(
        "rotorpy params: the rotors are neither in PX4's quadrotor X order (1 front right CCW, 2 rear left CCW,"
        " 3 front left CW, 4 rear right CW) nor in our plus order (1 right CW, 2 front CCW, 3 left CW, 4 rear CCW):"
        f" (x, y, direction) = {[(round(x, 4), round(y, 4), int(d)) for x, y, d in rotors]}"
    )


def vehicle_from_rotorpy(p: Mapping[str, Any], *, name: str = "rotorpy", drag_speed_mps: float = 1.0) -> VehicleParams:
    """Our vehicle for rotorpy's ``quad_params`` (the mapping in the module docstring)."""
    rotors = _rotors(p)
    arms = [math.hypot(x, y) for x, y, _ in rotors]
    if max(arms) > 1.01 * min(arms):
        raise VehicleFileError(f"rotorpy params: the rotors are at different distances from the centre {arms}; ours are all at one")
    for key in ("Ixy", "Ixz", "Iyz"):
        if float(p.get(key, 0.0)) != 0.0:
            raise VehicleFileError(f"rotorpy params: {key} = {p[key]!r}: our vehicle has no products of inertia")
    mass = float(p["mass"])
    k_eta = float(p["k_eta"])
    omega_hover = math.sqrt(mass * ROTORPY_GRAVITY_MPS2 / (4.0 * k_eta))
    k_d = float(p.get("k_d", 0.0))
    k_z = float(p.get("k_z", 0.0))
    return VehicleParams(
        name=name,
        mass_kg=mass,
        gravity_mps2=ROTORPY_GRAVITY_MPS2,
        arm_length_m=sum(arms) / 4.0,
        thrust_coeff_n_s2=k_eta,
        drag_coeff_n_m_s2=float(p["k_m"]),
        ixx_kg_m2=float(p["Ixx"]),
        iyy_kg_m2=float(p["Iyy"]),
        izz_kg_m2=float(p["Izz"]),
        rot_drag_x_n_m_s2=0.0,
        rot_drag_y_n_m_s2=0.0,
        rot_drag_z_n_m_s2=0.0,
        lin_drag_x_n_s_m=float(p.get("c_Dx", 0.0)) * drag_speed_mps + 4.0 * k_d * omega_hover,
        lin_drag_y_n_s_m=float(p.get("c_Dy", 0.0)) * drag_speed_mps + 4.0 * k_d * omega_hover,
        lin_drag_z_n_s_m=float(p.get("c_Dz", 0.0)) * drag_speed_mps + 4.0 * k_z * omega_hover,
        rotor_inertia_kg_m2=0.0,
        motor_time_constant_s=float(p["tau_m"]),
        rotor_speed_max_radps=float(p["rotor_speed_max"]),
        rotor_speed_idle_radps=float(p.get("rotor_speed_min", 0.0)),
    )
