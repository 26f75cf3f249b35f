"""``smcpilot gcs``: a command-line ground station for the flight controller.

::

    smcpilot gcs [--connect URL] status [--json]
    smcpilot gcs arm [--force] | disarm [--force]
    smcpilot gcs takeoff ALT [--wait] | goto N E D [--yaw DEG] [--wait] | land [--wait] | rtl
    smcpilot gcs mode NAME
    smcpilot gcs param get NAME [--json] | param set NAME VALUE | param list [--json]
    smcpilot gcs mission upload FILE | mission download [FILE] [--json] | mission start | mission clear
    smcpilot gcs watch [--once] [--rate-hz HZ]

``--connect`` takes :mod:`smcpilot.link` URLs: ``udpin:HOST:PORT`` listens where the FC sends its
telemetry (default ``udpin:127.0.0.1:14550``, where ``smcpilot sitl`` sends it; or set
``SMCPILOT_CONNECT``), ``udpout:HOST:PORT`` writes to the FC's own ground port. Watching and
commanding at once: when the default port is taken (``gcs watch`` holds it), the CLI talks to the
FC's own ground port ``udpout:127.0.0.1:14551`` instead (the FC serves it with its default link).

Exit codes: 0 done; 1 the vehicle refused or did not answer in time (denied, timeout); 2 usage or
configuration error (bad option, unreadable mission file). Errors are one line on stderr.

Mission files are ``smcpilot mission``'s TOML format (:mod:`ground.missions`: ``[[item]]`` tables
of type takeoff / waypoint / loiter_time / land / rtl / speed, positions as ``north_m``/``east_m``
from home or ``lat_deg``/``lon_deg``); ``mission upload`` flies only the items (``[sitl]`` and
``[[expect]]`` are for ``smcpilot mission run``). North/east offsets become latitude/longitude
through the vehicle's HOME_POSITION in :meth:`ground.missions.Mission.to_items` (with
:func:`smcpilot.geo.ned_to_global`); ``mission download`` writes the same format back.
"""

from __future__ import annotations

import argparse
import errno
import json
import math
import os
import sys
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, TextIO

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from ground.missions.schema import ItemSpec, MissionFileError, items_to_toml, load_mission
from ground.vehicle import (
    COPTER_MODES,
    HomePosition,
    MissionItem,
    Telemetry,
    UnknownModeError,
    Vehicle,
    VehicleError,
    json_safe,
    mode_number,
)
from ground.vehicle.param_meta import param_meta
from ground.vehicle.telemetry import mavlink_text
from smcpilot.errors import ConfigError, LinkError
from smcpilot.limits import HARD_LIMITS, takeoff_refusal, target_refusal
from smcpilot.protocol import FC_GROUND_PORT

DEFAULT_CONNECT = "udpin:127.0.0.1:14550"
CONNECT_ENV = "SMCPILOT_CONNECT"

EXIT_OK = 0
EXIT_VEHICLE = 1
EXIT_USAGE = 2


# -------------------------------------------------------------------------------------- rendering
#: what the live view shows for a value that does not exist (yet): never "nan".
MISSING = "—"


def _missing(v: float | None) -> bool:
    return v is None or not math.isfinite(v)


def _num(v: float | None, fmt: str = "{:7.2f}", missing: str = "-") -> str:
    return missing if _missing(v) else fmt.format(v)


def _triple(v: Sequence[float] | None, fmt: str = "{:7.2f}", missing: str = "-") -> str:
    return missing if v is None else " ".join(_num(x, fmt, missing) for x in v)


_CHANNELS = ("PHI", "THETA", "PSI", "Z")


def _per_channel(values: Mapping[str, float], fmt: str, armed: bool | None, sep: str, missing: str, *, why: bool = True) -> str:
    """The four channels' values; when none exists (the law's χ̂ and σ exist only in flight: the
    FC sends NaN while disarmed), one word for all of them."""
    if all(_missing(values.get(c)) for c in _CHANNELS):
        return missing + ("" if armed or not why else " (disarmed)")
    if sep == ",":
        return ",".join(_num(values.get(c), fmt, missing) for c in _CHANNELS)
    return sep.join(f"{c.lower()} {_num(values.get(c), fmt, missing)}" for c in _CHANNELS)


