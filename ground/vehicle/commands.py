"""Commands: ``COMMAND_LONG``/``COMMAND_INT`` with their ``COMMAND_ACK``, and the flight
commands built on them (arm, disarm, modes, take-off, go-to, land, RTL, home).

:class:`Commands` is the part of :class:`~ground.vehicle.Vehicle` reached as ``vehicle.commands``
(every method is also a :class:`~ground.vehicle.Vehicle` method of the same name).

Retries are wall clock: no ``COMMAND_ACK`` within ``ack_timeout_s`` -> the command is re-sent
(COMMAND_LONG with ``confirmation`` + 1), up to ``command_tries`` sends;
``MAV_RESULT_IN_PROGRESS`` extends the wait. Units: altitudes metres above home, local positions
metres NED from home, latitude/longitude degrees, headings degrees (0 north, 90 east).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from ground.vehicle.errors import CommandDenied, CommandTimeout, SetpointRefused, VehicleTimeout
from ground.vehicle.exchange import refusal_reason
from ground.vehicle.modes import mode_number
from ground.vehicle.names import command_name
from ground.vehicle.telemetry import HomePosition, StatusText
from smcpilot.errors import ConfigError
from smcpilot.protocol import COPTER_MODES, FORCE_ARM_MAGIC

if TYPE_CHECKING:
    from ground.vehicle.vehicle import Vehicle

__all__ = ["Commands"]

_NAN = float("nan")


class Commands:
    """Commands to one vehicle (``vehicle.commands``); settings ``ack_timeout_s`` and
    ``command_tries`` are the vehicle's."""

    def __init__(self, vehicle: Vehicle) -> None:
        self._vehicle = vehicle
        self._t0_wall = time.monotonic()

    def _boot_ms(self) -> int:
        """Our ``time_boot_ms`` for the set-points we send: wall ms since this part was made (wraps at 2^32)."""
        return int((time.monotonic() - self._t0_wall) * 1000.0) & 0xFFFFFFFF

    # ------------------------------------------------------------------------------ commands
    def command_long(
        self,
        command: int,
        param1: float = 0.0,
        param2: float = 0.0,
        param3: float = 0.0,
        param4: float = 0.0,
        param5: float = 0.0,
        param6: float = 0.0,
        param7: float = 0.0,
        *,
        check: bool = False,
        tries: int | None = None,
    ) -> int:
        """Send COMMAND_LONG and return the MAV_RESULT of its COMMAND_ACK.

        No ACK within ``ack_timeout_s`` wall: re-sent with ``confirmation`` + 1, up to ``tries``
        (default ``command_tries``) sends, then :class:`CommandTimeout`. With ``check``, a result
        other than ACCEPTED raises :class:`CommandDenied` with the vehicle's STATUSTEXT reason.
        """
        v = self._vehicle
        mav = v.mav
        params = (param1, param2, param3, param4, param5, param6, param7)

        def build(attempt: int) -> mavlink.MAVLink_message:
            return mav.command_long_encode(v.target_system, v.target_component, command, min(attempt, 255), *params)

        return self._command(command, build, check=check, tries=tries)

    def command_int(
        self,
        command: int,
        *,
        frame: int = mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
        param1: float = 0.0,
        param2: float = 0.0,
        param3: float = 0.0,
        param4: float = 0.0,
        x: int = 0,
        y: int = 0,
        z: float = 0.0,
        check: bool = False,
        tries: int | None = None,
    ) -> int:
        """Send COMMAND_INT (``x``/``y`` = lat/lon × 1e7 in global frames) and return the MAV_RESULT;
        retried like :meth:`command_long` (COMMAND_INT has no confirmation field: same message)."""
        v = self._vehicle
        mav = v.mav

        def build(attempt: int) -> mavlink.MAVLink_message:
            return mav.command_int_encode(
                v.target_system, v.target_component, frame, command, 0, 0, param1, param2, param3, param4, x, y, z
            )

        return self._command(command, build, check=check, tries=tries)

    def _command(
        self, command: int, build: Callable[[int], mavlink.MAVLink_message], *, check: bool, tries: int | None
    ) -> int:
        v = self._vehicle
        n_tries = v.command_tries if tries is None else tries
        texts: list[StatusText] = []
        result: int | None = None
        with v.subscribe(("COMMAND_ACK", "STATUSTEXT")) as sub:
            for attempt in range(n_tries):
                v.send(build(attempt))
                deadline = time.monotonic() + v.ack_timeout_s
                while result is None:
                    remaining = deadline - time.monotonic()
                    if remaining <= 0:
                        break
                    msg = sub.get(remaining)
                    if msg is None:
                        break
                    if msg.get_type() == "STATUSTEXT":
                        texts.append(StatusText.received(msg, v.sim_time_s))
                        continue
                    if msg.command != command:
                        continue
                    if msg.result == mavlink.MAV_RESULT_IN_PROGRESS:
                        deadline = time.monotonic() + v.ack_timeout_s
                        continue
                    result = msg.result
                if result is not None:
                    break
            if result is None:
                raise CommandTimeout(
                    f"no COMMAND_ACK for {command_name(command)} after {n_tries} tries ({n_tries * v.ack_timeout_s:g} s wall)",
                    what=f"COMMAND_ACK for {command_name(command)}",
                    sim_time_s=v.sim_time_s,
                )
            if check and result != mavlink.MAV_RESULT_ACCEPTED:
                reason = refusal_reason(v, sub, texts)
                raise CommandDenied(command, result, reason)
        return result

    # ------------------------------------------------------------------------- flight commands
    def arm(self, force: bool = False, *, wait: bool = True, timeout_sim_s: float = 5.0) -> None:
        """COMPONENT_ARM_DISARM arm (``force``: skip the pre-arm checks); then wait for the
        armed HEARTBEAT. Raises :class:`CommandDenied` with the reason."""
        self.command_long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1.0, FORCE_ARM_MAGIC if force else 0.0, check=True)
        if wait:
            self._vehicle.wait_armed(timeout_sim_s)

    def disarm(self, force: bool = False, *, wait: bool = True, timeout_sim_s: float = 5.0) -> None:
        """COMPONENT_ARM_DISARM disarm (``force`` is needed in the air); then wait for disarmed."""
        self.command_long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0.0, FORCE_ARM_MAGIC if force else 0.0, check=True)
        if wait:
            self._vehicle.wait_disarmed(timeout_sim_s)

    def set_mode(self, name: str | int, *, wait: bool = True, timeout_sim_s: float = 5.0) -> None:
        """MAV_CMD_DO_SET_MODE (param1 CUSTOM_MODE_ENABLED, param2 the ArduCopter mode number);
        then wait until the HEARTBEAT shows it. Raises :class:`UnknownModeError` for a bad name,
        :class:`CommandDenied` when the vehicle refuses."""
        number = mode_number(name)
        self.command_long(
            mavlink.MAV_CMD_DO_SET_MODE, float(mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), float(number), check=True
        )
        if wait:
            self._vehicle.wait_mode(number, timeout_sim_s)

    def takeoff(self, alt_m: float) -> None:
        """MAV_CMD_NAV_TAKEOFF to ``alt_m`` metres above home (vehicle armed, in GUIDED).
        Returns once accepted; :meth:`~ground.vehicle.Vehicle.wait_altitude` waits for the climb."""
        self.command_long(mavlink.MAV_CMD_NAV_TAKEOFF, param7=float(alt_m), check=True)

    def goto_ned(self, north_m: float, east_m: float, down_m: float, yaw_deg: float | None = None, *, verify: bool = True) -> None:
        """Fly to a local NED point (metres from home; down negative = up) with
        SET_POSITION_TARGET_LOCAL_NED; yaw in degrees (0 north, 90 east), None keeps the heading.

        The vehicle only follows set-points in GUIDED: if it is in another mode, this switches to
        GUIDED first. The message has no acknowledgement, so with ``verify`` (the default) this
        waits for the vehicle's verdict: its target echoed in ``POSITION_TARGET_LOCAL_NED``
        (taken), or its refusal ``STATUSTEXT`` ("Set-point ..."), or an echo that keeps another
        target after three sends (:class:`SetpointRefused`); nothing within
        ``ack_timeout_s * command_tries`` wall seconds: :class:`VehicleTimeout`.
        :meth:`~ground.vehicle.Vehicle.wait_position_ned` waits for the flight.
        """
        for name, v in (("north_m", north_m), ("east_m", east_m), ("down_m", down_m)):
            if not math.isfinite(v):
                raise ConfigError(f"goto_ned {name} must be finite, got {v!r}")
        if yaw_deg is not None and not math.isfinite(yaw_deg):
            raise ConfigError(f"goto_ned yaw_deg must be finite or None, got {yaw_deg!r}")
        vehicle = self._vehicle
        if vehicle.telemetry.mode_number != COPTER_MODES["GUIDED"]:
            self.set_mode("GUIDED")
        mask = (
            mavlink.POSITION_TARGET_TYPEMASK_VX_IGNORE
            | mavlink.POSITION_TARGET_TYPEMASK_VY_IGNORE
            | mavlink.POSITION_TARGET_TYPEMASK_VZ_IGNORE
            | mavlink.POSITION_TARGET_TYPEMASK_AX_IGNORE
            | mavlink.POSITION_TARGET_TYPEMASK_AY_IGNORE
            | mavlink.POSITION_TARGET_TYPEMASK_AZ_IGNORE
            | mavlink.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE
        )
        yaw_rad = 0.0
        if yaw_deg is None:
            mask |= mavlink.POSITION_TARGET_TYPEMASK_YAW_IGNORE
        else:
            yaw_rad = math.radians(yaw_deg)
        msg = vehicle.mav.set_position_target_local_ned_encode(
            self._boot_ms(), vehicle.target_system, vehicle.target_component, mavlink.MAV_FRAME_LOCAL_NED, mask,
            float(north_m), float(east_m), float(down_m), 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, yaw_rad, 0.0,
        )  # fmt: skip
        if not verify:
            vehicle.send(msg)
            return
        want = (float(north_m), float(east_m), float(down_m))

        def taken(m: mavlink.MAVLink_message) -> bool:
            return all(abs(a - b) <= 1e-3 + 1e-6 * abs(b) for a, b in zip((m.x, m.y, m.z), want))

        sends = 1
        wall_s = vehicle.ack_timeout_s * max(1, vehicle.command_tries)
        with vehicle.subscribe(("POSITION_TARGET_LOCAL_NED", "STATUSTEXT")) as sub:
            vehicle.send(msg)
            deadline = time.monotonic() + wall_s
            while (remaining := deadline - time.monotonic()) > 0:
                got = sub.get(remaining)
                if got is None:
                    break
                if got.get_type() == "STATUSTEXT":
                    text = StatusText.received(got, vehicle.sim_time_s).text
                    if text.startswith("Set-point"):
                        raise SetpointRefused(text.removeprefix("Set-point refused: "))
                    continue
                if taken(got):
                    return
                if sends >= 3:  # the vehicle streams another target: ours was not taken
                    raise SetpointRefused(f"the vehicle keeps its target NED ({got.x:.2f}, {got.y:.2f}, {got.z:.2f}) m")
                vehicle.send(msg)  # lost on the way, or it crossed an older echo: once more
                sends += 1
        raise VehicleTimeout(
            f"no verdict on the set-point within {wall_s:g} s wall (no POSITION_TARGET_LOCAL_NED echo, no refusal)",
            what="POSITION_TARGET_LOCAL_NED echo",
            sim_time_s=vehicle.sim_time_s,
        )

    def goto_global(self, lat_deg: float, lon_deg: float, alt_rel_m: float, yaw_deg: float | None = None) -> None:
        """Fly to a global point (altitude ``alt_rel_m`` above home) with COMMAND_INT
        MAV_CMD_DO_REPOSITION (the vehicle switches to GUIDED); yaw None keeps the heading."""
        for name, v in (("lat_deg", lat_deg), ("lon_deg", lon_deg), ("alt_rel_m", alt_rel_m)):
            if not math.isfinite(v):
                raise ConfigError(f"goto_global {name} must be finite, got {v!r}")
        self.command_int(
            mavlink.MAV_CMD_DO_REPOSITION,
            frame=mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
            param1=-1.0,
            param2=float(mavlink.MAV_DO_REPOSITION_FLAGS_CHANGE_MODE),
            param4=_NAN if yaw_deg is None else float(yaw_deg),
            x=int(round(lat_deg * 1e7)),
            y=int(round(lon_deg * 1e7)),
            z=float(alt_rel_m),
            check=True,
        )

    def land(self) -> None:
        """MAV_CMD_NAV_LAND (unused parameters NaN, as MAVSDK sends them): descend here, disarm on touchdown."""
        self.command_long(mavlink.MAV_CMD_NAV_LAND, 0.0, 0.0, 0.0, _NAN, _NAN, _NAN, 0.0, check=True)

    def rtl(self) -> None:
        """MAV_CMD_NAV_RETURN_TO_LAUNCH."""
        self.command_long(mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH, check=True)

    def request_message(self, message_id: int) -> int:
        """MAV_CMD_REQUEST_MESSAGE: have the vehicle send one message once; returns the MAV_RESULT."""
        return self.command_long(mavlink.MAV_CMD_REQUEST_MESSAGE, float(message_id))

    def get_home(self, timeout_s: float = 5.0) -> HomePosition:
        """The vehicle's home: the last HOME_POSITION, or asked for (MAV_CMD_GET_HOME_POSITION,
        re-asked every ``ack_timeout_s``) for up to ``timeout_s`` wall seconds."""
        v = self._vehicle
        home = v.telemetry.home
        if home is not None:
            return home
        deadline = time.monotonic() + timeout_s
        mav = v.mav
        with v.subscribe("HOME_POSITION") as sub:
            while True:
                v.send(
                    mav.command_long_encode(
                        v.target_system, v.target_component, mavlink.MAV_CMD_GET_HOME_POSITION, 0, 0, 0, 0, 0, 0, 0, 0
                    )
                )
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    break
                if sub.get(min(remaining, v.ack_timeout_s)) is not None:
                    home = v.telemetry.home
                    assert home is not None
                    return home
        raise VehicleTimeout(
            f"no HOME_POSITION from the vehicle within {timeout_s:g} s wall",
            what="HOME_POSITION",
            sim_time_s=v.sim_time_s,
        )
