"""The small interface every flight mode implements, after ArduCopter's ``Mode`` (mode.h).

One object per mode, built once by the :class:`fc.commander.Commander` and kept for the whole
flight (a mode's progress, e.g. how far RTL has got, lives in its object). The commander calls:

- :meth:`FlightMode.refuse_entry` before a requested switch (``set_mode``): None, or why not;
- :meth:`FlightMode.exit` on the mode being left (only when the mode really changes; it is told
  which mode comes next, as ArduCopter's ``exit_mode(old, new)``), then
  :meth:`FlightMode.enter` on the new one (also when a mode is entered again: re-entering LAND,
  RTL or AUTO restarts it);
- :meth:`FlightMode.run` once per control tick while armed, before the flight pipeline's step
  (simulated time; called 500 times a second: it allocates nothing on the common path);
  :meth:`FlightMode.watch` says, as data, when ``run`` would next act (a compiled flight checks
  that every tick instead of calling ``run``, :mod:`lab.fast`);
- :meth:`FlightMode.on_armed` after arming and :meth:`FlightMode.on_touchdown` when the pipeline
  disarmed by itself on touchdown (the pipeline, :class:`fc.flight.FlightControl`, owns that).

Modes see the vehicle through :class:`ModeHost` (the commander): the flight pipeline, the
configuration, home, the mission, whether the vehicle is flying, an event sink, and ``here(st)``:
where the vehicle is for a set-point "here" (the filtered hold point of :mod:`fc.estimate`, so
one noisy sample does not decide it; the state's own values in a clean flight). Positions are
in the paper frame (x north, y west, z up above home; FLU yaw): every conversion from a wire frame
happens in :mod:`fc.inbound`.

A refused request is a :class:`Refusal`: a domain value (why, and the result code a ground station
gets); only the ground edge (:mod:`fc.gcs`) turns it into ``COMMAND_ACK`` + ``STATUSTEXT``.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, ClassVar, NamedTuple, Protocol

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from smcpilot.protocol import Mode

if TYPE_CHECKING:  # pragma: no cover
    from fc.config import FcConfig
    from fc.estimate import HoldPoint
    from fc.flight import FlightControl, VehicleState
    from fc.mission import MissionStore
    from smcpilot.geo import Home

#: a take-off (and RTL's climb) counts as done within this height of its target, m.
TAKEOFF_DONE_M = 0.3

#: kinds of :class:`Watch`: nothing to do per tick; something to do every tick; ``|z - a| < r``;
#: the distance from (a, b, c) below ``r``; the horizontal distance from (a, b) below ``r``;
#: ``t_s - a >= b`` (a hold time over).
WATCH_NONE = 0
WATCH_ALWAYS = 1
WATCH_Z_NEAR = 2
WATCH_DIST3 = 3
WATCH_DIST2 = 4
WATCH_TIME = 5


class Watch(NamedTuple):
    """When a mode's per-tick :meth:`FlightMode.run` would do something, as data a compiled flight
    checks every tick without calling Python (:mod:`lab.fast`): on the estimated state (paper
    frame, m) and the simulated time since the first tick (s). Until it holds, ``run`` does
    nothing; once it holds, the tick is flown through ``run``."""

    kind: int
    a: float = 0.0
    b: float = 0.0
    c: float = 0.0
    r: float = 0.0


#: the margin :func:`watch_holds` keeps from a condition's boundary.
_MARGIN = 1e-9


def watch_holds(kind: int, a: float, b: float, c: float, r: float, x: float, y: float, z: float, t_s: float) -> bool:
    """The mode's watched condition (:class:`Watch`: ``kind``, ``a``, ``b``, ``c``, ``r``) holds now at the
    estimated position ``x``, ``y``, ``z`` (paper frame, m) and ``t_s`` s after the first tick, or
    is too close to call (Python decides: ``math.dist`` and ``math.hypot`` round differently from
    a plain square root). Pure: compiled flights (:mod:`lab.fast`, :mod:`fc.lockstep_kernel`) check
    it every tick without calling the mode."""
    if kind == WATCH_NONE:
        return False
    if kind == WATCH_Z_NEAR:
        return abs(z - a) < r
    if kind == WATCH_DIST3:
        dx = x - a
        dy = y - b
        dz = z - c
        return math.sqrt(dx * dx + dy * dy + dz * dz) < r * (1.0 + _MARGIN) + _MARGIN
    if kind == WATCH_DIST2:
        dx = x - a
        dy = y - b
        return math.sqrt(dx * dx + dy * dy) < r * (1.0 + _MARGIN) + _MARGIN
    if kind == WATCH_TIME:
        return t_s - a >= b - _MARGIN
    return True


WATCH_NOTHING = Watch(WATCH_NONE)
WATCH_EVERY_TICK = Watch(WATCH_ALWAYS)


class Refusal(NamedTuple):
    """A request the vehicle will not carry out: why (the ``STATUSTEXT``; empty: say nothing) and
    the ``MAV_RESULT`` a ground station gets for it."""

    reason: str
    code: int = mavlink.MAV_RESULT_DENIED


class ModeHost(Protocol):
    """What a mode needs of the vehicle (the commander provides it)."""

    flight: FlightControl
    home: Home
    mission: MissionStore

    @property
    def config(self) -> FcConfig: ...

    def flying(self) -> bool: ...

    def here(self, st: VehicleState) -> HoldPoint:
        """Where the vehicle is at state ``st``, for a set-point "here": the flight core's
        filtered hold point (:mod:`fc.estimate`), or ``st``'s own position and yaw."""
        ...

    def say(self, text: str, severity: int = mavlink.MAV_SEVERITY_INFO) -> None: ...

    def item_reached(self, seq: int) -> None: ...