def render_frame(t: Telemetry, *, url: str = "") -> list[str]:
    """The ``watch`` view of a telemetry snapshot, as lines without escapes (NED metres,
    degrees); a value that does not exist yet is "—", never "nan"."""
    m = MISSING
    att = None if t.attitude_rad is None else tuple(math.degrees(a) for a in t.attitude_rad)
    last = t.last_statustext
    sim = m if _missing(t.sim_time_s) else f"{t.sim_time_s:9.2f} s"
    chi = _per_channel(t.chi, "{:.3f}", t.armed, "  ", m)
    sig = _per_channel(t.sigma, "{:+.3f}", t.armed, "  ", m)
    return [
        f"smcpilot vehicle {t.system_id if t.system_id is not None else '?'}  {url}  sim time {sim}",
        f"  state    {'ARMED' if t.armed else 'disarmed':8s}  mode {t.mode_name or m:9s}  landed {t.landed_state_name or m:9s}"
        f"  prearm {'ok' if t.prearm_ok else m if t.prearm_ok is None else 'FAIL'}",
        f"  position N E D  {_triple(t.position_ned_m, missing=m)} m   altitude {_num(t.altitude_m, missing=m)} m",
        f"  velocity N E D  {_triple(t.velocity_ned_mps, missing=m)} m/s",
        f"  attitude r p y  {_triple(att, missing=m)} deg",
        f"  set-point NED   {_triple(t.setpoint_ned_m, missing=m)} m   mission item {t.mission_current if t.mission_current is not None else m}",
        f"  chi_hat  {chi}",
        f"  sigma    {sig}",
        f"  last msg {last.text if last else m}",
    ]


def render_line(t: Telemetry) -> str:
    """One-line form of the ``watch`` view (for logs and pipes; "-" for what does not exist yet)."""
    last = t.last_statustext
    chi = _per_channel(t.chi, "{:.3f}", t.armed, ",", "-", why=False)
    sig = _per_channel(t.sigma, "{:+.3f}", t.armed, ",", "-", why=False)
    return (
        f"t={_num(t.sim_time_s, '{:.2f}')} {'ARMED' if t.armed else 'disarmed'} {t.mode_name or '-'}"
        f" ned={_triple(t.position_ned_m, '{:.2f}').replace(' ', ',')} alt={_num(t.altitude_m, '{:.2f}')}"
        f" sp={_triple(t.setpoint_ned_m, '{:.2f}').replace(' ', ',')} chi={chi} sigma={sig}"
        f" msg={json.dumps(last.text) if last else '-'}"
    )


def render_comm(c: Mapping[str, int]) -> str:
    """The FC's rejected-packet counters (SYS_STATUS) as one ``status`` line."""
    if not c:
        return "  rejected -  (no SYS_STATUS yet)"
    return (
        f"  rejected {c['errors_comm']} packets: {c['errors_count1']} bad frames, {c['errors_count2']} signing,"
        f" {c['errors_count3']} refused, {c['errors_count4']} on the sim link; drop rate {c['drop_rate_comm'] / 100:.2f} %"
    )


def render_status(t: Telemetry) -> str:
    """Human-readable ``status``."""
    lines = render_frame(t)[1:]
    if t.home is not None:
        h = t.home
        lines.append(f"  home     {h.lat_deg:.7f} {h.lon_deg:.7f} {h.alt_amsl_m:.2f} m AMSL")
    lines.append(render_comm(t.comm_errors))
    return "\n".join(line.strip() if i == 0 else line for i, line in enumerate(lines))


