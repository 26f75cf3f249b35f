"""Scripted missions: a TOML file of mission items, SITL settings and expectations, and the
runner behind ``smcpilot mission run FILE``.

A mission file says what to fly (``[[item]]``), where (``[sitl]``, used only when the runner
launches SITL itself) and what must hold afterwards (``[[expect]]``)::

    name = "hop"                       # optional: name and description (strings)
    description = "take off, fly 5 m north, land"

    [sitl]                             # optional; every key optional
    controller = "adaptive_pid_smc"    # adaptive_pid_smc | pid_smc | cascade_pid
    vehicle = "../vehicles/heavy-quad.toml"   # vehicle TOML, relative to this file
    seed = 0                           # seed of sensor noise and gusts (integer >= 0)
    plant = "rigid-body"               # rigid-body | paper
    noise = false                      # sensor noise on the simulated state
    noise_scale = 1.0                  # multiplies the noise levels (>= 0)
    wind_force_ned_n = [0.4, -0.3, 0.0]   # constant wind force, newtons, NED
    gust_std_n = 0.3                   # horizontal gust force std, newtons (>= 0)
    home = [-35.363261, 149.165230, 584.0]  # lat deg, lon deg, alt m AMSL (default: the FC's)
    max_duration_s = 600.0             # simulated seconds of flight before the runner gives up

    [[sitl.fault]]                     # optional, any number: timed faults in the simulator, as a
    kind = "motor"                     # scenario's [[fault]] tables (smcpilot/faults.py); times are
    motor = 1                          # simulated seconds from SITL's start
    efficiency = 0.7
    start_s = 20.0

    [[item]]
    type = "takeoff"
    alt_m = 3.0

    [[item]]
    type = "waypoint"
    north_m = 5.0
    east_m = 0.0
    alt_m = 3.0

    [[item]]
    type = "land"

    [[expect]]
    kind = "reach"
    item = 2
    within_m = 0.3
    by_s = 15.0

    [[expect]]
    kind = "landed"

Items (``[[item]]``, flown in file order; item N is the vehicle's mission sequence number N,
home being item 0, inserted by :meth:`ground.vehicle.Vehicle.upload_mission`)
-----------------------------------------------------------------------------------------------
Positions are either ``north_m``/``east_m`` (metres north/east of the vehicle's home, MAVLink
local NED frame; converted to latitude/longitude through the vehicle's ``HOME_POSITION`` with
:func:`smcpilot.geo.ned_to_global`) or ``lat_deg``/``lon_deg`` (WGS-84 degrees), never both.
Altitudes ``alt_m`` are metres above home (``MAV_FRAME_GLOBAL_RELATIVE_ALT``).

============  ===================================================  =============================
type          keys                                                 MAVLink item
============  ===================================================  =============================
takeoff       ``alt_m`` (0.5-500): climb over the current point    NAV_TAKEOFF
waypoint      position, ``alt_m`` (0-500); optional ``hold_s``     NAV_WAYPOINT
              (0-3600 s, default 0), ``yaw_deg`` (heading: 0 north,
              90 east; default: keep), ``radius_m`` (acceptance
              radius, 0-100 m; 0 or absent = the FC's WP_RADIUS_M)
loiter_time   ``hold_s``; optional position (default: here) and     NAV_LOITER_TIME
              ``alt_m`` (default: the current altitude; required
              with a position)
land          optional position (default: here)                    NAV_LAND
rtl           —                                                    NAV_RETURN_TO_LAUNCH
speed         ``speed_mps`` (0 < v <= 50): horizontal speed from    DO_CHANGE_SPEED
              here on
============  ===================================================  =============================

The FC moves on when the vehicle is within the acceptance radius (3-D) of a point, then holds
``hold_s``; a ``land`` without a point lands where the vehicle is when the land item begins.
TOML note: top-level keys (``name``, ``description``) go before the first table; a key written
after ``[[item]]`` belongs to that item.

Expectations (``[[expect]]``, each with ``kind``)
-------------------------------------------------
Times are **mission time**: simulated seconds since the mission started (the FC's ``Mode AUTO``
event after ``MISSION_START``; the vehicle armed on the ground a moment before). Positions are
north/east/altitude-up metres relative to home. Only armed flight counts where it says so.

``reach``: ``item`` (an item number), ``within_m`` (> 0), ``by_s`` (>= 0)
    While flying the item or later, and by ``by_s``, the vehicle came within ``within_m`` of
    the item's target: the window runs from the moment the item became the current one (the
    FC's ``MISSION_ITEM_REACHED`` for the item before it; item 1 at 0) to ``by_s``, so a point
    merely passed earlier (home on the way up) does not count. The target is, for a waypoint
    and for a loiter_time with a position, its 3-D point (3-D distance); for a land with a
    position, its north/east point (horizontal distance); for a takeoff, its altitude
    (vertical distance). Other items have no target to reach: a parse error. Measured: the
    closest approach in the window and when the vehicle first came within the limit.
``max_tilt``: ``max_deg`` (0-90)
    The tilt (angle between the body z axis and the vertical, acos(cos roll · cos pitch)) stays
    at or below ``max_deg`` throughout the armed flight. Measured: the largest tilt and when.
``chi_hat``: ``max``; optional ``min`` (<= ``max``), ``channels`` (subset of
    ``["phi", "theta", "psi", "z"]``, default all)
    Every adaptive gain χ̂ of the chosen channels stays within [``min``, ``max``] throughout the
    armed flight. Fails when the log has no χ̂ (a controller without adaptive gains).
    Measured: each channel's range.
``final_position``: ``north_m``, ``east_m``, ``within_m`` (> 0); optional ``alt_m``
    The last recorded position is within ``within_m`` of (``north_m``, ``east_m``):
    horizontal distance, or 3-D distance when ``alt_m`` is given.
``landed``: optional ``by_s``
    At the end the vehicle is disarmed and on the ground (altitude < 0.3 m); with ``by_s``, it
    also disarmed at mission time <= ``by_s``. Measured: when it disarmed and its altitude.
``max_error_after``: ``t_s`` (>= 0), ``max_m`` (> 0); optional ``until_s`` (> ``t_s``)
    A hold: during armed flight from mission time ``t_s`` (to ``until_s``, default the end),
    the horizontal distance from the vehicle to its current position set-point stays below
    ``max_m``. The set-point is the FC's target (a step to each new item's point, not the
    smoothed reference), so choose a window in which the set-point does not jump. Measured:
    the largest error and when.

A swarm mission
---------------
``[sitl] count = K`` (2..64; ``spacing_m`` the spawn grid, default 4 m) flies the mission on K
vehicles at once in one lockstep swarm (:mod:`ground.missions.swarm_runner`): every vehicle flies
the shared ``[[item]]`` list, or its own, and is judged on the shared ``[[expect]]`` entries plus
its own. The i-th ``[[vehicle]]`` table is vehicle i (system id i)::

    [[vehicle]]                        # vehicle 1: the shared items and expectations
    [[vehicle]]                        # vehicle 2
    [[vehicle.item]]                   # its own items (replace the shared list)
    type = "takeoff"
    alt_m = 3.0
    [[vehicle.expect]]                 # its own expectations (added to the shared ones)
    kind = "reach"
    item = 1
    within_m = 0.3
    by_s = 20.0

A swarm mission may also expect ``kind = "separation"`` with ``min_m`` (> 0): the closest two
vehicles' centres came over the flight (the simulator's, on the true positions) is at least
``min_m``, and no two vehicles touched. North/east positions are each vehicle's own (its home is
where it spawned). A swarm mission launches its own SITL (no ``--connect``). The report has one
section per vehicle and one for the swarm; its JSON has ``vehicles`` by system id and ``separation``.

The runner
----------
:func:`run_mission` (``smcpilot mission run FILE``): launch lockstep SITL with ``[sitl]`` (or,
with ``--connect URL``, talk to a running vehicle), upload the items through the MAVLink
mission protocol (home inserted as item 0), switch to GUIDED if needed, arm, ``MISSION_START``
from item 1, then wait in simulated time until the vehicle disarms or ``max_duration_s``
(``[sitl]``, honoured with ``--connect`` too) has passed, printing a progress line every 5
simulated seconds; stop SITL, evaluate, print the report (each expectation PASS/FAIL, measured
value vs limit, and how it was measured), write the plots and optionally JSON. Exit codes of the
command: 0 every expectation held, 1 one failed or the mission could not be flown, 2 a broken
file or bad usage.

Where expectations are evaluated
--------------------------------
When the runner launches SITL, from the FC's ``.tlog``: the simulator's state at every control
tick (500 Hz), the actuator armed flag, and the controller's per-tick record (χ̂ and the
position set-point). With ``--connect`` (a vehicle that is already running) there is no FC log:
the runner records the telemetry it receives (10 Hz ``LOCAL_POSITION_NED``, ``ATTITUDE``,
``CHI_*``; armed from the 1 Hz ``HEARTBEAT``), writes it to a ``.tlog`` for the plots, and uses
it instead; ``max_error_after`` then compares with the set-point the FC streams
(``POSITION_TARGET_LOCAL_NED``, 4 Hz), or, from a vehicle that does not stream it, with the
*planned* set-point (the current item's point, taken from ``MISSION_ITEM_REACHED`` /
``MISSION_CURRENT``; for an item without a point, where the vehicle was when the item began;
home during RTL). The report says which source each expectation used.

Errors
------
:class:`MissionFileError` (a :class:`~smcpilot.errors.ConfigError`): the file is unreadable or
invalid; the message names the file, the section (``item N``, ``expect N``, ``[sitl]``) and the
key, e.g. ``box.toml: item 3 (waypoint): unknown key 'nort_m' (did you mean 'north_m'?)``.
:class:`MissionRunError`: the flight could not be flown (a SITL child died, the log is missing).
Vehicle refusals and timeouts are :class:`ground.vehicle.VehicleError`.

API
---
:func:`load_mission` (``path -> Mission``), :func:`parse_mission` (a parsed TOML dict),
:meth:`Mission.to_items` (``home -> list[ground.vehicle.MissionItem]``), :func:`items_to_toml`
(downloaded items back to this format), :func:`run_mission` (fly and evaluate -> a
:class:`MissionReport`), and the CLI pieces :func:`add_arguments` / :func:`main` of
``smcpilot mission``.

Modules
-------
:mod:`~ground.missions.schema` (the file format: :class:`ItemSpec`, :class:`SitlSettings`,
:class:`Mission`, :func:`parse_mission`, :func:`load_mission`, :func:`items_to_toml`),
:mod:`~ground.missions.expectations` (the ``[[expect]]`` kinds and their evaluation),
:mod:`~ground.missions.record` (:class:`FlightRecord` from the FC log or from the telemetry
:class:`TelemetryRecorder` receives), :mod:`~ground.missions.report` (:class:`MissionReport`,
:func:`print_report`), :mod:`~ground.missions.runner` (:func:`run_mission`),
:mod:`~ground.missions.cli` and :mod:`~ground.missions.errors`. This package re-exports their
public names (``__all__`` as before, and ``PROGRESS_EVERY_SIM_S``, ``LANDED_MAX_ALT_M``,
``EXIT_PASSED``, ``EXIT_FAILED``, ``EXIT_USAGE``).
"""

