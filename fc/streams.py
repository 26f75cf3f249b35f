"""Which telemetry messages go to ground stations, how often (simulated time), and when next.

Defaults follow docs/gcs-protocol.md; ``SET_MESSAGE_INTERVAL`` and ``REQUEST_DATA_STREAM`` change
them. Scheduling is pure: :meth:`StreamScheduler.due` returns the message ids due at a time.

Bounds (hostile or mistaken requests): an interval shorter than :data:`MIN_INTERVAL_US` gets
that one (the fastest we stream; a REQUEST_DATA_STREAM group at most :data:`MAX_STREAM_RATE_HZ`), one longer than :data:`MAX_INTERVAL_US` is refused, and the
heartbeat is never slower than :data:`MAX_HEARTBEAT_INTERVAL_US` nor off (ground stations take
a vehicle silent for a few seconds as lost). :func:`interval_refusal` says why a request is
refused.
"""

from __future__ import annotations

from pymavlink.dialects.v20 import ardupilotmega as mavlink

M = mavlink
#: the shortest interval streamed, µs (200 Hz); shorter requests get this one.
MIN_INTERVAL_US = 5_000
#: the fastest a REQUEST_DATA_STREAM group streams, Hz (ArduPilot's ``SRn_*`` rates range 0-50 Hz);
#: faster requests get this rate. One message can still be asked faster with SET_MESSAGE_INTERVAL.
MAX_STREAM_RATE_HZ = 50
#: the longest interval accepted, µs (one minute); longer requests are refused.
MAX_INTERVAL_US = 60_000_000
#: the heartbeat's longest interval, µs (1 Hz, the MAVLink heartbeat rate).
MAX_HEARTBEAT_INTERVAL_US = 1_000_000
#: message id -> default rate in Hz (None: follows the telemetry rate parameter)
DEFAULT_RATES_HZ: dict[int, float | None] = {
    M.MAVLINK_MSG_ID_HEARTBEAT: 1.0,
    M.MAVLINK_MSG_ID_SYS_STATUS: 1.0,
    M.MAVLINK_MSG_ID_SYSTEM_TIME: 1.0,
    M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 1.0,
    M.MAVLINK_MSG_ID_ATTITUDE: None,
    M.MAVLINK_MSG_ID_LOCAL_POSITION_NED: None,
    M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: None,
    M.MAVLINK_MSG_ID_NAMED_VALUE_FLOAT: None,
    M.MAVLINK_MSG_ID_GPS_RAW_INT: 2.0,
    M.MAVLINK_MSG_ID_VFR_HUD: 4.0,
    M.MAVLINK_MSG_ID_MISSION_CURRENT: 1.0,
    M.MAVLINK_MSG_ID_HOME_POSITION: 0.2,
    M.MAVLINK_MSG_ID_NAMED_VALUE_INT: 1.0,
    M.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED: 4.0,
    M.MAVLINK_MSG_ID_EKF_STATUS_REPORT: 2.0,
}

#: REQUEST_DATA_STREAM groups (ArduPilot's grouping, restricted to what we send).
STREAM_GROUPS: dict[int, tuple[int, ...]] = {
    M.MAV_DATA_STREAM_EXTENDED_STATUS: (
        M.MAVLINK_MSG_ID_SYS_STATUS,
        M.MAVLINK_MSG_ID_GPS_RAW_INT,
        M.MAVLINK_MSG_ID_MISSION_CURRENT,
        M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE,
    ),
    M.MAV_DATA_STREAM_POSITION: (
        M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
        M.MAVLINK_MSG_ID_LOCAL_POSITION_NED,
        M.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED,
    ),
    M.MAV_DATA_STREAM_EXTRA1: (M.MAVLINK_MSG_ID_ATTITUDE,),
    M.MAV_DATA_STREAM_EXTRA2: (M.MAVLINK_MSG_ID_VFR_HUD,),
    M.MAV_DATA_STREAM_EXTRA3: (M.MAVLINK_MSG_ID_SYSTEM_TIME, M.MAVLINK_MSG_ID_HOME_POSITION, M.MAVLINK_MSG_ID_EKF_STATUS_REPORT),
}


