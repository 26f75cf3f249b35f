"""Parameters: the GCS side of the MAVLink parameter protocol (PARAM_REQUEST_READ,
PARAM_SET, PARAM_REQUEST_LIST -> PARAM_VALUE).

:class:`Params` is the part of :class:`~ground.vehicle.Vehicle` reached as ``vehicle.params``
(``vehicle.params.get("SMC_Z_KP")``; the vehicle's ``get_param``/``set_param``/``list_params``
delegate to it). Names are MAVLink parameter ids (at most 16 characters, case-insensitive: sent
upper-case); values are numbers in the parameter's own unit (an ``int`` for integer
parameters). Retries are wall clock: a request (or PARAM_SET) is re-sent every
``param_timeout_s``, ``param_tries`` times; a list fetch re-requests missing indices one by one.
"""

from __future__ import annotations

import math
import re
import time
from typing import TYPE_CHECKING

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from ground.vehicle.errors import ParamExchangeError, ParamRejected
from ground.vehicle.exchange import await_match, refusal_reason
from ground.vehicle.telemetry import StatusText, mavlink_text
from smcpilot.errors import ConfigError

if TYPE_CHECKING:
    from ground.vehicle.vehicle import Vehicle

__all__ = ["Params"]

_INT_PARAM_TYPES = frozenset(
    {
        mavlink.MAV_PARAM_TYPE_UINT8,
        mavlink.MAV_PARAM_TYPE_INT8,
        mavlink.MAV_PARAM_TYPE_UINT16,
        mavlink.MAV_PARAM_TYPE_INT16,
        mavlink.MAV_PARAM_TYPE_UINT32,
        mavlink.MAV_PARAM_TYPE_INT32,
    }
)