from __future__ import annotations

from ground.missions.cli import EXIT_FAILED as EXIT_FAILED
from ground.missions.cli import EXIT_PASSED as EXIT_PASSED
from ground.missions.cli import EXIT_USAGE as EXIT_USAGE
from ground.missions.cli import add_arguments, main
from ground.missions.errors import MissionFileError, MissionRunError
from ground.missions.expectations import (
    CHANNELS,
    EXPECTATION_KINDS,
    ChiHat,
    Expectation,
    ExpectationResult,
    FinalPosition,
    Landed,
    MaxErrorAfter,
    MaxTilt,
    Reach,
    evaluate,
)
from ground.missions.expectations import (
    LANDED_MAX_ALT_M as LANDED_MAX_ALT_M,
)
from ground.missions.record import FlightRecord, TelemetryRecorder, record_from_log
from ground.missions.report import MissionReport, print_report
from ground.missions.runner import PROGRESS_EVERY_SIM_S as PROGRESS_EVERY_SIM_S
from ground.missions.runner import run_mission
from ground.missions.schema import (
    DEFAULT_MAX_DURATION_S,
    ITEM_TYPES,
    ItemSpec,
    Mission,
    SitlSettings,
    items_to_toml,
    load_mission,
    parse_mission,
)

__all__ = [
    "CHANNELS",
    "DEFAULT_MAX_DURATION_S",
    "EXPECTATION_KINDS",
    "ITEM_TYPES",
    "ChiHat",
    "Expectation",
    "ExpectationResult",
    "FinalPosition",
    "FlightRecord",
    "ItemSpec",
    "Landed",
    "MaxErrorAfter",
    "MaxTilt",
    "Mission",
    "MissionFileError",
    "MissionReport",
    "MissionRunError",
    "Reach",
    "SitlSettings",
    "TelemetryRecorder",
    "add_arguments",
    "evaluate",
    "items_to_toml",
    "load_mission",
    "main",
    "parse_mission",
    "print_report",
    "record_from_log",
    "run_mission",
]
