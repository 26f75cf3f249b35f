"""Missions: the GCS side of the MAVLink mission protocol (upload, download, clear) and the
commands that run a mission (start, set the current item).

:class:`Mission` is the part of :class:`~ground.vehicle.Vehicle` reached as ``vehicle.mission``
(``vehicle.mission.upload(items)``; the vehicle's ``upload_mission``, ``download_mission``,
``clear_mission``, ``start_mission`` and ``set_current_item`` delegate to it).

As in ArduPilot, **item 0 is home**: :meth:`Mission.upload` takes the items to fly and inserts
the home item itself (from the vehicle's ``HOME_POSITION``), so ``items[0]`` becomes sequence
number 1; :meth:`Mission.download` strips item 0 again. Sequence numbers given to or reported by
the vehicle (:meth:`Mission.set_current`, :attr:`~ground.vehicle.telemetry.Telemetry.mission_current`,
``MISSION_ITEM_REACHED``) are the vehicle's: user item ``k`` (0-based) is sequence number
``k + 1``. Retries are wall clock (``mission_timeout_s``, ``mission_tries``).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from ground.vehicle.errors import MissionError, VehicleTimeout
from ground.vehicle.exchange import refusal_reason
from ground.vehicle.items import MissionItem
from ground.vehicle.names import mission_result_name
from ground.vehicle.telemetry import StatusText
from smcpilot.errors import ConfigError

if TYPE_CHECKING:
    from ground.vehicle.subscription import Subscription
    from ground.vehicle.vehicle import Vehicle

__all__ = ["Mission"]


class Mission:
    """The vehicle's mission (``vehicle.mission``); settings ``mission_timeout_s`` and
    ``mission_tries`` are the vehicle's."""

    def __init__(self, vehicle: Vehicle) -> None:
        self._vehicle = vehicle

    def upload(self, items: Sequence[MissionItem]) -> None:
        """Upload ``items`` (the items to fly; home is inserted as item 0 from the vehicle's
        HOME_POSITION): MISSION_COUNT -> MISSION_REQUEST_INT/MISSION_REQUEST -> MISSION_ITEM_INT
        ... -> MISSION_ACK.

        Retries: while the vehicle has requested nothing, MISSION_COUNT is re-sent every
        ``mission_timeout_s`` (``mission_tries`` times); after that the vehicle drives the
        transaction (it re-requests what it misses) and we answer every request, giving up after
        ``mission_tries`` × ``mission_timeout_s`` of silence. Raises :class:`MissionError` with the
        MAV_MISSION_RESULT name when the vehicle refuses an item.
        """
        v = self._vehicle
        for i, item in enumerate(items):
            if not isinstance(item, MissionItem):
                raise ConfigError(f"mission item {i} must be a MissionItem, got {type(item).__name__}")
        try:
            home = v.get_home(timeout_s=max(2.0, 2 * v.mission_timeout_s))
        except VehicleTimeout:
            home = None  # ArduPilot replaces item 0 with its home anyway
        full = [MissionItem.home(home), *items]
        mav = v.mav
        ts, tc = v.target_system, v.target_component
        count_msg = mav.mission_count_encode(ts, tc, len(full), mavlink.MAV_MISSION_TYPE_MISSION)
        texts: list[StatusText] = []
        requested = False
        last_sent: mavlink.MAVLink_message | None = None
        silent_rounds = 0
        with v.subscribe(("MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK", "STATUSTEXT")) as sub:
            v.send(count_msg)
            while True:
                msg = sub.get(v.mission_timeout_s)
                if msg is None:
                    silent_rounds += 1
                    if silent_rounds >= v.mission_tries:
                        raise MissionError(
                            f"mission upload ({len(full)} items incl. home) timed out: the vehicle went silent for"
                            f" {silent_rounds * v.mission_timeout_s:g} s wall"
                            + ("" if requested else " without requesting any item")
                        )
                    # Nothing requested yet: the count was lost. Else our last item or the
                    # vehicle's answer to it was: send it again (the vehicle re-acks a finished upload).
                    v.send(count_msg if last_sent is None else last_sent)
                    continue
                t = msg.get_type()
                if t == "STATUSTEXT":
                    texts.append(StatusText.received(msg, v.sim_time_s))
                    continue
                if getattr(msg, "mission_type", 0) != mavlink.MAV_MISSION_TYPE_MISSION:
                    continue
                silent_rounds = 0
                if t == "MISSION_ACK":
                    if msg.type == mavlink.MAV_MISSION_ACCEPTED:
                        if requested or len(full) == 0:
                            return
                        continue  # a stale ACK from an earlier transaction
                    raise MissionError(
                        f"mission upload refused with {mission_result_name(msg.type)}",
                        result=msg.type,
                        reason=refusal_reason(v, sub, texts, grace_s=0.2),
                    )
                seq = msg.seq
                if not 0 <= seq < len(full):
                    raise MissionError(f"the vehicle requested item {seq} of a {len(full)}-item mission")
                requested = True
                last_sent = full[seq].to_message(mav, seq, ts, tc)
                v.send(last_sent)

    def download(self, *, include_home: bool = False) -> list[MissionItem]:
        """Download the mission: MISSION_REQUEST_LIST -> MISSION_COUNT -> MISSION_REQUEST_INT
        (each item) -> MISSION_ACK. Each request is re-sent every ``mission_timeout_s`` up to
        ``mission_tries`` times. Returns the items to fly: **item 0 (home) is stripped** unless
        ``include_home`` (then the list is exactly the vehicle's, sequence number = index)."""
        v = self._vehicle
        mav = v.mav
        ts, tc = v.target_system, v.target_component
        mtype = mavlink.MAV_MISSION_TYPE_MISSION
        with v.subscribe(("MISSION_COUNT", "MISSION_ITEM_INT", "MISSION_ITEM", "MISSION_ACK")) as sub:
            count_reply = self._exchange(
                sub,
                mav.mission_request_list_encode(ts, tc, mtype),
                lambda m: m.get_type() == "MISSION_COUNT" and getattr(m, "mission_type", 0) == mtype,
                "MISSION_COUNT",
            )
            count = count_reply.count
            items: list[MissionItem] = []
            for seq in range(count):
                reply = self._exchange(
                    sub,
                    mav.mission_request_int_encode(ts, tc, seq, mtype),
                    lambda m, s=seq: m.get_type() in ("MISSION_ITEM_INT", "MISSION_ITEM")  # type: ignore[misc]
                    and m.seq == s
                    and getattr(m, "mission_type", 0) == mtype,
                    f"mission item {seq}",
                )
                items.append(MissionItem.from_message(reply))
            v.send(mav.mission_ack_encode(ts, tc, mavlink.MAV_MISSION_ACCEPTED, mtype))
        return items if include_home else items[1:]

    def clear(self) -> None:
        """MISSION_CLEAR_ALL, re-sent until the MISSION_ACK; raises :class:`MissionError` if refused."""
        v = self._vehicle
        mav = v.mav
        ts, tc = v.target_system, v.target_component
        with v.subscribe("MISSION_ACK") as sub:
            ack = self._exchange(
                sub,
                mav.mission_clear_all_encode(ts, tc, mavlink.MAV_MISSION_TYPE_MISSION),
                lambda m: getattr(m, "mission_type", 0) == mavlink.MAV_MISSION_TYPE_MISSION,
                "MISSION_ACK for MISSION_CLEAR_ALL",
            )
        if ack.type != mavlink.MAV_MISSION_ACCEPTED:
            raise MissionError(f"mission clear refused with {mission_result_name(ack.type)}", result=ack.type)

    def start(self, first_seq: int = 0) -> None:
        """MAV_CMD_MISSION_START (switches to AUTO; 0 = from the current item)."""
        self._vehicle.command_long(mavlink.MAV_CMD_MISSION_START, float(first_seq), 0.0, check=True)

    def set_current(self, seq: int) -> None:
        """MAV_CMD_DO_SET_MISSION_CURRENT: continue the mission at vehicle sequence number
        ``seq`` (1 = the first item after home)."""
        if seq < 0:
            raise ConfigError(f"mission sequence number must be >= 0, got {seq}")
        self._vehicle.command_long(mavlink.MAV_CMD_DO_SET_MISSION_CURRENT, float(seq), check=True)

    def _exchange(
        self,
        sub: Subscription,
        request: mavlink.MAVLink_message,
        match: Callable[[mavlink.MAVLink_message], bool],
        what: str,
    ) -> mavlink.MAVLink_message:
        """Send ``request`` until a matching reply comes (``mission_tries`` × ``mission_timeout_s``);
        a MISSION_ACK that is not the awaited reply is an error from the vehicle."""
        v = self._vehicle
        for _ in range(v.mission_tries):
            v.send(request)
            deadline = time.monotonic() + v.mission_timeout_s
            while (remaining := deadline - time.monotonic()) > 0:
                msg = sub.get(remaining)
                if msg is None:
                    break
                if match(msg):
                    return msg
                if msg.get_type() == "MISSION_ACK" and getattr(msg, "mission_type", 0) == mavlink.MAV_MISSION_TYPE_MISSION:
                    raise MissionError(f"waiting for {what}, the vehicle ended the transaction with {mission_result_name(msg.type)}", result=msg.type)
        raise MissionError(f"no {what} after {v.mission_tries} requests {v.mission_timeout_s:g} s apart")
