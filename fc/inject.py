"""``MAV_CMD_INJECT_FAILURE`` (420) as changes of the simulator's ``SIM_*`` parameters.

The flight controller injects nothing itself: a failure is a change of the simulator's live
parameters (:data:`smcpilot.faults.SIM_PARAMS`), forwarded over the sim link exactly as a
ground station's ``PARAM_SET`` of that name would be (:mod:`fc.gcs`). :func:`injection` is the
pure mapping, after PX4's command (param1 failure unit, param2 failure type, param3 instance):

============================ ================================================================
unit                         what it changes
============================ ================================================================
``SYSTEM_MOTOR``             ``OFF``: sets motor ``instance``'s bit (1..4; 0 = all) in
                             ``SIM_MOT_OFF``; ``OK``: clears it
``SENSOR_GYRO``              ``SIM_GYR_FAULT`` (+ ``_V``): ``OK`` 0, ``STUCK`` 1, ``WRONG`` 2
                             (bias 0.1 rad/s), ``GARBAGE`` 3 (noise 0.5 rad/s), ``OFF`` 4
                             (dropout), ``DELAYED`` 5 (0.1 s)
``SENSOR_ACCEL``             ``SIM_ACC_FAULT`` the same (bias 1 m/s², noise 5 m/s²)
``SENSOR_GPS``               ``SIM_POS_FAULT`` and ``SIM_VEL_FAULT`` the same (bias 5 m and
                             1 m/s, noise 2 m and 1 m/s)
============================ ================================================================

Sensors have one instance (0 or 1). Anything else the simulator cannot do — other units, the
types ``SLOW`` and ``INTERMITTENT``, a second sensor — is refused with ``UNSUPPORTED`` and a
reason; numbers that are not whole, not finite or not in MAVLink's enums are ``DENIED``.
Every reason fits one ``STATUSTEXT`` (50 characters).
Refusals are :class:`fc.modes.Refusal` values; :mod:`fc.gcs` turns them into ``COMMAND_ACK``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import NamedTuple

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from fc.modes.base import Refusal
from smcpilot.faults import SENSOR_FAULT_PARAM, FaultError, sensor_fault_from_params

M = mavlink
_UNITS: dict[int, str] = {
    k: e.name.removeprefix("FAILURE_UNIT_") for k, e in M.enums["FAILURE_UNIT"].items() if not e.name.endswith("ENUM_END")
}
_TYPES: dict[int, str] = {
    k: e.name.removeprefix("FAILURE_TYPE_") for k, e in M.enums["FAILURE_TYPE"].items() if not e.name.endswith("ENUM_END")
}
#: failure type -> SIM_*_FAULT mode number (0 none, 1 stuck, 2 bias, 3 noise, 4 dropout, 5 delay).
_SENSOR_MODE = {
    M.FAILURE_TYPE_OK: 0,
    M.FAILURE_TYPE_STUCK: 1,
    M.FAILURE_TYPE_WRONG: 2,
    M.FAILURE_TYPE_GARBAGE: 3,
    M.FAILURE_TYPE_OFF: 4,
    M.FAILURE_TYPE_DELAYED: 5,
}
_MODE_WORDS = ("ok", "stuck", "bias", "noise", "dropout", "delay")
#: delay of FAILURE_TYPE_DELAYED, s.
DELAY_S = 0.1
#: unit -> ((sensor, bias value, noise std, unit text), ...): the default fault values per sensor.
_SENSOR_UNITS: dict[int, tuple[tuple[str, float, float, str], ...]] = {
    M.FAILURE_UNIT_SENSOR_GYRO: (("gyro", 0.1, 0.5, "rad/s"),),
    M.FAILURE_UNIT_SENSOR_ACCEL: (("accel", 1.0, 5.0, "m/s^2"),),
    M.FAILURE_UNIT_SENSOR_GPS: (("position", 5.0, 2.0, "m"), ("velocity", 1.0, 1.0, "m/s")),
}
_UNIT_NAMES = {M.FAILURE_UNIT_SENSOR_GYRO: "gyro", M.FAILURE_UNIT_SENSOR_ACCEL: "accel", M.FAILURE_UNIT_SENSOR_GPS: "GPS"}
_ALL_MOTORS = 0b1111


class Injection(NamedTuple):
    """An accepted failure injection: the ``SIM_*`` changes in the order to send them (only
    values that change), and the announcement for ``STATUSTEXT``."""

    changes: tuple[tuple[str, float], ...]
    text: str
    #: True for a failure, False for FAILURE_TYPE_OK (cleared): the announcement's severity.
    failure: bool


def _whole(v: float) -> bool:
    return math.isfinite(v) and v >= 0.0 and v == int(v)


def injection(unit: float, ftype: float, instance: float, sim: Mapping[str, float]) -> Injection | Refusal:
    """The ``SIM_*`` changes of ``MAV_CMD_INJECT_FAILURE(unit, ftype, instance)`` given the
    simulator's values in force ``sim`` (name -> value), or why not."""
    if not (_whole(unit) and _whole(ftype) and _whole(instance)):
        return Refusal(f"Inject: not whole numbers: {unit:g}, {ftype:g}, {instance:g}")
    u, t, inst = int(unit), int(ftype), int(instance)
    if u not in _UNITS:
        return Refusal(f"Inject: unknown failure unit {u}")
    if t not in _TYPES:
        return Refusal(f"Inject: unknown failure type {t}")
    uname, tname = _UNITS[u], _TYPES[t]
    unsupported = M.MAV_RESULT_UNSUPPORTED
    if u == M.FAILURE_UNIT_SYSTEM_MOTOR:
        if not 0 <= inst <= 4:
            return Refusal(f"Inject: no motor {inst} (0 = all, 1..4)")
        if t not in (M.FAILURE_TYPE_OK, M.FAILURE_TYPE_OFF):
            return Refusal(f"Inject: motor {tname} not simulated", unsupported)
        bits = _ALL_MOTORS if inst == 0 else 1 << (inst - 1)
        old = int(sim["SIM_MOT_OFF"])
        new = old | bits if t == M.FAILURE_TYPE_OFF else old & ~bits
        which = "all motors" if inst == 0 else f"motor {inst}"
        motor_changes: tuple[tuple[str, float], ...] = (("SIM_MOT_OFF", float(new)),) if new != old else ()
        if t == M.FAILURE_TYPE_OFF:
            return Injection(motor_changes, f"Failure injected: {which} off", True)
        return Injection(motor_changes, f"Failure cleared: {which}", False)
    sensors = _SENSOR_UNITS.get(u)
    if sensors is None:
        return Refusal(f"Inject: {uname} not simulated", unsupported)
    if inst > 1:
        return Refusal(f"Inject: {_UNIT_NAMES[u]} {inst} not simulated (one sensor)", unsupported)
    mode = _SENSOR_MODE.get(t)
    if mode is None:
        return Refusal(f"Inject: {_UNIT_NAMES[u]} {tname} not simulated", unsupported)
    changes: list[tuple[str, float]] = []
    values: list[str] = []
    for sensor, bias, noise, unit_text in sensors:
        value = {2: bias, 3: noise, 5: DELAY_S}.get(mode, 0.0)
        if mode in (2, 3):
            values.append(f"{value:g} {unit_text}")
        changes.extend(_sensor_changes(sensor, mode, value, sim))
    name = _UNIT_NAMES[u]
    if mode == 0:
        return Injection(tuple(changes), f"Failure cleared: {name}", False)
    detail = f" {DELAY_S:g} s" if mode == 5 else (" " + ", ".join(values) if values else "")
    return Injection(tuple(changes), f"Failure injected: {name} {_MODE_WORDS[mode]}{detail}", True)


def _valid(sensor: str, mode: float, value: float) -> bool:
    try:
        sensor_fault_from_params(sensor, int(mode), value)
    except FaultError:
        return False
    return True


def _sensor_changes(sensor: str, mode: int, value: float, sim: Mapping[str, float]) -> list[tuple[str, float]]:
    """The (mode, value) parameter changes of one sensor, ordered so that the pair in force is a
    valid fault after each of them (the simulator checks every change on its own)."""
    mode_name = SENSOR_FAULT_PARAM[sensor]
    value_name = mode_name + "_V"
    old_mode, old_value = sim[mode_name], sim[value_name]
    out: list[tuple[str, float]] = []
    if float(mode) == old_mode and value == old_value:
        return out
    if float(mode) == old_mode:
        return [(value_name, value)]
    if value == old_value:
        return [(mode_name, float(mode))]
    if mode == 0 or _valid(sensor, mode, old_value):
        return [(mode_name, float(mode)), (value_name, value)]
    if _valid(sensor, old_mode, value):
        return [(value_name, value), (mode_name, float(mode))]
    return [(mode_name, 0.0), (value_name, value), (mode_name, float(mode))]


__all__ = ["DELAY_S", "Injection", "injection"]
