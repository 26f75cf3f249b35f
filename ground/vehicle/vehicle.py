""":class:`Vehicle`: the link to one vehicle (:class:`~ground.vehicle.link.Link`) with its parts
``commands`` (:class:`~ground.vehicle.commands.Commands`), ``params``
(:class:`~ground.vehicle.params.Params`) and ``mission``
(:class:`~ground.vehicle.mission.Mission`), as crazyflie-lib-python's ``Crazyflie`` composes
``Commander``, ``Param`` and ``Log``. The flight, parameter and mission methods of
:class:`Vehicle` delegate to the parts.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from ground.vehicle.commands import Commands
from ground.vehicle.items import MissionItem
from ground.vehicle.link import Link
from ground.vehicle.mission import Mission
from ground.vehicle.params import Params
from ground.vehicle.telemetry import HomePosition
from smcpilot.errors import ConfigError

__all__ = ["Vehicle"]


class Vehicle(Link):
    """A connection to one vehicle; see :mod:`ground.vehicle`. Use as a context manager.

    ``url``: ``udpin:HOST:PORT`` (listen where the FC sends telemetry; ``udpin:127.0.0.1:0`` binds
    a free port, see :attr:`local_address`) or ``udpout:HOST:PORT`` (write to the FC's port).
    ``system_id``: talk to this vehicle only (default: the first vehicle heard).
    ``connect_timeout_s``: wall seconds to wait for the vehicle's HEARTBEAT in :meth:`connect`.
    Protocol retries: ``ack_timeout_s``/``command_tries`` (commands), ``param_timeout_s``/
    ``param_tries``, ``mission_timeout_s``/``mission_tries`` (all wall clock).
    Waits: ``wall_margin_s``, ``wall_per_sim_s`` (wall safety limit of a wait of T simulated
    seconds = margin + per_sim × T) and ``stall_timeout_s`` (give up when the vehicle has been
    silent this many wall seconds).
    ``signing_key``: MAVLink 2 signing, a 32-byte key or a key file (64 hex digits or a
    passphrase, see :func:`smcpilot.signing.load_key`); None: unsigned (docs/security.md).

    Parts: ``commands`` (:class:`~ground.vehicle.commands.Commands`), ``params``
    (:class:`~ground.vehicle.params.Params`: ``get``, ``set``, ``list``) and ``mission``
    (:class:`~ground.vehicle.mission.Mission`: ``upload``, ``download``, ``clear``, ``start``,
    ``set_current``). The settings stay attributes of the vehicle, read by the parts on every use.
    """

    def __init__(
        self,
        url: str,
        *,
        system_id: int | None = None,
        connect_timeout_s: float = 15.0,
        ack_timeout_s: float = 1.0,
        command_tries: int = 5,
        param_timeout_s: float = 1.0,
        param_tries: int = 5,
        mission_timeout_s: float = 1.5,
        mission_tries: int = 5,
        wall_margin_s: float = 30.0,
        wall_per_sim_s: float = 3.0,
        stall_timeout_s: float = 10.0,
        statustext_history: int = 100,
        heartbeat_period_s: float = 1.0,
        signing_key: bytes | str | os.PathLike[str] | None = None,
    ) -> None:
        for name, value in (
            ("connect_timeout_s", connect_timeout_s),
            ("ack_timeout_s", ack_timeout_s),
            ("param_timeout_s", param_timeout_s),
            ("mission_timeout_s", mission_timeout_s),
            ("wall_margin_s", wall_margin_s),
            ("stall_timeout_s", stall_timeout_s),
            ("heartbeat_period_s", heartbeat_period_s),
        ):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ConfigError(f"Vehicle {name} must be a finite number > 0, got {value!r}")
        for name, count in (("command_tries", command_tries), ("param_tries", param_tries), ("mission_tries", mission_tries)):
            if not isinstance(count, int) or count < 1:
                raise ConfigError(f"Vehicle {name} must be an integer >= 1, got {count!r}")
        if system_id is not None and not 1 <= system_id <= 254:
            raise ConfigError(f"system_id must lie in 1..254, got {system_id}")
        super().__init__(
            url,
            system_id=system_id,
            connect_timeout_s=connect_timeout_s,
            wall_margin_s=wall_margin_s,
            wall_per_sim_s=wall_per_sim_s,
            stall_timeout_s=stall_timeout_s,
            statustext_history=statustext_history,
            heartbeat_period_s=heartbeat_period_s,
            signing_key=signing_key,
        )
        self.ack_timeout_s = float(ack_timeout_s)
        self.command_tries = command_tries
        self.param_timeout_s = float(param_timeout_s)
        self.param_tries = param_tries
        self.mission_timeout_s = float(mission_timeout_s)
        self.mission_tries = mission_tries
        #: COMMAND_LONG/COMMAND_INT and the flight commands.
        self.commands = Commands(self)
        #: the parameter protocol.
        self.params = Params(self)
        #: the mission protocol and the mission commands.
        self.mission = Mission(self)

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
        """COMMAND_LONG, retried until its COMMAND_ACK; returns the MAV_RESULT (see :meth:`Commands.command_long`)."""
        return self.commands.command_long(
            command, param1, param2, param3, param4, param5, param6, param7, check=check, tries=tries
        )

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
        """COMMAND_INT, retried until its COMMAND_ACK; returns the MAV_RESULT (see :meth:`Commands.command_int`)."""
        return self.commands.command_int(
            command, frame=frame, param1=param1, param2=param2, param3=param3, param4=param4, x=x, y=y, z=z,
            check=check, tries=tries,
        )  # fmt: skip

    def arm(self, force: bool = False, *, wait: bool = True, timeout_sim_s: float = 5.0) -> None:
        """Arm (``force``: skip the pre-arm checks) and wait for it (see :meth:`Commands.arm`)."""
        self.commands.arm(force, wait=wait, timeout_sim_s=timeout_sim_s)

    def disarm(self, force: bool = False, *, wait: bool = True, timeout_sim_s: float = 5.0) -> None:
        """Disarm (``force`` in the air) and wait for it (see :meth:`Commands.disarm`)."""
        self.commands.disarm(force, wait=wait, timeout_sim_s=timeout_sim_s)

    def set_mode(self, name: str | int, *, wait: bool = True, timeout_sim_s: float = 5.0) -> None:
        """Switch to an ArduCopter mode and wait for it (see :meth:`Commands.set_mode`)."""
        self.commands.set_mode(name, wait=wait, timeout_sim_s=timeout_sim_s)

    def takeoff(self, alt_m: float) -> None:
        """Take off to ``alt_m`` metres above home (see :meth:`Commands.takeoff`)."""
        self.commands.takeoff(alt_m)

    def goto_ned(self, north_m: float, east_m: float, down_m: float, yaw_deg: float | None = None, *, verify: bool = True) -> None:
        """Fly to a local NED point, metres from home; waits for the vehicle's verdict unless
        ``verify`` is False (see :meth:`Commands.goto_ned`)."""
        self.commands.goto_ned(north_m, east_m, down_m, yaw_deg, verify=verify)

    def goto_global(self, lat_deg: float, lon_deg: float, alt_rel_m: float, yaw_deg: float | None = None) -> None:
        """Fly to a global point, altitude above home (see :meth:`Commands.goto_global`)."""
        self.commands.goto_global(lat_deg, lon_deg, alt_rel_m, yaw_deg)

    def land(self) -> None:
        """Land here (see :meth:`Commands.land`)."""
        self.commands.land()

    def rtl(self) -> None:
        """Return to launch (see :meth:`Commands.rtl`)."""
        self.commands.rtl()

    def request_message(self, message_id: int) -> int:
        """Have the vehicle send one message once; returns the MAV_RESULT (see :meth:`Commands.request_message`)."""
        return self.commands.request_message(message_id)

    def get_home(self, timeout_s: float = 5.0) -> HomePosition:
        """The vehicle's home, asked for if not known yet (see :meth:`Commands.get_home`)."""
        return self.commands.get_home(timeout_s)

    # ----------------------------------------------------------------------------- parameters
    def get_param(self, name: str) -> float:
        """One parameter's value (see :meth:`Params.get`)."""
        return self.params.get(name)

    def set_param(self, name: str, value: float) -> float:
        """Set a parameter; returns the value now in force (see :meth:`Params.set`)."""
        return self.params.set(name, value)

    def list_params(self) -> dict[str, float]:
        """Every parameter, name -> value (see :meth:`Params.list`)."""
        return self.params.list()

    # -------------------------------------------------------------------------------- missions
    def upload_mission(self, items: Sequence[MissionItem]) -> None:
        """Upload the items to fly; home is inserted as item 0 (see :meth:`Mission.upload`)."""
        self.mission.upload(items)

    def download_mission(self, *, include_home: bool = False) -> list[MissionItem]:
        """The vehicle's mission, home stripped unless ``include_home`` (see :meth:`Mission.download`)."""
        return self.mission.download(include_home=include_home)

    def clear_mission(self) -> None:
        """Clear the vehicle's mission (see :meth:`Mission.clear`)."""
        self.mission.clear()

    def start_mission(self, first_seq: int = 0) -> None:
        """MAV_CMD_MISSION_START, switching to AUTO (see :meth:`Mission.start`)."""
        self.mission.start(first_seq)

    def set_current_item(self, seq: int) -> None:
        """Continue at vehicle sequence number ``seq``, 1 = the first item after home (see :meth:`Mission.set_current`)."""
        self.mission.set_current(seq)

    def __repr__(self) -> str:
        st = self._state
        return f"Vehicle({self.url!r}, system={st.system_id}, mode={st.mode_name}, armed={st.armed})"
