"""Several vehicles on one ground address: :class:`Swarm`, one :class:`~ground.vehicle.Vehicle` per system id.

A swarm launched by ``smcpilot sitl --count K`` answers ground stations through one router
(:mod:`ground.router`, the ``router answers on`` address it prints, 14551 by default). Each
vehicle of a :class:`Swarm` is an ordinary :class:`~ground.vehicle.Vehicle` writing to that address
(``udpout:``) from a socket of its own and listening only to its system id; the router sends every
vehicle's telemetry to each of them and each one's packets to the vehicle they name::

    with Swarm("udpout:127.0.0.1:14551", [1, 2, 3]) as swarm:
        swarm.arm_all()
        swarm.takeoff_all(3.0)
        swarm.wait_all(lambda v: v.wait_altitude(3.0, tol_m=0.3, timeout_sim_s=20))
        swarm[2].goto_ned(4.0, 0.0, -3.0)
        swarm.land_all()
        swarm.wait_all(lambda v: v.wait_disarmed(timeout_sim_s=60))

``wait_all`` runs one wait per vehicle on threads and raises the first failure, naming the vehicle.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator, Sequence
from types import TracebackType
from typing import Any, Self

from ground.vehicle.errors import VehicleError
from ground.vehicle.vehicle import Vehicle
from smcpilot.errors import ConfigError
from smcpilot.link import parse_endpoint


class SwarmError(VehicleError):
    """One vehicle of a swarm failed (the message names its system id)."""


class Swarm:
    """One :class:`Vehicle` per system id, all on one ``udpout:`` ground address (a swarm's router).

    ``vehicle_kw`` are :class:`Vehicle`'s settings (timeouts, signing key), the same for each.
    """

    def __init__(self, url: str, sysids: Sequence[int], **vehicle_kw: Any) -> None:
        if parse_endpoint(url).mode != "out":
            raise ConfigError(f"Swarm needs a udpout:HOST:PORT address (a swarm's router answers on one), got {url!r}:"
                              " one listening socket cannot be shared by several vehicles")  # fmt: skip
        ids = list(sysids)
        if not ids or len(set(ids)) != len(ids):
            raise ConfigError(f"Swarm needs distinct system ids, got {ids!r}")
        self.url = url
        self.vehicles: dict[int, Vehicle] = {sid: Vehicle(url, system_id=sid, **vehicle_kw) for sid in ids}

    def __getitem__(self, sysid: int) -> Vehicle:
        try:
            return self.vehicles[sysid]
        except KeyError:
            raise KeyError(f"no vehicle with system id {sysid} in this swarm ({', '.join(map(str, self.vehicles))})") from None

    def __iter__(self) -> Iterator[Vehicle]:
        return iter(self.vehicles.values())

    def __len__(self) -> int:
        return len(self.vehicles)

    @property
    def sysids(self) -> tuple[int, ...]:
        return tuple(self.vehicles)

    # -- lifecycle ---------------------------------------------------------------------------------
    def connect(self, timeout_s: float | None = None) -> Self:
        """Open every vehicle's link and wait for each one's HEARTBEAT; closes all on failure."""
        try:
            for v in self.vehicles.values():
                v.open()
            self.wait_all(lambda v: v.wait_heartbeat(timeout_s))
        except BaseException:
            self.close()
            raise
        return self

    def close(self) -> None:
        for v in self.vehicles.values():
            v.close()

    def __enter__(self) -> Self:
        return self.connect()

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        self.close()

    # -- every vehicle at once -----------------------------------------------------------------------
    def wait_all(self, action: Callable[[Vehicle], object]) -> dict[int, object]:
        """Run ``action(vehicle)`` for every vehicle at once (one thread each); their results by
        system id. The first failure (by system id) is raised as :class:`SwarmError` naming it."""
        results: dict[int, object] = {}
        errors: dict[int, BaseException] = {}

        def run(sid: int, v: Vehicle) -> None:
            try:
                results[sid] = action(v)
            except BaseException as exc:  # re-raised below, naming the vehicle
                errors[sid] = exc

        threads = [threading.Thread(target=run, args=(sid, v), name=f"swarm-{sid}", daemon=True) for sid, v in self.vehicles.items()]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        if errors:
            sid = min(errors)
            raise SwarmError(f"vehicle {sid}: {type(errors[sid]).__name__}: {errors[sid]}") from errors[sid]
        return results

    def arm_all(self, *, timeout_sim_s: float = 5.0) -> None:
        self.wait_all(lambda v: v.arm(timeout_sim_s=timeout_sim_s))

    def takeoff_all(self, alt_m: float) -> None:
        self.wait_all(lambda v: v.takeoff(alt_m))

    def land_all(self) -> None:
        self.wait_all(lambda v: v.land())

    def goto(self, sysid: int, north_m: float, east_m: float, down_m: float, yaw_deg: float | None = None) -> None:
        """Vehicle ``sysid`` to a point of its own local frame (NED, m, from where it spawned)."""
        self[sysid].goto_ned(north_m, east_m, down_m, yaw_deg)

    def positions_ned_m(self) -> dict[int, tuple[float, float, float] | None]:
        """Every vehicle's latest position in its own local frame (None before its first)."""
        return {sid: v.position_ned_m for sid, v in self.vehicles.items()}

    def __repr__(self) -> str:
        return f"Swarm({self.url!r}, {list(self.vehicles)})"


__all__ = ["Swarm", "SwarmError"]