def interval_refusal(msg_id: int, interval_us: float) -> str | None:
    """Why ``SET_MESSAGE_INTERVAL(msg_id, interval_us)`` is refused, or None if it is fine."""
    if interval_us != interval_us or interval_us in (float("inf"), float("-inf")):
        return "Message interval: not a number"
    if msg_id not in DEFAULT_RATES_HZ:
        return f"Message interval: message {msg_id} not streamed"
    if msg_id == M.MAVLINK_MSG_ID_HEARTBEAT and (interval_us < 0 or interval_us > MAX_HEARTBEAT_INTERVAL_US):
        return f"Message interval: heartbeat stays at {MAX_HEARTBEAT_INTERVAL_US // 1000} ms or faster"
    if interval_us > MAX_INTERVAL_US:
        return f"Message interval: {interval_us:.3g} us over the {MAX_INTERVAL_US // 1_000_000} s limit"
    return None


class StreamScheduler:
    """Intervals in microseconds of simulated time; 0 means off."""

    def __init__(self, telemetry_rate_hz: float) -> None:
        self._telemetry_rate_hz = telemetry_rate_hz
        self._override: dict[int, int] = {}
        self._next_us: dict[int, int] = {}
        self._earliest_us = 0
        self.interval_us: dict[int, int] = {}
        self._recompute()

    def _default_us(self, msg_id: int) -> int:
        rate = DEFAULT_RATES_HZ[msg_id]
        return int(round(1e6 / (self._telemetry_rate_hz if rate is None else rate)))

    def _recompute(self) -> None:
        self.interval_us = {mid: self._override.get(mid, self._default_us(mid)) for mid in DEFAULT_RATES_HZ}

    def set_telemetry_rate(self, rate_hz: float) -> None:
        self._telemetry_rate_hz = rate_hz
        self._recompute()
        self._earliest_us = 0

    def set_interval(self, msg_id: int, interval_us: float) -> bool:
        """MAV_CMD_SET_MESSAGE_INTERVAL semantics: -1 off, 0 default, else µs (at least
        :data:`MIN_INTERVAL_US`). False if refused (:func:`interval_refusal`)."""
        if interval_refusal(msg_id, interval_us) is not None:
            return False
        if interval_us == 0:
            self._override.pop(msg_id, None)
        elif interval_us < 0:
            self._override[msg_id] = 0
        else:
            self._override[msg_id] = max(MIN_INTERVAL_US, int(interval_us))
        self._recompute()
        self._next_us.pop(msg_id, None)
        self._earliest_us = 0
        return True

    def request_stream(self, stream_id: int, rate_hz: int, start: bool) -> str | None:
        """REQUEST_DATA_STREAM: set a group's rate (0 Hz or stop: off; faster than
        :data:`MAX_STREAM_RATE_HZ`: that rate, as ArduPilot bounds its ``SRn_*`` rates). Returns why
        it was refused (unknown group), or None."""
        if stream_id == M.MAV_DATA_STREAM_ALL:
            ids: tuple[int, ...] = tuple(m for ids in STREAM_GROUPS.values() for m in ids)
        elif stream_id in STREAM_GROUPS:
            ids = STREAM_GROUPS[stream_id]
        else:
            return f"Data stream: group {stream_id} unknown"
        for mid in ids:
            self.set_interval(mid, int(1e6 / min(rate_hz, MAX_STREAM_RATE_HZ)) if start and rate_hz > 0 else -1)
        return None

    def defer(self, ids: list[int], t_us: int) -> None:
        """Messages that were due but not sent (the ground link's budget ran out): due again from
        ``t_us`` (the next tick), their phase kept."""
        for mid in ids:
            self._next_us[mid] = t_us
        if ids:
            self._earliest_us = min(self._earliest_us, t_us)

    def due(self, t_us: int) -> list[int]:
        if t_us < self._earliest_us:
            return []  # nothing due before the earliest next time (the common case, per tick)
        out: list[int] = []
        nxt = self._next_us
        for mid, interval in self.interval_us.items():
            if interval <= 0:
                continue
            when = nxt.get(mid)
            if when is None or t_us >= when:
                out.append(mid)
                # keep the phase: next = previous due time + interval (but never in the past)
                base = when if when is not None and t_us - when < interval else t_us
                nxt[mid] = base + interval
        active = [nxt.get(m, t_us) for m, i in self.interval_us.items() if i > 0]
        self._earliest_us = min(active) if active else 2**63
        return out