class FlightMode:
    """One flight mode. Subclasses set :attr:`number` and override what they need."""

    #: the ArduCopter custom-mode number.
    number: ClassVar[Mode]
    #: one may arm in this mode (the pre-arm check; :data:`smcpilot.protocol.ARMABLE_MODES`).
    allows_arming: ClassVar[bool] = False
    #: the pipeline holds the horizontal position (False: ALT_HOLD, level attitude, drifts).
    position_hold: ClassVar[bool] = True

    def __init__(self, host: ModeHost) -> None:
        self.host = host
        self.flight = host.flight

    @property
    def name(self) -> str:
        return self.number.name

    @property
    def is_landing(self) -> bool:
        """The mode is bringing the vehicle down to land now."""
        return False

    def refuse_entry(self) -> Refusal | None:
        """Why a switch to this mode is refused now, or None."""
        return None

    def prearm_failure(self) -> str | None:
        """Why arming in this mode would be refused (the mode's part of the pre-arm check), or None."""
        return None if self.allows_arming else f"PreArm: cannot arm in {self.name}"

    def enter(self, prev: Mode, st: VehicleState | None) -> None:
        """The vehicle switches to this mode from ``prev`` (may be this mode) at state ``st``
        (None: no state yet)."""

    def run(self, st: VehicleState, t_s: float, dt_s: float) -> None:
        """Per control tick while armed (simulated time), before the pipeline's step."""

    def watch(self) -> Watch:
        """When :meth:`run` would next act (see :class:`Watch`); a mode that overrides ``run``
        must override this too, or it is flown through ``run`` every tick."""
        return WATCH_NOTHING if type(self).run is FlightMode.run else WATCH_EVERY_TICK

    def exit(self, to: Mode) -> None:
        """The vehicle leaves this mode for mode ``to`` (another one)."""

    def on_armed(self) -> None:
        """The vehicle was just armed in this mode."""

    def on_touchdown(self) -> Mode | None:
        """The pipeline disarmed on touchdown; the mode to switch to silently, or None to stay."""
        return None


class HoldHereMode(FlightMode):
    """Modes that hold the position they are entered at (GUIDED, LOITER, ALT_HOLD): switching to
    one while armed keeps the vehicle where it is (on the ground: the altitude set-point too)."""

    allows_arming = True

    def enter(self, prev: Mode, st: VehicleState | None) -> None:
        f = self.flight
        if st is not None and f.armed and prev != self.number:
            h = self.host.here(st)
            f.set_target(h.x_m, h.y_m, h.z_m if self.host.flying() else f.target[2])