# -------------------------------------------------------------------------------------- arguments
def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options and sub-commands of ``smcpilot gcs``."""
    p.add_argument(
        "--connect",
        metavar="URL",
        default=os.environ.get(CONNECT_ENV, DEFAULT_CONNECT),
        help=f"where the vehicle is: udpin:HOST:PORT listens where the FC sends telemetry, udpout:HOST:PORT writes"
        f" to the FC's ground port (default ${CONNECT_ENV} or {DEFAULT_CONNECT}; when that port is taken, e.g. by"
        f" `smcpilot gcs watch`, the FC's own ground port udpout:127.0.0.1:{FC_GROUND_PORT})",
    )
    p.add_argument("--timeout", type=float, default=15.0, metavar="S", help="wall seconds to wait for the vehicle's heartbeat (default 15)")
    p.add_argument("--sysid", type=int, metavar="N", help="talk to this MAVLink system id only (default: the first vehicle heard)")
    p.add_argument("--signing-key", type=Path, metavar="FILE",
                   help="sign what we send and check what we get (MAVLink 2 signing): FILE holds 64 hex digits or a"
                   " passphrase, as the FC's --signing-key (docs/security.md)")  # fmt: skip
    sub = p.add_subparsers(dest="gcs_command", metavar="ACTION")
    sub.required = True

    s = sub.add_parser("status", help="print the vehicle's state once (every vehicle's, behind a swarm's router)",
                       description="Print mode, arming, position, attitude, χ̂, σ and home once. Where several vehicles"
                       " answer (a swarm's router), one line for each, then the first in full; --sysid N picks one."
                       " --json: the first vehicle's object, with \"vehicles\": every vehicle's object when there are several.")  # fmt: skip
    s.add_argument("--json", action="store_true", help="print JSON (one object)")
    s.set_defaults(gcs_handler=_status)

    s = sub.add_parser("arm", help="arm the motors (pre-arm checks unless --force)", description="COMPONENT_ARM_DISARM arm; waits until the heartbeat shows armed.")
    s.add_argument("--force", action="store_true", help="skip the pre-arm checks (ArduPilot's force code 21196)")
    s.set_defaults(gcs_handler=_arm)

    s = sub.add_parser("disarm", help="disarm the motors (--force in the air)", description="COMPONENT_ARM_DISARM disarm; in the air it needs --force.")
    s.add_argument("--force", action="store_true", help="disarm even in the air (the vehicle falls)")
    s.set_defaults(gcs_handler=_disarm)

    s = sub.add_parser("takeoff", help="climb to ALT metres above home (armed, GUIDED)", description="MAV_CMD_NAV_TAKEOFF: climb over the current position.")
    s.add_argument("alt_m", type=float, metavar="ALT", help="altitude above home, m")
    s.add_argument("--wait", action="store_true", help="wait until the altitude is reached")
    s.add_argument("--tol", type=float, default=0.3, metavar="M", help="altitude tolerance for --wait, m (default 0.3)")
    s.add_argument("--timeout-sim", type=float, default=60.0, metavar="S", help="--wait limit, simulated seconds (default 60)")
    s.set_defaults(gcs_handler=_takeoff)

    s = sub.add_parser("goto", help="fly to a local NED point (m from home; D negative is up)", description="SET_POSITION_TARGET_LOCAL_NED in GUIDED (switches to GUIDED first), then waits for the"
                       " vehicle's verdict: the target echoed in POSITION_TARGET_LOCAL_NED, or its refusal (exit 1 with the"
                       " reason). Targets must be finite, not below ground and inside the vehicle's geofence (FENCE_*).")
    s.add_argument("north_m", type=float, metavar="N", help="north of home, m")
    s.add_argument("east_m", type=float, metavar="E", help="east of home, m")
    s.add_argument("down_m", type=float, metavar="D", help="down from home, m (-3 = 3 m up)")
    s.add_argument("--yaw", type=float, metavar="DEG", help="heading, degrees (0 north, 90 east); default: keep")
    s.add_argument("--wait", action="store_true", help="wait until the point is reached")
    s.add_argument("--tol", type=float, default=0.5, metavar="M", help="distance tolerance for --wait, m (default 0.5)")
    s.add_argument("--timeout-sim", type=float, default=60.0, metavar="S", help="--wait limit, simulated seconds (default 60)")
    s.set_defaults(gcs_handler=_goto)

    s = sub.add_parser("land", help="land where the vehicle is (disarms on touchdown)", description="MAV_CMD_NAV_LAND: switches to LAND.")
    s.add_argument("--wait", action="store_true", help="wait until landed and disarmed")
    s.add_argument("--timeout-sim", type=float, default=120.0, metavar="S", help="--wait limit, simulated seconds (default 120)")
    s.set_defaults(gcs_handler=_land)

    s = sub.add_parser("rtl", help="return to launch and land", description="MAV_CMD_NAV_RETURN_TO_LAUNCH: switches to RTL.")
    s.set_defaults(gcs_handler=_rtl)

    s = sub.add_parser("mode", help="change flight mode", description=f"MAV_CMD_DO_SET_MODE. ArduCopter names: {', '.join(COPTER_MODES)} (this FC flies ALT_HOLD, AUTO, GUIDED, LOITER, RTL, LAND).")
    s.add_argument("mode_name", metavar="NAME", help="mode name, e.g. GUIDED, LOITER, AUTO, LAND")
    s.set_defaults(gcs_handler=_mode)

    param = sub.add_parser("param", help="read and write parameters", description="The parameter protocol: get, set, list.")
    psub = param.add_subparsers(dest="param_command", metavar="ACTION")
    psub.required = True
    s = psub.add_parser("get", help="print one parameter", description="PARAM_REQUEST_READ by name.")
    s.add_argument("name", metavar="NAME", help="parameter name, e.g. SMC_Z_KP")
    s.add_argument("--json", action="store_true", help='print {"name": ..., "value": ...}')
    s.set_defaults(gcs_handler=_param_get)
    s = psub.add_parser("set", help="set one parameter", description="PARAM_SET; prints the value now in force. Exit 1 if the vehicle refused it.")
    s.add_argument("name", metavar="NAME", help="parameter name")
    s.add_argument("value", type=float, metavar="VALUE", help="new value")
    s.set_defaults(gcs_handler=_param_set)
    s = psub.add_parser("list", help="print every parameter with unit, range and description",
                        description="PARAM_REQUEST_LIST: every parameter with its value, unit, range and description"
                        " (from the shipped apm.pdef.xml metadata; docs/parameters.md has the same table).")  # fmt: skip
    s.add_argument("--json", action="store_true", help="print a JSON object name -> value")
    s.add_argument("--parm", action="store_true", help="print NAME VALUE lines only (.parm format, loadable with --param-file)")
    s.set_defaults(gcs_handler=_param_list)

    mission = sub.add_parser("mission", help="upload, download, start or clear the mission", description="The mission protocol (item 0 is home and is handled by the client).")
    msub = mission.add_subparsers(dest="mission_command", metavar="ACTION")
    msub.required = True
    s = msub.add_parser("upload", help="upload a mission TOML file", description="Upload the [[item]] list of a mission file (the format of `smcpilot mission`, see"
                        " ground/missions/__init__.py; its [sitl] and [[expect]] tables are ignored here). north_m/east_m"
                        " are converted to latitude/longitude through the vehicle's home.")
    s.add_argument("file", type=Path, metavar="FILE", help="mission TOML file")
    s.set_defaults(gcs_handler=_mission_upload)
    s = msub.add_parser("download", help="download the mission (TOML to FILE or stdout)", description="Download the mission; home (item 0) is left out.")
    s.add_argument("file", type=Path, nargs="?", metavar="FILE", help="write the mission here (TOML); default: print it")
    s.add_argument("--json", action="store_true", help="print the items as JSON instead of TOML (a list of [[item]] tables)")
    s.add_argument("--latlon", action="store_true", help="write positions as lat_deg/lon_deg (default: north_m/east_m from the vehicle's home)")
    s.set_defaults(gcs_handler=_mission_download)
    s = msub.add_parser("start", help="fly the mission (AUTO)", description="MAV_CMD_MISSION_START: switches to AUTO (armed, with a mission).")
    s.set_defaults(gcs_handler=_mission_start)
    s = msub.add_parser("clear", help="delete the mission", description="MISSION_CLEAR_ALL.")
    s.set_defaults(gcs_handler=_mission_clear)

    s = sub.add_parser("watch", help="live view of the vehicle (Ctrl-C ends)", description="Redraws state, mode, position, set-point, χ̂, σ and the last STATUSTEXT in place a few times"
                       " a second; one line per update when stdout is not a terminal.")
    s.add_argument("--once", action="store_true", help="print one frame and exit")
    s.add_argument("--rate-hz", type=float, default=4.0, metavar="HZ", help="updates per wall second (default 4)")
    s.set_defaults(gcs_handler=_watch)
    _accept_link_options_after_action(p)


def _accept_link_options_after_action(p: argparse.ArgumentParser) -> None:
    """Let ``--connect``, ``--timeout`` and ``--sysid`` also follow the action (``gcs status
    --timeout 2``): every action's parser repeats them with no default of its own, so a value
    given before the action stands unless one after it overrides it."""
    link_options = [a for a in p._actions if "--connect" in a.option_strings or "--timeout" in a.option_strings
                    or "--sysid" in a.option_strings]  # fmt: skip
    pending = [a for a in p._actions if isinstance(a, argparse._SubParsersAction)]
    while pending:
        for leaf in pending.pop().choices.values():
            nested = [a for a in leaf._actions if isinstance(a, argparse._SubParsersAction)]
            if nested:
                pending.extend(nested)
                continue
            for opt in link_options:
                leaf.add_argument(*opt.option_strings, dest=opt.dest, type=opt.type, metavar=opt.metavar,
                                  default=argparse.SUPPRESS, help=opt.help)  # fmt: skip


# --------------------------------------------------------------------------------------- handlers
def main(args: argparse.Namespace) -> int:
    """Entry point of ``smcpilot gcs``: connect, run the action, map errors to exit codes."""
    if args.timeout is None or not (math.isfinite(args.timeout) and args.timeout > 0):
        raise ConfigError(f"--timeout must be > 0 seconds, got {args.timeout}")
    handler: Callable[[Vehicle, argparse.Namespace, TextIO], int] = args.gcs_handler
    _precheck(args)
    waiting = _WaitingNotice(f"smcpilot gcs: waiting up to {args.timeout:g} s for a vehicle on {args.connect} ...", sys.stderr)
    try:
        with _open_vehicle(args) as vehicle:
            waiting.done()
            return handler(vehicle, args, sys.stdout)
    except UnknownModeError:
        raise  # a usage error: exit 2 through the CLI's handler
    except VehicleError as exc:
        waiting.done()
        print(f"smcpilot gcs: error: {exc}", file=sys.stderr)
        return EXIT_VEHICLE
    finally:
        waiting.done()


class _WaitingNotice:
    """On a terminal, say what we wait for unless the vehicle answers within ``after_s``, and erase
    it again once it does or we give up, so what remains is the command's own output or its one
    error line. Elsewhere (a script, a log) nothing is written."""

    def __init__(self, text: str, out: TextIO, after_s: float = 0.3) -> None:
        self._text, self._out = text, out
        self._lock = threading.Lock()
        self._shown = self._finished = False
        self._timer: threading.Timer | None = None
        if out.isatty():
            self._timer = threading.Timer(after_s, self._show)
            self._timer.daemon = True
            self._timer.start()

    def _show(self) -> None:
        with self._lock:
            if not self._finished:
                self._out.write(self._text)
                self._out.flush()
                self._shown = True

    def done(self) -> None:
        with self._lock:
            if self._finished:
                return
            self._finished = True
            if self._timer is not None:
                self._timer.cancel()
            if self._shown:
                self._out.write("\r\x1b[K")
                self._out.flush()


def _open_vehicle(args: argparse.Namespace) -> Vehicle:
    """The vehicle link, opened. Watching and commanding at once: when the default listening
    port is taken (``smcpilot gcs watch`` or another ground station holds it), talk to the FC's
    own ground port instead (it answers every station that writes to it); with an explicit
    ``--connect`` that is taken, a one-line error says what to do."""
    url = args.connect
    key = getattr(args, "signing_key", None)
    try:
        return Vehicle(url, system_id=args.sysid, connect_timeout_s=args.timeout, signing_key=key).open()
    except LinkError as exc:
        if not isinstance(exc.__cause__, OSError) or exc.__cause__.errno != errno.EADDRINUSE:
            raise
        fc_port = f"udpout:127.0.0.1:{FC_GROUND_PORT}"
        if url != DEFAULT_CONNECT or CONNECT_ENV in os.environ:
            raise ConfigError(
                f"{url}: port taken (another ground station listens there, e.g. smcpilot gcs watch); use the FC's own"
                f" ground port: --connect {fc_port} (or the gcs= address the FC prints)"
            ) from None
    print(f"smcpilot gcs: {url} is taken (smcpilot gcs watch?): talking to the FC's own ground port ({fc_port})", file=sys.stderr)
    return Vehicle(fc_port, system_id=args.sysid, connect_timeout_s=args.timeout, signing_key=key).open()


def _precheck(args: argparse.Namespace) -> None:
    """Usage errors we can find before connecting (exit 2 at once, no vehicle needed)."""
    if args.gcs_handler is _mode:
        mode_number(args.mode_name)
    elif args.gcs_handler is _mission_upload:
        args.mission = load_mission(args.file)
    elif args.gcs_handler is _takeoff and not (math.isfinite(args.alt_m) and args.alt_m > 0):
        raise ConfigError(f"takeoff altitude must be > 0 m, got {args.alt_m}")
    elif args.gcs_handler is _takeoff and (why := takeoff_refusal(args.alt_m, HARD_LIMITS)) is not None:
        raise ConfigError(f"takeoff: {why}")  # the vehicle would refuse it whatever its fence
    elif args.gcs_handler is _goto:
        for name in ("north_m", "east_m", "down_m", "yaw"):
            v = getattr(args, name)
            if v is not None and not math.isfinite(v):
                raise ConfigError(f"goto {name}: must be a finite number, got {v}")
        why = target_refusal(args.north_m, args.east_m, -args.down_m, HARD_LIMITS)
        if why is not None:  # the same rule as the vehicle's (smcpilot.limits); it adds its own fence
            raise ConfigError(f"goto: {why}")
    elif args.gcs_handler is _param_set and not math.isfinite(args.value):
        raise ConfigError(f"parameter value must be finite, got {args.value}")
    elif args.gcs_handler is _watch and not (math.isfinite(args.rate_hz) and 0 < args.rate_hz <= 50):
        raise ConfigError(f"--rate-hz must lie in (0, 50], got {args.rate_hz}")
    for name in ("tol", "timeout_sim"):
        v = getattr(args, name, None)
        if v is not None and not (math.isfinite(v) and v > 0):
            raise ConfigError(f"--{name.replace('_', '-')} must be > 0, got {v}")


def _settle(vehicle: Vehicle, wall_s: float = 2.0) -> Telemetry:
    """Give the telemetry a moment to fill in (position and attitude), at most ``wall_s``."""
    deadline = time.monotonic() + wall_s
    while time.monotonic() < deadline:
        t = vehicle.telemetry
        if t.position_ned_m is not None and t.attitude_rad is not None:
            return t
        time.sleep(0.02)
    return vehicle.telemetry


#: ``gcs status`` without ``--sysid`` listens at least this long (wall s) after connecting, so that
#: every vehicle behind one address (a swarm's router) has sent its 1 Hz HEARTBEAT before the list.
HEAR_ALL_S = 1.2


def _status(vehicle: Vehicle, args: argparse.Namespace, out: TextIO) -> int:
    t0 = time.monotonic()
    _settle(vehicle)
    if args.sysid is None:  # (the telemetry of the one vehicle comes at once; the others' heartbeats at 1 Hz)
        while time.monotonic() - t0 < HEAR_ALL_S:
            time.sleep(0.02)
    deadline = time.monotonic() + 1.5  # SYS_STATUS (the counters) comes at 1 Hz
    while not vehicle.telemetry.comm_errors and time.monotonic() < deadline:
        time.sleep(0.02)
    try:
        vehicle.get_home(timeout_s=1.0)
    except VehicleError:
        pass
    t = vehicle.telemetry
    why = _prearm_failure(vehicle) if t.prearm_ok is False and not t.armed else None
    heard = vehicle.vehicles_heard() if args.sysid is None else {}
    if len(heard) > 1:  # a swarm behind one address: every vehicle, the one we talk to in full
        if args.json:
            d = t.as_dict()
            d["prearm_failure"] = why
            others = [tel.as_dict() for sid, tel in heard.items() if sid != t.system_id]
            out.write(json.dumps({**d, "vehicles": [d, *others]}, allow_nan=False) + "\n")
            return EXIT_OK
        out.write(f"{len(heard)} vehicles: system ids {', '.join(map(str, heard))} (--sysid N talks to one)\n")
        for sid, tel in heard.items():
            out.write(f"  vehicle {sid}: {render_line(tel)}\n")
        out.write(render_status(t) + "\n")
        if why is not None:
            out.write(f"  prearm   {why}\n")
        return EXIT_OK
    if args.json:
        d = t.as_dict()
        d["prearm_failure"] = why
        out.write(json.dumps(d, allow_nan=False) + "\n")
    else:
        out.write(render_status(t) + "\n")
        if why is not None:
            out.write(f"  prearm   {why}\n")
    return EXIT_OK


def _prearm_failure(vehicle: Vehicle, wall_s: float = 2.0) -> str | None:
    """Why the vehicle would refuse to arm: MAV_CMD_RUN_PREARM_CHECKS makes it say so in a
    ``STATUSTEXT`` ("PreArm: ..."), as ArduPilot does; None if it said nothing in ``wall_s``."""
    with vehicle.subscribe("STATUSTEXT") as sub:
        try:
            vehicle.commands.command_long(mavlink.MAV_CMD_RUN_PREARM_CHECKS)
        except VehicleError:
            return None
        deadline = time.monotonic() + wall_s
        while (remaining := deadline - time.monotonic()) > 0:
            msg = sub.get(remaining)
            if msg is None:
                break
            text = mavlink_text(msg.text)
            if text.startswith("PreArm"):
                return None if text == "PreArm: checks pass" else text
    return None


def _arm(vehicle: Vehicle, args: argparse.Namespace, out: TextIO) -> int:
    vehicle.arm(force=args.force)
    out.write("armed\n")
    return EXIT_OK


def _disarm(vehicle: Vehicle, args: argparse.Namespace, out: TextIO) -> int:
    vehicle.disarm(force=args.force)
    out.write("disarmed\n")
    return EXIT_OK


def _takeoff(vehicle: Vehicle, args: argparse.Namespace, out: TextIO) -> int:
    vehicle.takeoff(args.alt_m)
    out.write(f"taking off to {args.alt_m:g} m\n")
    if args.wait:
        t = vehicle.wait_altitude(args.alt_m, args.tol, args.timeout_sim)
        out.write(f"at {t.altitude_m:.2f} m (sim time {t.sim_time_s:.2f} s)\n")
    return EXIT_OK


def _goto(vehicle: Vehicle, args: argparse.Namespace, out: TextIO) -> int:
    vehicle.goto_ned(args.north_m, args.east_m, args.down_m, args.yaw)  # waits for the vehicle's verdict
    out.write(f"set-point taken: going to NED ({args.north_m:g}, {args.east_m:g}, {args.down_m:g}) m\n")
    if args.wait:
        t = vehicle.wait_position_ned(args.north_m, args.east_m, args.down_m, args.tol, args.timeout_sim)
        out.write(f"arrived (sim time {t.sim_time_s:.2f} s)\n")
    return EXIT_OK


def _land(vehicle: Vehicle, args: argparse.Namespace, out: TextIO) -> int:
    vehicle.land()
    out.write("landing\n")
    if args.wait:
        t = vehicle.wait_disarmed(args.timeout_sim)
        out.write(f"landed and disarmed (sim time {t.sim_time_s:.2f} s)\n")
    return EXIT_OK


def _rtl(vehicle: Vehicle, args: argparse.Namespace, out: TextIO) -> int:
    vehicle.rtl()
    out.write("returning to launch\n")
    return EXIT_OK


def _mode(vehicle: Vehicle, args: argparse.Namespace, out: TextIO) -> int:
    vehicle.set_mode(args.mode_name)
    out.write(f"mode {vehicle.mode}\n")
    return EXIT_OK


def _param_get(vehicle: Vehicle, args: argparse.Namespace, out: TextIO) -> int:
    value = vehicle.get_param(args.name)
    name = args.name.strip().upper()
    out.write((json.dumps({"name": name, "value": value}) if args.json else f"{name} {_param_text(value)}") + "\n")
    return EXIT_OK


def _param_set(vehicle: Vehicle, args: argparse.Namespace, out: TextIO) -> int:
    value = vehicle.set_param(args.name, args.value)
    out.write(f"{args.name.strip().upper()} {_param_text(value)}\n")
    return EXIT_OK


def _param_list(vehicle: Vehicle, args: argparse.Namespace, out: TextIO) -> int:
    params = vehicle.list_params()
    if args.json:
        out.write(json.dumps(params) + "\n")
    elif args.parm:
        for name, value in params.items():
            out.write(f"{name} {_param_text(value)}\n")
    else:
        meta = param_meta()
        width = max((len(n) for n in params), default=4)
        out.write(f"{'NAME':{width}s}  {'VALUE':>12s}  {'UNIT':8s}  {'RANGE':>16s}  DESCRIPTION\n")
        for name, value in params.items():
            m = meta.get(name)
            if m is None:
                out.write(f"{name:{width}s}  {_param_text(value):>12s}\n")
                continue
            label = f" ({m.values[int(value)]})" if m.values and isinstance(value, int) and value in m.values else ""
            desc = m.description.split(". Default ", 1)[0] + (" [restart]" if m.restart else "")
            out.write(f"{name:{width}s}  {_param_text(value) + label:>12s}  {m.unit or '-':8s}  {m.range_text():>16s}  {desc}\n")
    return EXIT_OK


def _param_text(value: float) -> str:
    return str(value) if isinstance(value, int) else f"{value:.9g}"


def _mission_upload(vehicle: Vehicle, args: argparse.Namespace, out: TextIO) -> int:
    mission = getattr(args, "mission", None) or load_mission(args.file)
    home = vehicle.get_home() if mission.uses_local_positions else None
    items = mission.to_items(home)
    vehicle.upload_mission(items)
    out.write(f"uploaded {len(items)} items (+ home) from {args.file}\n")
    return EXIT_OK


def _mission_download(vehicle: Vehicle, args: argparse.Namespace, out: TextIO) -> int:
    items = vehicle.download_mission()
    home = None if args.latlon else vehicle.get_home()
    if args.json:
        text = json.dumps(json_safe([_entry(item, k, home) for k, item in enumerate(items, start=1)]), allow_nan=False) + "\n"
    else:
        where = "lat_deg/lon_deg" if home is None else "north_m/east_m from the vehicle's home"
        text = items_to_toml(items, home, header=f"mission downloaded by smcpilot gcs ({len(items)} items; home, item 0, not listed; positions as {where})")
    if args.file is not None:
        try:
            args.file.parent.mkdir(parents=True, exist_ok=True)
            args.file.write_text(text, encoding="utf-8")
        except OSError as exc:
            raise ConfigError(f"cannot write {args.file}: {exc.strerror or exc}") from None
        out.write(f"downloaded {len(items)} items to {args.file}\n")
    else:
        out.write(text)
    return EXIT_OK


def _entry(item: MissionItem, number: int, home: HomePosition | None) -> dict[str, Any]:
    """One downloaded item in the mission-file format, for ``--json`` (an item the format has no
    type for comes as ``{"type": null, "command": ..., ...}``)."""
    try:
        return ItemSpec.from_mission_item(item, number, home).to_toml_entry()
    except MissionFileError:
        return {
            "type": None,
            "command": item.command,
            "command_name": item.command_name,
            "frame": item.frame,
            "params": [item.param1, item.param2, item.param3, item.param4],
            "lat_deg": item.lat_deg,
            "lon_deg": item.lon_deg,
            "alt_m": item.alt_m,
        }


def _mission_start(vehicle: Vehicle, args: argparse.Namespace, out: TextIO) -> int:
    vehicle.start_mission()
    out.write("mission started (AUTO)\n")
    return EXIT_OK


def _mission_clear(vehicle: Vehicle, args: argparse.Namespace, out: TextIO) -> int:
    vehicle.clear_mission()
    out.write("mission cleared\n")
    return EXIT_OK


def _watch(vehicle: Vehicle, args: argparse.Namespace, out: TextIO) -> int:
    if args.once:
        _settle(vehicle)
        out.write("\n".join(render_frame(vehicle.telemetry, url=vehicle.url)) + "\n")
        return EXIT_OK
    tty = out.isatty()
    period = 1.0 / args.rate_hz
    if tty:
        out.write("\x1b[?25l\x1b[2J")  # hide the cursor, clear the screen
    try:
        while True:
            t = vehicle.telemetry
            if tty:
                out.write("\x1b[H" + "".join(line + "\x1b[K\n" for line in render_frame(t, url=vehicle.url)) + "\x1b[J")
            else:
                out.write(render_line(t) + "\n")
            out.flush()
            if getattr(out, "broken", False):  # the reader went away (`... | head`): nothing to watch for
                return EXIT_OK
            time.sleep(period)
    except KeyboardInterrupt:
        return EXIT_OK
    finally:
        if tty:
            out.write("\x1b[?25h")
            out.flush()