class Params:
    """The vehicle's parameters (``vehicle.params``); settings ``param_timeout_s`` and
    ``param_tries`` are the vehicle's.

    Every PARAM_VALUE the vehicle sends is remembered (value and MAV_PARAM_TYPE), so
    :meth:`set` knows a parameter's type without asking again.
    """

    def __init__(self, vehicle: Vehicle) -> None:
        self._vehicle = vehicle
        #: name -> (value, MAV_PARAM_TYPE) of every PARAM_VALUE received.
        self._seen: dict[str, tuple[float, int]] = {}
        vehicle.subscribe("PARAM_VALUE", self._remember)

    def _remember(self, msg: mavlink.MAVLink_message) -> None:
        """Subscription callback (receiver thread): note a PARAM_VALUE."""
        self._seen[mavlink_text(msg.param_id)] = (msg.param_value, msg.param_type)

    def get(self, name: str) -> float:
        """PARAM_REQUEST_READ by name (re-requested every ``param_timeout_s``, ``param_tries``
        times); returns the value (an ``int`` for integer parameters). Raises :class:`ParamExchangeError`
        when the vehicle never answers (unknown name)."""
        value, _ = self._read(name)
        return value

    def _read(self, name: str) -> tuple[float, int]:
        """(value, MAV_PARAM_TYPE). Stops re-requesting early when the vehicle sent a STATUSTEXT
        naming the parameter instead of a value (e.g. "unknown SMC_FOO"): that is its answer."""
        v = self._vehicle
        pid = _param_id(name)
        mav = v.mav
        said: list[str] = []

        def match(m: mavlink.MAVLink_message) -> bool:
            if m.get_type() == "STATUSTEXT":
                text = mavlink_text(m.text)
                if re.search(rf"\b{re.escape(pid)}\b", text.upper()):
                    said.append(text)
                    return True
                return False
            return mavlink_text(m.param_id) == pid

        tries = 0
        with v.subscribe(("PARAM_VALUE", "STATUSTEXT")) as sub:
            while tries < v.param_tries and not said:
                tries += 1
                v.send(mav.param_request_read_encode(v.target_system, v.target_component, pid.encode(), -1))
                msg = await_match(sub, match, v.param_timeout_s)
                if msg is not None and msg.get_type() == "PARAM_VALUE":
                    return _param_value(msg), msg.param_type
        if said:
            raise ParamExchangeError(f"no value for parameter {pid}: {said[-1]}")
        raise ParamExchangeError(
            f"no PARAM_VALUE for {pid!r} after {tries} requests {v.param_timeout_s:g} s apart"
            " (unknown parameter, or the vehicle is not answering)"
        )

    def set(self, name: str, value: float) -> float:
        """PARAM_SET (re-sent every ``param_timeout_s`` until the PARAM_VALUE echo, ``param_tries``
        times); returns the value now in force. Raises :class:`ParamRejected` (with the
        STATUSTEXT reason) when the vehicle kept another value."""
        v = self._vehicle
        pid = _param_id(name)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"parameter {pid}: value must be a number, got {value!r}")
        cached = self._seen.get(pid)
        ptype = cached[1] if cached is not None else self._read(pid)[1]
        mav = v.mav
        texts: list[StatusText] = []
        with v.subscribe(("PARAM_VALUE", "STATUSTEXT")) as sub:
            for _ in range(v.param_tries):
                v.send(mav.param_set_encode(v.target_system, v.target_component, pid.encode(), float(value), ptype))
                deadline = time.monotonic() + v.param_timeout_s
                while (remaining := deadline - time.monotonic()) > 0:
                    msg = sub.get(remaining)
                    if msg is None:
                        break
                    if msg.get_type() == "STATUSTEXT":
                        texts.append(StatusText.received(msg, v.sim_time_s))
                        continue
                    if mavlink_text(msg.param_id) != pid:
                        continue
                    got = _param_value(msg)
                    if not _float32_equal(float(got), float(value)):
                        raise ParamRejected(pid, float(value), float(got), refusal_reason(v, sub, texts))
                    return got
        raise ParamExchangeError(f"no PARAM_VALUE echo for PARAM_SET {pid} after {v.param_tries} tries {v.param_timeout_s:g} s apart")

    def list(self) -> dict[str, float]:
        """Every parameter (PARAM_REQUEST_LIST), in index order: name -> value (``int`` for
        integer parameters). Indices still missing when the stream pauses for
        ``param_timeout_s`` are re-requested one by one (PARAM_REQUEST_READ by index), up to
        ``param_tries`` rounds; then :class:`ParamExchangeError` lists what is missing."""
        v = self._vehicle
        mav = v.mav
        by_index: dict[int, tuple[str, float]] = {}
        count: int | None = None
        with v.subscribe("PARAM_VALUE") as sub:
            v.send(mav.param_request_list_encode(v.target_system, v.target_component))
            rounds = 0
            while count is None or len(by_index) < count:
                msg = sub.get(v.param_timeout_s)
                if msg is not None:
                    count = msg.param_count
                    if 0 <= msg.param_index < msg.param_count:
                        by_index[msg.param_index] = (mavlink_text(msg.param_id), _param_value(msg))
                    continue
                rounds += 1
                if rounds >= v.param_tries:
                    missing = "all" if count is None else f"{count - len(by_index)} of {count}"
                    raise ParamExchangeError(f"parameter list incomplete after {rounds} retries: {missing} missing")
                if count is None:
                    v.send(mav.param_request_list_encode(v.target_system, v.target_component))
                else:
                    for index in range(count):
                        if index not in by_index:
                            v.send(mav.param_request_read_encode(v.target_system, v.target_component, b"", index))
        return {name: value for _, (name, value) in sorted(by_index.items())}


def _param_id(name: str) -> str:
    """The MAVLink parameter id of ``name``: stripped, upper-case, at most 16 characters."""
    if not isinstance(name, str) or not name.strip():
        raise ConfigError(f"parameter name must be a non-empty string, got {name!r}")
    pid = name.strip().upper()
    if len(pid) > 16:
        raise ConfigError(f"parameter name {pid!r} is longer than MAVLink's 16 characters")
    return pid


def _param_value(msg: mavlink.MAVLink_message) -> float:
    """A PARAM_VALUE's value: an ``int`` for integer parameter types (when finite), else a float."""
    v = float(msg.param_value)
    if msg.param_type in _INT_PARAM_TYPES and math.isfinite(v):
        return int(round(v))
    return v


def _float32_equal(a: float, b: float) -> bool:
    """Equal as MAVLink's float32 carries them."""
    if math.isnan(a) or math.isnan(b):
        return False
    return a == b or abs(a - b) <= 1e-6 * max(abs(a), abs(b))
