"""The ground router of a swarm: one ground address for every vehicle, routed by target system.

``python -m ground.router --ground udp:127.0.0.1:14550 --vehicle 1=127.0.0.1:14561 --vehicle 2=...``

Each flight controller of a swarm sends its telemetry to the router's vehicle-side port; the router
sends it on, datagram for datagram and byte for byte, to the ground (``--ground``: the station's
address, as an FC's own ``--gcs`` would) and to every station that has written to it. What a station
sends is split into its MAVLink packets and each goes to the vehicle its ``target_system`` names —
to every vehicle for 0 or a message without a target (a ground station's HEARTBEAT) — so a station
that, like pymavlink's ``udpin``, answers only the last address it heard still reaches every vehicle
and a command to one system id never reaches another. Packets are forwarded unchanged: MAVLink 2
signatures stay valid end to end (the router holds no key and checks none; each FC does).

Dropped and counted: a packet for a system id no vehicle has (``no_such_vehicle``), bytes that are
not whole MAVLink packets (``rx_bad``), datagrams on the vehicle side from an address that is no
vehicle's (``foreign``). Vehicle addresses come from ``--vehicle SYSID=HOST:PORT``, or are learned
for the system ids ``--sysids`` names: the first address to send from the vehicle side under one
of them is that vehicle (the vehicle side listens on loopback only; any other sender is foreign).

Ends on SIGTERM or SIGINT (exit 0), printing ``ROUTER_SUMMARY {json}``.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import select
import signal
import socket
import struct
import sys
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import TextIO

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from smcpilot.errors import EndpointError, SmcpilotError
from smcpilot.link import DEFAULT_PEER_TIMEOUT_S, Address, parse_endpoint

EXIT_OK = 0
EXIT_CONFIG = 2
#: ground stations remembered at once (the configured one always).
MAX_GROUND_PEERS = 16
_V1, _V2 = 0xFE, 0xFD
_SIGNED = 0x01


def _target_offsets() -> dict[int, int]:
    """Message id -> byte offset of ``target_system`` in its payload (messages that have one)."""
    out: dict[int, int] = {}
    for msgid, cls in mavlink.mavlink_map.items():
        names = list(getattr(cls, "ordered_fieldnames", ()))
        if "target_system" not in names:
            continue
        codes = re.findall(r"(\d*)([a-zA-Z?])", cls.unpacker.format.lstrip("<>=!@"))
        if len(codes) != len(names):
            continue
        offset = 0
        for (count, code), name in zip(codes, names):
            if name == "target_system":
                out[msgid] = offset
                break
            offset += struct.calcsize("<" + count + code)
    return out


TARGET_OFFSETS = _target_offsets()


def split_packets(data: bytes) -> tuple[list[tuple[bytes, int, int | None]], int]:
    """The MAVLink packets of a datagram: (bytes, source system, target system or None for "no
    target field") each, and how many runs of bytes were not a whole packet (dropped).

    A target beyond a MAVLink 2 payload's trimmed end is 0 (trailing zeros are cut on the wire).
    """
    out: list[tuple[bytes, int, int | None]] = []
    bad = 0
    i, n = 0, len(data)
    in_garbage = False
    while i < n:
        magic = data[i]
        if magic == _V2 and i + 10 <= n:
            length = data[i + 1]
            total = 12 + length + (13 if data[i + 2] & _SIGNED else 0)
            head, msgid = 10, data[i + 7] | data[i + 8] << 8 | data[i + 9] << 16
            src = data[i + 5]
        elif magic == _V1 and i + 6 <= n:
            length = data[i + 1]
            total = 8 + length
            head, msgid = 6, data[i + 5]
            src = data[i + 3]
        else:
            total = 0
        if total == 0 or i + total > n:
            if not in_garbage:
                bad += 1
                in_garbage = True
            nxt = [k for k in (data.find(b"\xfd", i + 1), data.find(b"\xfe", i + 1)) if k >= 0]
            i = min(nxt) if nxt else n
            continue
        in_garbage = False
        offset = TARGET_OFFSETS.get(msgid)
        target: int | None = None
        if offset is not None:
            target = data[i + head + offset] if offset < length else 0
        out.append((data[i:i + total], src, target))
        i += total
    return out, bad


@dataclass
class RouterCounters:
    to_ground_datagrams: int = 0
    to_vehicle_packets: int = 0
    broadcast_packets: int = 0
    no_such_vehicle: int = 0
    rx_bad: int = 0
    foreign: int = 0
    send_errors: int = 0


class GroundRouter:
    """The router's two sockets and its routing (see the module docstring). Use as a context manager."""

    def __init__(self, ground_url: str, vehicles: dict[int, Address] | None = None, *, sysids: Sequence[int] = (),
                 ground_port: int = 0, vehicle_host: str = "127.0.0.1", vehicle_port: int = 0) -> None:  # fmt: skip
        vehicles = dict(vehicles or {})
        if not vehicles and not sysids:
            raise SmcpilotError("the router needs its vehicles: --vehicle SYSID=HOST:PORT, or the --sysids to learn")
        #: system ids whose address is learned from the vehicle side (the first address sending as one).
        self.learn = frozenset(sysids) - set(vehicles)
        self.ground = parse_endpoint(ground_url)
        self.counters = RouterCounters()
        self.by_sysid: dict[int, Address] = dict(vehicles)
        self._vehicle_addrs = set(vehicles.values())
        self._configured_ground: Address | None = None
        self._ground_peers: dict[Address, float] = {}
        self.vside = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.gside = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.vside.bind((vehicle_host, vehicle_port))
            if self.ground.mode == "in":
                self.gside.bind((self.ground.host, self.ground.port))
            else:
                self._configured_ground = (socket.gethostbyname(self.ground.host), self.ground.port)
                try:
                    self.gside.bind(("127.0.0.1" if self._configured_ground[0].startswith("127.") else "0.0.0.0", ground_port))
                except OSError:
                    if not ground_port:
                        raise
                    self.gside.bind(("127.0.0.1" if self._configured_ground[0].startswith("127.") else "0.0.0.0", 0))
        except OSError as exc:
            self.close()
            raise SmcpilotError(f"router: cannot bind its sockets: {exc.strerror or exc}") from exc
        self.vside.setblocking(False)
        self.gside.setblocking(False)
        self._stop = False

    @property
    def vehicle_address(self) -> Address:
        host, port = self.vside.getsockname()[:2]
        return (host, port)

    @property
    def ground_address(self) -> Address:
        host, port = self.gside.getsockname()[:2]
        return (host, port)

    def request_stop(self, *_: object) -> None:
        self._stop = True

    def close(self) -> None:
        self.vside.close()
        self.gside.close()

    def __enter__(self) -> GroundRouter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- routing ---------------------------------------------------------------------------------
    def _ground_destinations(self, now: float) -> list[Address]:
        for addr, seen in list(self._ground_peers.items()):
            if now - seen > DEFAULT_PEER_TIMEOUT_S:
                del self._ground_peers[addr]
        out = list(self._ground_peers)
        if self._configured_ground is not None and self._configured_ground not in self._ground_peers:
            out.append(self._configured_ground)
        return out

    def _send(self, sock: socket.socket, data: bytes, addr: Address) -> None:
        try:
            sock.sendto(data, addr)
        except OSError:
            self.counters.send_errors += 1

    def from_vehicle(self, data: bytes, addr: Address, now: float) -> None:
        src = (data[5] if data[0] == _V2 else data[3] if data[0] == _V1 else None) if len(data) >= 6 else None
        if addr not in self._vehicle_addrs:
            if src is None or src not in self.learn or src in self.by_sysid:
                self.counters.foreign += 1
                return
            self._vehicle_addrs.add(addr)
            self.by_sysid[src] = addr
        for dest in self._ground_destinations(now):
            self._send(self.gside, data, dest)
        self.counters.to_ground_datagrams += 1

    def from_ground(self, data: bytes, addr: Address, now: float) -> None:
        if addr not in self._ground_peers and len(self._ground_peers) >= MAX_GROUND_PEERS:
            oldest = min(self._ground_peers, key=self._ground_peers.__getitem__)
            del self._ground_peers[oldest]
        self._ground_peers[addr] = now
        packets, bad = split_packets(data)
        c = self.counters
        c.rx_bad += bad
        out: dict[Address, list[bytes]] = {}
        everyone = list(dict.fromkeys(self.by_sysid.values()))
        for packet, _src, target in packets:
            if target is None or target == 0:
                c.broadcast_packets += 1
                for a in everyone:
                    out.setdefault(a, []).append(packet)
                continue
            dest = self.by_sysid.get(target)
            if dest is None:
                c.no_such_vehicle += 1
                continue
            c.to_vehicle_packets += 1
            out.setdefault(dest, []).append(packet)
        for dest, parts in out.items():
            self._send(self.vside, b"".join(parts), dest)

    def serve(self, poll_s: float = 0.5) -> None:
        socks = [self.vside, self.gside]
        while not self._stop:
            try:
                ready, _, _ = select.select(socks, [], [], poll_s)
            except InterruptedError:
                continue
            now = time.monotonic()
            for sock in ready:
                for _ in range(256):
                    try:
                        data, addr = sock.recvfrom(65535)
                    except (BlockingIOError, InterruptedError):
                        break
                    except OSError:  # an ICMP refusal of an earlier send: that peer is gone
                        self.counters.send_errors += 1
                        continue
                    a: Address = (addr[0], addr[1])
                    if sock is self.vside:
                        self.from_vehicle(data, a, now)
                    else:
                        self.from_ground(data, a, now)

    def summary(self) -> dict:
        return {**asdict(self.counters), "vehicles": {str(k): f"{v[0]}:{v[1]}" for k, v in sorted(self.by_sysid.items())},
                "ground_peers": len(self._ground_peers)}  # fmt: skip


def _vehicle_arg(text: str) -> tuple[int, Address]:
    sysid, eq, where = text.partition("=")
    host, colon, port = where.rpartition(":")
    if not (eq and colon and sysid.isdigit() and port.isdigit() and 1 <= int(sysid) <= 255 and 0 < int(port) <= 65535):
        raise argparse.ArgumentTypeError(f"expected SYSID=HOST:PORT (system id 1..255), got {text!r}")
    return int(sysid), (host or "127.0.0.1", int(port))


def _sysids_arg(text: str) -> tuple[int, ...]:
    try:
        ids = tuple(int(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected system ids N,N,... (1..255), got {text!r}") from None
    if not ids or not all(1 <= v <= 255 for v in ids):
        raise argparse.ArgumentTypeError(f"expected system ids N,N,... (1..255), got {text!r}")
    return ids


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m ground.router",
        description="One ground address for a swarm: forwards every vehicle's telemetry to the ground and each"
        " ground packet to the vehicle its target_system names (all for 0), bytes unchanged (signing intact).",
    )
    p.add_argument("--ground", required=True, metavar="URL",
                   help="the ground side: udp:HOST:PORT sends there and answers whoever writes, udpin:HOST:PORT listens")
    p.add_argument("--ground-port", type=int, default=0, metavar="PORT",
                   help="with udp:HOST:PORT, send from this port of ours (stations may write to it; default any free port,"
                   " a taken one falls back to a free one)")  # fmt: skip
    p.add_argument("--vehicle", type=_vehicle_arg, action="append", default=[], metavar="SYSID=HOST:PORT",
                   help="a vehicle's FC ground port (repeat for each vehicle)")
    p.add_argument("--sysids", type=_sysids_arg, default=(), metavar="N,N,...",
                   help="learn these vehicles' addresses: the first address sending under each system id")
    return p


def main(argv: Sequence[str] | None = None, out: TextIO = sys.stdout) -> int:
    args = build_parser().parse_args(argv)
    vehicles: dict[int, Address] = {}
    for sysid, addr in args.vehicle:
        if sysid in vehicles:
            print(f"router: error: system id {sysid} given twice", file=sys.stderr)
            return EXIT_CONFIG
        vehicles[sysid] = addr
    try:
        router = GroundRouter(args.ground, vehicles, sysids=args.sysids, ground_port=args.ground_port)
    except (SmcpilotError, EndpointError, OSError) as exc:
        print(f"router: error: {exc}", file=sys.stderr)
        return EXIT_CONFIG
    with router:
        signal.signal(signal.SIGTERM, router.request_stop)
        signal.signal(signal.SIGINT, router.request_stop)
        v, g = router.vehicle_address, router.ground_address
        print(f"ROUTER_READY vehicles={v[0]}:{v[1]} ground={g[0]}:{g[1]} to={router.ground.url} pid={os.getpid()}", file=out, flush=True)
        router.serve()
        print("ROUTER_SUMMARY " + json.dumps(router.summary(), sort_keys=True), file=out, flush=True)
    return EXIT_OK


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
