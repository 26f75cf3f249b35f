"""A MAVLink ground-station client for smcpilot (and any ArduCopter-like vehicle).

:class:`Vehicle` is what tests, scripts and ``smcpilot gcs`` use to fly the flight controller
through its ground link (docs/gcs-protocol.md)::

    with Vehicle("udpin:127.0.0.1:14550") as v:        # where the FC sends its telemetry
        v.arm()
        v.takeoff(3.0)
        v.wait_altitude(3.0, tol_m=0.3, timeout_sim_s=20)
        v.goto_ned(4.0, -3.0, -3.0, yaw_deg=90)
        v.wait_position_ned(4.0, -3.0, -3.0, tol_m=0.5, timeout_sim_s=30)
        v.land()
        v.wait_disarmed(timeout_sim_s=30)

A vehicle is its link (connection, receiver thread, telemetry, waits) plus three parts, as
crazyflie-lib-python's ``Crazyflie`` composes ``Commander``, ``Param`` and ``Log``:
``v.commands`` (:class:`Commands`: COMMAND_LONG/COMMAND_INT and the flight commands),
``v.params`` (:class:`Params`: ``v.params.get("SMC_Z_KP")``, ``v.params.set(name, value)``,
``v.params.list()``) and ``v.mission`` (:class:`Mission`: ``v.mission.upload(items)``,
``download()``, ``clear()``, ``start()``, ``set_current(seq)``). The :class:`Vehicle` methods of
the same jobs (``arm``, ``get_param``, ``upload_mission``, ...) delegate to the parts.

Connection URLs are :mod:`smcpilot.link`'s: ``udpin:HOST:PORT`` listens where the FC sends
telemetry (the FC's ``--gcs udp:HOST:PORT``); ``udpout:HOST:PORT`` writes to the FC's own ground
port (the ``gcs=`` address it prints, :attr:`ground.sitl.Sitl.gcs_address`). We are system 255,
component 190 (MAV_COMP_ID_MISSIONPLANNER), and send a GCS ``HEARTBEAT`` at 1 Hz wall clock from a
background thread.

Threads: exactly one thread (the receiver) reads the link; it keeps the latest telemetry
(:class:`Telemetry`, read with :attr:`Vehicle.telemetry`), feeds subscribers
(:meth:`Vehicle.subscribe`) and wakes waiters. Every send goes through one lock (the link is not
thread-safe). Public methods may be called from any thread.

Two clocks:

- **simulated time** (``time_boot_ms`` of SYSTEM_TIME, ATTITUDE, LOCAL_POSITION_NED, ... — the FC
  stamps them with the simulator's clock in lockstep): every ``wait_*`` timeout is in simulated
  seconds (``timeout_sim_s``), so a test means the same thing at 1x and at 20x real time. Each wait
  also has a wall-clock safety limit (``wall_margin_s + wall_per_sim_s * timeout_sim_s``) and fails
  early when no telemetry arrives for ``stall_timeout_s`` wall seconds, so nothing hangs when the
  simulator stops.
- **wall clock**: protocol retries (a ground station lives in real time, as the FC's protocol
  timeouts do). Commands: ``COMMAND_LONG`` re-sent with ``confirmation`` + 1 when no
  ``COMMAND_ACK`` came within ``ack_timeout_s`` (1 s), up to ``command_tries`` (5) sends;
  ``MAV_RESULT_IN_PROGRESS`` extends the wait. Parameters: the request (or ``PARAM_SET``) re-sent
  after 1 s, up to 5 times; a list fetch re-requests missing indices one by one. Missions: the
  GCS side of the upload/download transactions (below).

Missions follow ArduPilot: **item 0 is home**. :meth:`Vehicle.upload_mission` takes the items to
fly and inserts the home item itself (from the vehicle's ``HOME_POSITION``), so ``items[0]``
becomes sequence number 1; :meth:`Vehicle.download_mission` strips item 0 again. Sequence numbers
given to or reported by the vehicle (:meth:`Vehicle.set_current_item`,
:attr:`Telemetry.mission_current`, ``MISSION_ITEM_REACHED``) are the vehicle's, i.e. user item
``k`` (0-based) is sequence number ``k + 1``.

Errors (all :class:`~smcpilot.errors.SmcpilotError`): :class:`VehicleTimeout` (what was awaited,
the last value, the simulated time), :class:`CommandDenied` (the MAV_RESULT name and the FC's
STATUSTEXT reason), :class:`ParamRejected`, :class:`MissionError`, :class:`UnknownModeError`.

Modules (none imports :mod:`ground.vehicle.vehicle` at import time):

- :mod:`~ground.vehicle.vehicle`: :class:`Vehicle`, the link with its parts;
- :mod:`~ground.vehicle.link`: :class:`~ground.vehicle.link.Link`, the connection, receiver and
  heartbeat threads, subscriptions, telemetry properties and the waits;
- :mod:`~ground.vehicle.telemetry`: :class:`Telemetry`, :class:`StatusText`,
  :class:`HomePosition` and the parser of incoming messages;
- :mod:`~ground.vehicle.subscription`: :class:`Subscription`;
- :mod:`~ground.vehicle.commands`, :mod:`~ground.vehicle.params`, :mod:`~ground.vehicle.mission`:
  the parts; :mod:`~ground.vehicle.exchange`: what their request/reply exchanges share;
- :mod:`~ground.vehicle.items`: :class:`MissionItem`;
- :mod:`~ground.vehicle.errors`, :mod:`~ground.vehicle.modes` (mode names <-> numbers),
  :mod:`~ground.vehicle.names` (MAVLink enum names).
"""

from __future__ import annotations

from ground.vehicle.commands import Commands
from ground.vehicle.errors import (
    CommandDenied,
    CommandTimeout,
    ConnectTimeout,
    MissionError,
    ParamError,
    ParamExchangeError,
    ParamRejected,
    SetpointRefused,
    UnknownModeError,
    VehicleError,
    VehicleTimeout,
)
from ground.vehicle.items import MissionItem
from ground.vehicle.link import GCS_COMPONENT_ID, GCS_SYSTEM_ID, Link
from ground.vehicle.mission import Mission
from ground.vehicle.modes import COPTER_MODES, mode_name, mode_number
from ground.vehicle.names import command_name, mission_result_name, result_name
from ground.vehicle.params import Params
from ground.vehicle.subscription import Subscription
from ground.vehicle.swarm import Swarm, SwarmError
from ground.vehicle.telemetry import HomePosition, StatusText, Telemetry, json_safe
from ground.vehicle.vehicle import Vehicle

__all__ = [
    "COPTER_MODES",
    "GCS_COMPONENT_ID",
    "GCS_SYSTEM_ID",
    "CommandDenied",
    "CommandTimeout",
    "Commands",
    "ConnectTimeout",
    "HomePosition",
    "Link",
    "Mission",
    "MissionError",
    "MissionItem",
    "ParamError",
    "ParamExchangeError",
    "ParamRejected",
    "Params",
    "SetpointRefused",
    "StatusText",
    "Subscription",
    "Swarm",
    "SwarmError",
    "Telemetry",
    "UnknownModeError",
    "Vehicle",
    "VehicleError",
    "VehicleTimeout",
    "command_name",
    "json_safe",
    "mission_result_name",
    "mode_name",
    "mode_number",
    "result_name",
]
