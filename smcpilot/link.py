"""MAVLink over UDP: the link plumbing the flight controller and the simulator bridge share.

Endpoints are written the way MAVLink tools write them:

``udp:HOST:PORT`` or ``udpout:HOST:PORT``
    send to HOST:PORT from an ephemeral port of our own (bound on loopback when HOST is a loopback
    address, else on all interfaces), and also answer every address that writes to us.
``udpin:HOST:PORT``
    bind HOST:PORT (``udpin::PORT`` = all interfaces; PORT 0 = any free port), no destination
    until someone writes to us; then answer whoever writes.

(Careful: pymavlink and MAVProxy read a bare ``udp:`` as *listen*; here it means *send*.)

:class:`MavlinkUdp` sends each message to every known peer, packs several messages into one
datagram with :meth:`MavlinkUdp.send_many`, and parses every datagram completely and on its own
(a datagram holds whole packets, so no parser state is carried from one datagram, or one peer,
to the next). Bad bytes never raise: they are dropped and counted in
:attr:`MavlinkUdp.counters`, and the parser resynchronises on the next start-of-frame byte inside
the same datagram, so a good packet behind garbage still arrives. Sending never raises on
network errors either (an unreachable ground station must not stop the control loop): they are
counted in ``tx_errors``.

With a :class:`~smcpilot.signing.Signing` whose key is set, every packet sent is signed
(the fast-path ones too) with the link's ``link_id``, and every packet received is checked
before it is returned: unsigned ones outside the accepted list, bad signatures and old or
out-of-window timestamps are dropped and counted (``rx_unsigned``, ``rx_bad_signature``,
``rx_old_timestamp``, ``rx_stream_window``). A ``SETUP_SIGNING`` packet reaches the tlog with its
key zeroed.

The three messages of the control loop (ATTITUDE, LOCAL_POSITION_NED, HIL_ACTUATOR_CONTROLS) are
encoded and decoded by :mod:`smcpilot.fastcodec` (same bytes, same message objects, several times
faster); everything else goes through pymavlink.

Every message sent and every message returned by :meth:`MavlinkUdp.recv` is written to the tlog,
if one is given, stamped with the injected ``clock_us()`` (simulated time in lockstep, so logs
are reproducible bit for bit). Peer expiry uses real time (``time.monotonic``), because peers
come and go in the real world.

A link is not thread-safe: one thread owns it.
"""

from __future__ import annotations

import errno
import ipaddress
import math
import os
import re
import select
import socket
import struct
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass
from types import TracebackType
from typing import Literal

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from smcpilot import fastcodec
from smcpilot import signing as _signing
from smcpilot.errors import EndpointError, LinkClosedError, LinkError
from smcpilot.impair import Impairer, LinkImpairment
from smcpilot.signing import Signing, redact_setup_signing
from smcpilot.tlog import TlogWriter

__all__ = [
    "Address",
    "Endpoint",
    "LinkCounters",
    "MavlinkUdp",
    "PacketSink",
    "parse_endpoint",
    "DEFAULT_PEER_TIMEOUT_S",
    "DEFAULT_MAX_DATAGRAM_BYTES",
]

#: A UDP peer address as the socket module gives it: ``(host, port)``.
Address = tuple[str, int]

#: A peer that has not written for this long stops receiving :meth:`MavlinkUdp.send`.
DEFAULT_PEER_TIMEOUT_S = 10.0
#: :meth:`MavlinkUdp.send_many` starts a new datagram before one would exceed this size; 1400
#: stays under an Ethernet/Wi-Fi MTU, so datagrams are not fragmented on the way to a GCS.
DEFAULT_MAX_DATAGRAM_BYTES = 1400
#: At most this many peers learnt from incoming traffic are remembered (the initial destination
#: of an ``out`` endpoint comes on top); a flood of new source addresses cannot make us send to
#: more places than this. When full, the peer heard from least recently is forgotten.
DEFAULT_MAX_PEERS = 16
#: When the peer table is full, a peer (not pinned) silent this long gives its place to a new
#: one; a station writing its 1 Hz heartbeat never is.
PEER_QUIET_S = 2.5

_SCHEMES: dict[str, Literal["out", "in"]] = {"udp": "out", "udpout": "out", "udpin": "in"}
_HOST_RE = re.compile(r"^[A-Za-z0-9](?:[A-Za-z0-9.-]*[A-Za-z0-9])?$")
_ENDPOINT_FORMS = "udp:HOST:PORT, udpout:HOST:PORT or udpin:HOST:PORT"

_RECV_BUFFER_BYTES = 65535
_MAGIC_V1 = mavlink.PROTOCOL_MARKER_V1
_MAGIC_V2 = mavlink.PROTOCOL_MARKER_V2
_START_OF_FRAME = re.compile(b"[\xfd\xfe]")
_SIGNATURE_BYTES = mavlink.MAVLINK_SIGNATURE_BLOCK_LEN
_DECODE_ERRORS = (mavlink.MAVError, struct.error, ArithmeticError, LookupError, TypeError, ValueError)
_FD_SETSIZE = 1024
_UNKNOWN_MESSAGE = mavlink.MAVLink_unknown
_SETUP_SIGNING_LOW = mavlink.MAVLINK_MSG_ID_SETUP_SIGNING & 0xFF  # id 256: low byte 0, middle byte 1
_SIGNING_OK = _signing.OK
_REJECT_COUNTERS = _signing.REJECT_REASONS
#: Linux's IP_RECVERR: report ICMP errors (a closed peer port) on an unconnected UDP socket.
_IP_RECVERR = getattr(socket, "IP_RECVERR", 11)


@dataclass(frozen=True)
class Endpoint:
    """Where a link sends or listens. ``mode`` "out": send to host:port; "in": bind host:port."""

    mode: Literal["out", "in"]
    host: str
    port: int

    def __post_init__(self) -> None:
        if self.mode not in ("out", "in"):
            raise EndpointError(f"endpoint {self!r}: mode must be 'out' or 'in'")
        if not isinstance(self.host, str) or not self.host:
            raise EndpointError(f"endpoint {self!r}: host must be a non-empty string")
        lowest_port = 0 if self.mode == "in" else 1
        if not isinstance(self.port, int) or not lowest_port <= self.port <= 65535:
            raise EndpointError(f"endpoint {self!r}: port must be an integer in {lowest_port}..65535")

    @property
    def url(self) -> str:
        """Canonical URL form, ``udpout:HOST:PORT`` or ``udpin:HOST:PORT``."""
        return f"udp{self.mode}:{self.host}:{self.port}"

    def __str__(self) -> str:
        return self.url


def parse_endpoint(url: str) -> Endpoint:
    """Parse ``udp:HOST:PORT``, ``udpout:HOST:PORT`` or ``udpin:HOST:PORT`` (IPv4 or host name).

    ``udpin`` accepts an empty host (all interfaces) and port 0 (any free port). Raises
    :class:`~smcpilot.errors.EndpointError` naming the URL for anything else.
    """
    if not isinstance(url, str):
        raise EndpointError(f"endpoint must be a string like {_ENDPOINT_FORMS}, got {url!r}")
    text = url.strip()
    scheme, colon, rest = text.partition(":")
    mode = _SCHEMES.get(scheme.lower())
    if not colon or mode is None:
        raise EndpointError(f"endpoint {url!r}: unknown form; expected {_ENDPOINT_FORMS}")
    if rest.startswith("//"):
        raise EndpointError(f"endpoint {url!r}: write {scheme}:HOST:PORT without '//'")
    host, colon, port_text = rest.rpartition(":")
    if not colon:
        raise EndpointError(f"endpoint {url!r}: missing ':PORT'; expected {_ENDPOINT_FORMS}")
    if ":" in host or host.startswith("["):
        raise EndpointError(f"endpoint {url!r}: IPv6 addresses are not supported; use an IPv4 address or host name")
    if not port_text.isdigit() or not port_text.isascii():
        raise EndpointError(f"endpoint {url!r}: port {port_text!r} is not a number")
    port = int(port_text)
    lowest_port = 0 if mode == "in" else 1
    if not lowest_port <= port <= 65535:
        raise EndpointError(f"endpoint {url!r}: port {port} is outside {lowest_port}..65535")
    if not host:
        if mode == "out":
            raise EndpointError(f"endpoint {url!r}: an outgoing endpoint needs a host to send to")
        host = "0.0.0.0"
    elif not _HOST_RE.match(host) or len(host) > 253:
        raise EndpointError(f"endpoint {url!r}: {host!r} is not a valid IPv4 address or host name")
    return Endpoint(mode=mode, host=host, port=port)


def udp_kernel_drops(sock: socket.socket) -> int | None:
    """The kernel's count of datagrams dropped for ``sock`` (Linux: the ``drops`` column of
    ``/proc/net/udp`` on the socket's inode); None where it cannot be read."""
    try:
        inode = str(os.fstat(sock.fileno()).st_ino)
        with open("/proc/net/udp", encoding="ascii") as f:
            next(f)
            for line in f:
                cols = line.split()
                if len(cols) >= 13 and cols[9] == inode:
                    return int(cols[12])
    except (OSError, ValueError, StopIteration):
        return None
    return None


@dataclass(slots=True)
class LinkCounters:
    """Traffic statistics of one link (mutable; read them, or ``reset()``).

    ``rx_unsigned``, ``rx_bad_signature``, ``rx_old_timestamp`` and ``rx_stream_window`` count
    good packets dropped by signing (:meth:`smcpilot.signing.Signing.check`).
    ``rx_bad`` counts runs of bytes that are not a good packet (garbage, a truncated packet, a
    bad CRC, bad header flags): a whole garbage datagram counts once, and a good packet ends a
    run. ``rx_unknown`` counts well-framed packets whose id the dialect does not know (their CRC
    cannot be checked). ``rx_foreign_system`` counts good packets dropped because their source
    system is not ``accept_system``. ``tx_messages`` counts messages encoded (each took a
    sequence number), ``tx_datagrams`` datagrams the OS accepted, ``tx_errors`` failed sends
    (unreachable peer, full buffer, ...), including ICMP refusals reported on a later receive.
    """

    rx_datagrams: int = 0
    rx_messages: int = 0
    rx_bad: int = 0
    rx_unknown: int = 0
    rx_foreign_system: int = 0
    tx_messages: int = 0
    tx_datagrams: int = 0
    tx_errors: int = 0
    #: errno of the most recent failed send, 0 if none.
    last_tx_errno: int = 0
    #: datagrams from a new address not remembered as a peer because ``max_peers`` were known
    #: (their messages are still returned by ``recv``), or peers forgotten to make room.
    peers_rejected: int = 0
    rx_unsigned: int = 0
    rx_bad_signature: int = 0
    rx_old_timestamp: int = 0
    rx_stream_window: int = 0

    @property
    def rx_rejected(self) -> int:
        """Every packet received and not returned: bad bytes, unknown ids, foreign systems, signing."""
        return (
            self.rx_bad + self.rx_unknown + self.rx_foreign_system + self.rx_unsigned + self.rx_bad_signature
            + self.rx_old_timestamp + self.rx_stream_window
        )  # fmt: skip

    @property
    def rx_signing_rejected(self) -> int:
        """Packets dropped by signing (unsigned, bad signature, old or out-of-window timestamp)."""
        return self.rx_unsigned + self.rx_bad_signature + self.rx_old_timestamp + self.rx_stream_window

    def as_dict(self) -> dict[str, int]:
        """A plain-dict snapshot."""
        return asdict(self)

    def reset(self) -> None:
        """Set every counter back to zero."""
        for name in self.__slots__:  # type: ignore[attr-defined]
            setattr(self, name, 0)


class PacketSink:
    """The file pymavlink writes packed messages to, collecting them for one send (a stream link:
    PX4's simulator API over TCP, both sides)."""

    def __init__(self) -> None:
        self.parts: list[bytes] = []

    def write(self, data: bytes) -> None:
        self.parts.append(bytes(data))

    def take(self) -> bytes:
        """Everything written since the last take, joined."""
        data = b"".join(self.parts)
        self.parts.clear()
        return data


class _LinkWriter:
    """File-like shim so ``link.mav.<message>_send(...)`` sends through the link."""

    __slots__ = ("_link",)

    def __init__(self, link: MavlinkUdp) -> None:
        self._link = link

    def write(self, packet: bytes) -> None:
        self._link._send_encoded(packet)


def _wall_clock_us() -> int:
    return time.time_ns() // 1000


class MavlinkUdp:
    """A MAVLink 2 link over one UDP socket; see the module docstring. Use as a context manager."""

    def __init__(
        self,
        endpoint_or_url: Endpoint | str,
        *,
        source_system: int,
        source_component: int,
        accept_system: int | None = None,
        tlog: TlogWriter | None = None,
        clock_us: Callable[[], int] | None = None,
        peer_timeout_s: float = DEFAULT_PEER_TIMEOUT_S,
        max_peers: int = DEFAULT_MAX_PEERS,
        max_datagram_bytes: int = DEFAULT_MAX_DATAGRAM_BYTES,
        fast_codec: bool = True,
        monotonic_s: Callable[[], float] = time.monotonic,
        bind_port: int = 0,
        signing: Signing | None = None,
        link_id: int = 0,
        accept_unsigned: frozenset[int] | None = None,
        impairment: LinkImpairment | None = None,
        impair_seed: int = 0,
    ) -> None:
        """Open the socket.

        ``bind_port``: for an ``out`` endpoint, the local port to send from (0: any free port), so
        that others can write to a known port of ours as well (the FC's second ground port).

        ``source_system``/``source_component`` go into every packet we send; with
        ``accept_system`` set, packets from any other system id are dropped. ``tlog`` (owned by
        the caller, not closed here) records traffic stamped with ``clock_us()`` (default: wall
        clock, µs since the epoch). ``fast_codec=False`` forces pymavlink for every message.
        ``monotonic_s`` is the real-time clock for peer expiry (injectable for tests).
        ``signing`` (shared by the process's links) signs and checks packets while its key is
        set, this link's packets carrying ``link_id``; ``accept_unsigned`` replaces the signing's
        list of messages accepted unsigned on this link (e.g. a trusted link that also takes
        ``SETUP_SIGNING``).
        ``impairment`` (:mod:`smcpilot.impair`) degrades what this link sends and what it receives,
        each direction with its own stream seeded from ``impair_seed``, timed by ``monotonic_s``.
        """
        endpoint = parse_endpoint(endpoint_or_url) if isinstance(endpoint_or_url, str) else endpoint_or_url
        if not isinstance(endpoint, Endpoint):
            raise EndpointError(f"endpoint must be an Endpoint or a URL string, got {endpoint_or_url!r}")
        for name, value, lowest in (
            ("source_system", source_system, 0),
            ("source_component", source_component, 0),
            ("accept_system", 0 if accept_system is None else accept_system, 0),
        ):
            if not isinstance(value, int) or not lowest <= value <= 255:
                raise LinkError(f"{name} must be an integer in 0..255, got {value!r}")
        if not peer_timeout_s > 0:
            raise LinkError(f"peer_timeout_s must be > 0, got {peer_timeout_s!r}")
        if not isinstance(link_id, int) or not 0 <= link_id <= 255:
            raise LinkError(f"link_id must be an integer in 0..255, got {link_id!r}")
        if max_peers < 1:
            raise LinkError(f"max_peers must be >= 1, got {max_peers!r}")
        if max_datagram_bytes < 300:
            raise LinkError(f"max_datagram_bytes must be >= 300 (one MAVLink packet), got {max_datagram_bytes!r}")

        self._endpoint = endpoint
        self._accept_system = accept_system
        self._tlog = tlog
        self._clock_us = clock_us if clock_us is not None else _wall_clock_us
        self._peer_timeout_s = float(peer_timeout_s)
        self._max_peers = max_peers
        self._max_datagram_bytes = max_datagram_bytes
        self._monotonic_s = monotonic_s
        self._packers = dict(fastcodec.PACKERS) if fast_codec else {}
        self._decoders = dict(fastcodec.DECODERS) if fast_codec else {}
        self.counters = LinkCounters()
        self._signing = signing
        self._link_id = link_id
        self._accept_unsigned = accept_unsigned
        #: addresses that sent signed packets or commands: a flood of new addresses never
        #: evicts them from the peer table (they still expire after ``peer_timeout_s`` of silence).
        self._pinned: set[Address] = set()
        self._rx_signed = False
        #: set once a send was refused by the peer's host (its port is closed: the peer process is
        #: gone); reported only after :meth:`report_peer_errors`.
        self.peer_refused = False
        active = impairment is not None and impairment.active
        self._tx_impair: Impairer[tuple[bytes, Address]] | None = Impairer(impairment, 2 * impair_seed + 1) if active else None  # type: ignore[arg-type]
        self._rx_impair: Impairer[tuple[bytes, Address]] | None = Impairer(impairment, 2 * impair_seed + 2) if active else None  # type: ignore[arg-type]

        self._mav = mavlink.MAVLink(_LinkWriter(self), srcSystem=source_system, srcComponent=source_component)
        self._decoder = mavlink.MAVLink(None)  # decode() only: stateless without signing
        self._decode = self._decoder.decode

        self._initial_destination: Address | None = None
        self._peer_seen_s: dict[Address, float] = {}
        self._destinations: tuple[Address, ...] = ()
        self._next_prune_s = math.inf
        #: where the next send_many(others_limit=...) starts among the peers not pinned.
        self._others_turn = 0
        self._closed = True

        self._bind_port = int(bind_port)
        sock = self._open_socket(endpoint)
        self._sock = sock
        self._fd = sock.fileno()
        self._local_address: Address = sock.getsockname()[:2]
        self._closed = False
        self._rebuild_destinations()

    def _open_socket(self, endpoint: Endpoint) -> socket.socket:
        try:
            infos = socket.getaddrinfo(endpoint.host, endpoint.port, socket.AF_INET, socket.SOCK_DGRAM)
        except OSError as exc:
            raise LinkError(f"endpoint {endpoint.url}: cannot resolve host {endpoint.host!r}: {exc}") from exc
        host, port = infos[0][4][:2]  # AF_INET: (host, port)
        address: Address = (str(host), int(port))
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            if endpoint.mode == "in":
                sock.bind(address)
            else:
                loopback = ipaddress.ip_address(address[0]).is_loopback
                sock.bind(("127.0.0.1" if loopback else "0.0.0.0", self._bind_port))
                self._initial_destination = address
            sock.setblocking(False)
        except OSError as exc:
            sock.close()
            raise LinkError(f"endpoint {endpoint.url}: cannot bind UDP socket: {exc.strerror or exc}") from exc
        return sock

    # ------------------------------------------------------------------ properties

    @property
    def endpoint(self) -> Endpoint:
        """The endpoint this link was opened on."""
        return self._endpoint

    @property
    def local_address(self) -> Address:
        """``(host, port)`` our socket is bound to."""
        return self._local_address

    @property
    def mav(self) -> mavlink.MAVLink:
        """pymavlink encoder: ``link.mav.attitude_encode(...)`` builds a message for :meth:`send`;
        ``link.mav.heartbeat_send(...)`` sends at once to every peer. Its ``seq`` is the link's
        sequence counter."""
        return self._mav

    @property
    def peers(self) -> tuple[Address, ...]:
        """Addresses :meth:`send` currently reaches: the initial destination, then every address
        that has written good packets to us within ``peer_timeout_s``."""
        if self._next_prune_s <= self._monotonic_s():
            self._prune_peers()
        return self._destinations

    @property
    def signing(self) -> Signing | None:
        """The signing state this link uses (None: never signs)."""
        return self._signing

    @property
    def link_id(self) -> int:
        """The link id this link's signed packets carry."""
        return self._link_id

    @property
    def closed(self) -> bool:
        """True once :meth:`close` has run."""
        return self._closed

    def kernel_drops(self) -> int | None:
        """Datagrams the kernel dropped for this socket because its receive buffer was full (a
        flood faster than we take datagrams off it): Linux's per-socket count in ``/proc/net/udp``;
        None where there is none (another OS, a closed socket)."""
        return udp_kernel_drops(self._sock)

    def fileno(self) -> int:
        """The socket's file descriptor, for the caller's own ``select``."""
        return self._fd

    # ------------------------------------------------------------------ sending

    def send(self, msg: mavlink.MAVLink_message) -> None:
        """Encode ``msg`` (next sequence number) and send it to every peer; log it once."""
        packet = self._encode(msg)
        self._send_datagram_to_peers(packet)  # the peer first: logging is off the critical path
        if self._tlog is not None:
            self._tlog.write(self._clock_us(), self._log_copy(packet))

    def send_many(self, msgs: Iterable[mavlink.MAVLink_message], *, others_limit: int | None = None) -> int:
        """Encode several messages and send them in as few datagrams as fit
        ``max_datagram_bytes`` (normally one) to every peer; all logged with one timestamp.

        ``others_limit``: the initial destination and the pinned peers get them always; of the
        other peers (learnt from their traffic alone) at most this many, taken in turn from one
        call to the next, so a table full of strangers costs a bounded number of sends (None:
        every peer). Returns how many peers were left out."""
        encode = self._encode
        packets = [encode(msg) for msg in msgs]
        if not packets:
            return 0
        skipped = 0
        if others_limit is None:
            for datagram in self._datagrams(packets):
                self._send_datagram_to_peers(datagram)
        else:
            dests, skipped = self._limited_destinations(others_limit)
            send = self._send_datagram
            for datagram in self._datagrams(packets):
                for addr in dests:
                    send(datagram, addr)
        if self._tlog is not None:
            self._tlog.write_many(self._clock_us(), packets)
        return skipped

    def _limited_destinations(self, others_limit: int) -> tuple[list[Address], int]:
        """The initial destination, the pinned peers, and ``others_limit`` of the other peers from
        where the last call stopped; and how many others were left out."""
        dests = self.peers
        initial, pinned = self._initial_destination, self._pinned
        out = [a for a in dests if a == initial or a in pinned]
        others = [a for a in dests if a != initial and a not in pinned]
        n = len(others)
        if n <= others_limit:
            return out + others, 0
        start = self._others_turn % n
        self._others_turn = start + others_limit
        out.extend(others[(start + k) % n] for k in range(others_limit))
        return out, n - others_limit

    def take_seq(self) -> int:
        """The next sequence number, consumed: for packets encoded by :mod:`smcpilot.fastcodec`
        directly (no message object) and sent with :meth:`send_packets`."""
        mav = self._mav
        seq = mav.seq
        mav.seq = (seq + 1) & 0xFF
        self.counters.tx_messages += 1
        return seq

    @property
    def source(self) -> tuple[int, int]:
        """(source system, source component) this link sends as."""
        return self._mav.srcSystem, self._mav.srcComponent

    def send_packets(self, packets: Sequence[bytes]) -> None:
        """Send already-encoded packets (numbered with :meth:`take_seq`) to every peer in as few
        datagrams as fit, then log them: the hot-path variant of :meth:`send_many`."""
        if self._closed:
            raise LinkClosedError(f"link {self._endpoint.url} is closed")
        signing = self._signing
        if signing is not None and signing.enabled:
            link_id = self._link_id
            packets = [signing.sign(p, link_id) for p in packets]
        for datagram in self._datagrams(packets) if len(packets) > 1 else packets:
            self._send_datagram_to_peers(datagram)
        if self._tlog is not None:
            self._tlog.write_many(self._clock_us(), packets)

    def send_packets_to(self, packets: Sequence[bytes], addr: Address) -> None:
        """:meth:`send_packets` to ``addr`` only (e.g. the one simulator a link answers)."""
        if self._closed:
            raise LinkClosedError(f"link {self._endpoint.url} is closed")
        signing = self._signing
        if signing is not None and signing.enabled:
            link_id = self._link_id
            packets = [signing.sign(p, link_id) for p in packets]
        for datagram in self._datagrams(packets) if len(packets) > 1 else packets:
            self._send_datagram(datagram, addr)
        if self._tlog is not None:
            self._tlog.write_many(self._clock_us(), packets)

    def send_many_to(self, msgs: Iterable[mavlink.MAVLink_message], addr: Address) -> None:
        """Like :meth:`send_many`, to ``addr`` only (e.g. a parameter list to the station that asked)."""
        encode = self._encode
        packets = [encode(msg) for msg in msgs]
        if not packets:
            return
        if self._tlog is not None:
            self._tlog.write_many(self._clock_us(), packets)
        for datagram in self._datagrams(packets):
            self._send_datagram(datagram, addr)

    def send_to(self, msg: mavlink.MAVLink_message, addr: Address) -> None:
        """Encode ``msg`` and send it to ``addr`` only (e.g. a COMMAND_ACK to the requester)."""
        packet = self._encode(msg)
        if self._tlog is not None:
            self._tlog.write(self._clock_us(), self._log_copy(packet))
        self._send_datagram(packet, addr)

    def _encode(self, msg: mavlink.MAVLink_message) -> bytes:
        if self._closed:
            raise LinkClosedError(f"link {self._endpoint.url} is closed")
        mav = self._mav
        seq = mav.seq
        packer = self._packers.get(type(msg))
        if packer is not None and not mav.signing.sign_outgoing:
            packet = packer(msg, seq, mav.srcSystem, mav.srcComponent)
        else:
            packet = msg.pack(mav)
        mav.seq = (seq + 1) & 0xFF
        self.counters.tx_messages += 1
        signing = self._signing
        if signing is not None and signing.enabled:
            packet = signing.sign(packet, self._link_id)
        return packet

    @staticmethod
    def _log_copy(packet: bytes) -> bytes:
        """What the tlog gets of a packet: itself, or a SETUP_SIGNING with its key zeroed."""
        if len(packet) > 9 and packet[7] == _SETUP_SIGNING_LOW and packet[8] == 1 and packet[0] == _MAGIC_V2:
            return redact_setup_signing(packet)
        return packet

    def _send_encoded(self, packet: bytes) -> None:
        """Send a packet pymavlink's ``MAVLink.send`` has encoded (it advances ``seq`` itself)."""
        if self._closed:
            raise LinkClosedError(f"link {self._endpoint.url} is closed")
        self.counters.tx_messages += 1
        signing = self._signing
        if signing is not None and signing.enabled:
            packet = signing.sign(bytes(packet), self._link_id)
        if self._tlog is not None:
            self._tlog.write(self._clock_us(), self._log_copy(packet))
        self._send_datagram_to_peers(packet)

    def _datagrams(self, packets: Sequence[bytes]) -> list[bytes]:
        limit = self._max_datagram_bytes
        datagrams: list[bytes] = []
        batch: list[bytes] = []
        size = 0
        for packet in packets:
            if size + len(packet) > limit and batch:
                datagrams.append(b"".join(batch))
                batch, size = [], 0
            batch.append(packet)
            size += len(packet)
        datagrams.append(b"".join(batch))
        return datagrams

    def _send_datagram_to_peers(self, datagram: bytes) -> None:
        if self._next_prune_s <= self._monotonic_s():
            self._prune_peers()
        send = self._send_datagram if self._tx_impair is not None else self._sendto
        for addr in self._destinations:
            send(datagram, addr)

    def _send_datagram(self, datagram: bytes, addr: Address) -> None:
        impair = self._tx_impair
        if impair is not None:
            now_s = self._monotonic_s()
            impair.offer((datagram, addr), now_s)
            for held, to in impair.due(now_s):
                self._sendto(held, to)
            return
        self._sendto(datagram, addr)

    def _sendto(self, datagram: bytes, addr: Address) -> None:
        counters = self.counters
        try:
            self._sock.sendto(datagram, addr)
        except OSError as exc:
            counters.tx_errors += 1
            counters.last_tx_errno = exc.errno or 0
            if exc.errno == errno.ECONNREFUSED:
                self.peer_refused = True
        else:
            counters.tx_datagrams += 1

    # ------------------------------------------------------------------ receiving

    def recv(self, timeout_s: float, *, max_datagrams: int = 256) -> list[tuple[mavlink.MAVLink_message, Address]]:
        """Wait up to ``timeout_s`` for a datagram, then take every datagram already queued
        (at most ``max_datagrams``) without waiting; return their good messages with the sender's
        address, in arrival order. ``timeout_s <= 0`` only polls. Returns ``[]`` on timeout, or
        when everything that arrived was dropped."""
        if self._closed:
            raise LinkClosedError(f"link {self._endpoint.url} is closed")
        if self._rx_impair is not None:
            return self._recv_impaired(timeout_s, max_datagrams)
        received: list[tuple[mavlink.MAVLink_message, Address]] = []
        if timeout_s > 0 and not self._wait_readable(timeout_s):
            return received
        parse = self._parse_datagram
        now_s = -1.0
        for data, addr in self._take_datagrams(max_datagrams):
            self._rx_signed = False
            if parse(data, addr, received):
                if now_s < 0:
                    now_s = self._monotonic_s()
                self._heard(addr, now_s)
        return received

    def recv_datagrams(self, max_datagrams: int = 256) -> list[tuple[bytes, Address]]:
        """Take up to ``max_datagrams`` datagrams already queued (after the receiving impairment,
        if any), unparsed, without waiting: the cheap first half of :meth:`recv`, for an owner that
        decides what to parse and when (:meth:`parse` is the second half)."""
        if self._closed:
            raise LinkClosedError(f"link {self._endpoint.url} is closed")
        rx = self._rx_impair
        if rx is None:
            return self._take_datagrams(max_datagrams)
        self.pump()
        now_s = self._monotonic_s()
        for item in self._take_datagrams(max_datagrams):
            rx.offer(item, now_s)
        return list(rx.due(now_s))

    def parse(self, data: bytes, addr: Address) -> list[tuple[mavlink.MAVLink_message, Address]]:
        """The good messages of one datagram from :meth:`recv_datagrams` (counted, checked, logged
        and the peer noted exactly as :meth:`recv` does)."""
        received: list[tuple[mavlink.MAVLink_message, Address]] = []
        self._rx_signed = False
        if self._parse_datagram(data, addr, received):
            self._heard(addr, self._monotonic_s())
        return received

    def heard(self, addr: Address, messages: int) -> None:
        """A datagram from :meth:`recv_datagrams` that its owner decoded itself (an unsigned one:
        on a link with signing on, use :meth:`parse`): count its ``messages`` good messages and
        refresh the sender's peer entry, as :meth:`parse` would have."""
        self.counters.rx_messages += messages
        self._rx_signed = False
        self._heard(addr, self._monotonic_s())

    def _take_datagrams(self, max_datagrams: int) -> list[tuple[bytes, Address]]:
        """Up to ``max_datagrams`` datagrams off the socket (counted), without waiting."""
        recvfrom = self._sock.recvfrom
        counters = self.counters
        out: list[tuple[bytes, Address]] = []
        for _ in range(max_datagrams):
            try:
                data, addr = recvfrom(_RECV_BUFFER_BYTES)
            except BlockingIOError:
                break
            except (ConnectionRefusedError, ConnectionResetError) as exc:
                self._refused(exc)  # an ICMP "port unreachable" for an earlier send
                continue
            counters.rx_datagrams += 1
            out.append((data, addr))
        return out

    def _refused(self, exc: OSError) -> None:
        """A send of ours was refused by the peer's host (its port is closed), reported on receive."""
        counters = self.counters
        counters.tx_errors += 1
        counters.last_tx_errno = exc.errno or 0
        self.peer_refused = True

    def _heard(self, addr: Address, now_s: float) -> None:
        """A good datagram from ``addr``: refresh (or add) its peer entry; pin it if it was signed."""
        seen = self._peer_seen_s
        if addr in seen:
            seen[addr] = now_s
        else:
            self._add_peer(addr, now_s)
        if self._rx_signed and addr in seen:
            self._pinned.add(addr)

    # ------------------------------------------------------------------ impairment, dead peers

    def report_peer_errors(self) -> None:
        """Ask the OS to report ICMP errors for our sends (Linux ``IP_RECVERR``): a datagram sent
        to a closed port (the peer process died) then sets :attr:`peer_refused` on a later
        :meth:`recv`. A stopped (SIGSTOP) peer keeps its port open and is not reported. Meant for
        the simulator link, where the peer is one process on this machine."""
        try:
            self._sock.setsockopt(socket.IPPROTO_IP, _IP_RECVERR, 1)
        except OSError:  # pragma: no cover - not Linux: the watchdogs still notice
            pass

    def pump(self) -> None:
        """Release the impaired datagrams whose time has come (sending side; the receiving side is
        released by :meth:`recv`). Nothing to do without an impairment."""
        impair = self._tx_impair
        if impair is not None and impair.pending:
            for held, to in impair.due(self._monotonic_s()):
                self._sendto(held, to)

    def impair_wait_s(self) -> float:
        """Seconds until an impaired datagram is due, either direction (``inf``: none held), for
        the owner's ``select`` timeout."""
        tx, rx = self._tx_impair, self._rx_impair
        if tx is None or rx is None:
            return math.inf
        now_s = self._monotonic_s()
        return min(tx.wait_s(now_s), rx.wait_s(now_s))

    @property
    def impair_counters(self) -> dict[str, dict[str, int]] | None:
        """What the impairment did, per direction (None without one)."""
        tx, rx = self._tx_impair, self._rx_impair
        if tx is None or rx is None:
            return None
        return {"tx": tx.counters.as_dict(), "rx": rx.counters.as_dict()}

    def _recv_impaired(self, timeout_s: float, max_datagrams: int) -> list[tuple[mavlink.MAVLink_message, Address]]:
        """:meth:`recv` through the receiving impairer: datagrams are taken off the socket at once
        and parsed when the impairer releases them."""
        rx = self._rx_impair
        assert rx is not None
        mono = self._monotonic_s
        received: list[tuple[mavlink.MAVLink_message, Address]] = []
        end_s = mono() + max(0.0, timeout_s)
        while True:
            self.pump()
            now_s = mono()
            for item in self._take_datagrams(max_datagrams):
                rx.offer(item, now_s)
            for data, addr in rx.due(now_s):
                self._rx_signed = False
                if self._parse_datagram(data, addr, received):
                    self._heard(addr, now_s)
            remaining = end_s - now_s
            if received or remaining <= 0:
                return received
            self._wait_readable(min(remaining, self.impair_wait_s()))

    def _wait_readable(self, timeout_s: float) -> bool:
        if self._fd < _FD_SETSIZE:
            readable, _, _ = select.select((self._fd,), (), (), timeout_s)
            return bool(readable)
        poller = select.poll()  # pragma: no cover - only in processes with > 1024 open files
        poller.register(self._fd, select.POLLIN)
        return bool(poller.poll(math.ceil(timeout_s * 1000.0)))

    def _parse_datagram(
        self, data: bytes, addr: Address, received: list[tuple[mavlink.MAVLink_message, Address]]
    ) -> int:
        """Append the good messages of one datagram to ``received``; return how many."""
        counters = self.counters
        decoders = self._decoders
        accept_system = self._accept_system
        tlog = self._tlog
        signing = self._signing
        stamp_us = -1
        accepted = 0
        in_bad_run = False
        decoder: Callable[[bytes], mavlink.MAVLink_message | None] | None = None
        src_system = -1
        size = len(data)
        i = 0
        while i < size:
            magic = data[i]
            end = -1
            if magic == _MAGIC_V2:
                if i + 10 <= size:
                    flags = data[i + 2]
                    if not flags & ~1:  # only the "signed" incompat flag is defined
                        end = i + 12 + data[i + 1] + (_SIGNATURE_BYTES if flags else 0)
                        src_system = data[i + 5]
                        decoder = None if flags else decoders.get(data[i + 7] | (data[i + 8] << 8) | (data[i + 9] << 16))
            elif magic == _MAGIC_V1:
                if i + 6 <= size:
                    end = i + 8 + data[i + 1]
                    src_system = data[i + 3]
                    decoder = None
            if 0 <= end <= size:
                packet = data[i:end]
                if decoder is not None:
                    msg = decoder(packet)
                else:
                    try:
                        msg = self._decode(bytearray(packet))
                    except _DECODE_ERRORS:
                        msg = None
                    else:
                        if isinstance(msg, _UNKNOWN_MESSAGE):  # framed, but not in our dialect
                            counters.rx_unknown += 1
                            in_bad_run = False
                            i = end
                            continue
                if msg is not None:
                    in_bad_run = False
                    i = end
                    if accept_system is not None and src_system != accept_system:
                        counters.rx_foreign_system += 1
                        continue
                    if signing is not None and signing.enabled:
                        mid = packet[7] | packet[8] << 8 | packet[9] << 16 if magic == _MAGIC_V2 else packet[5]
                        verdict = signing.check(packet, mid, self._accept_unsigned)
                        if verdict != _SIGNING_OK:
                            name = _REJECT_COUNTERS[verdict]
                            setattr(counters, name, getattr(counters, name) + 1)
                            continue
                        if packet[2] & 1 and magic == _MAGIC_V2:
                            msg._signed = True
                            msg._link_id = packet[-13]
                            self._rx_signed = True
                    received.append((msg, addr))
                    accepted += 1
                    if tlog is not None:
                        if stamp_us < 0:
                            stamp_us = self._clock_us()
                        tlog.write(stamp_us, self._log_copy(packet))
                    continue
            # Not a good packet at i: count the run once and resynchronise on the next
            # start-of-frame byte after i.
            if not in_bad_run:
                counters.rx_bad += 1
                in_bad_run = True
            found = _START_OF_FRAME.search(data, i + 1)
            i = found.start() if found is not None else size
        counters.rx_messages += accepted
        return accepted

    # ------------------------------------------------------------------ peers

    def pin_peer(self, addr: Address) -> None:
        """Keep ``addr`` (a station that sent a command) in the peer table: new addresses never
        evict it, only its own silence for ``peer_timeout_s`` does."""
        if addr in self._peer_seen_s:
            self._pinned.add(addr)
        else:
            self._add_peer(addr, self._monotonic_s(), pin=True)

    @property
    def pinned_peers(self) -> frozenset[Address]:
        """The peers kept against floods (signed packets or commands came from them)."""
        return frozenset(self._pinned)

    def _add_peer(self, addr: Address, now_s: float, *, pin: bool = False) -> None:
        seen = self._peer_seen_s
        if len(seen) >= self._max_peers:
            if self._next_prune_s <= now_s:  # (a flood calls this per datagram: prune only when due)
                self._prune_peers()
            if len(seen) >= self._max_peers:
                # Full. Pinned peers (signed packets, commands) are never evicted by a newcomer;
                # of the others, one silent for PEER_QUIET_S (it missed its 1 Hz heartbeat: gone
                # or going) makes room, so short-lived clients cannot lock new ones out. A peer
                # that keeps writing keeps its place: a flood of new addresses is not remembered
                # (its messages are still returned) and cannot evict the stations already known.
                pinned = self._pinned
                candidates = [a for a in seen if a not in pinned]
                victim: Address | None = None
                if candidates:
                    oldest = min(candidates, key=seen.__getitem__)
                    if pin or now_s - seen[oldest] >= PEER_QUIET_S:
                        victim = oldest
                self.counters.peers_rejected += 1
                if victim is None:
                    return
                del seen[victim]
        seen[addr] = now_s
        if pin:
            self._pinned.add(addr)
        self._next_prune_s = min(self._next_prune_s, now_s + self._peer_timeout_s)
        self._rebuild_destinations()

    def _prune_peers(self) -> None:
        seen = self._peer_seen_s
        now_s = self._monotonic_s()
        oldest_allowed_s = now_s - self._peer_timeout_s
        stale = [addr for addr, seen_s in seen.items() if seen_s < oldest_allowed_s]
        for addr in stale:
            del seen[addr]
            self._pinned.discard(addr)
        self._next_prune_s = min(seen.values()) + self._peer_timeout_s if seen else math.inf
        if stale:
            self._rebuild_destinations()

    def _rebuild_destinations(self) -> None:
        initial = self._initial_destination
        learnt = tuple(addr for addr in self._peer_seen_s if addr != initial)
        self._destinations = ((initial,) if initial is not None else ()) + learnt

    # ------------------------------------------------------------------ lifetime

    def close(self) -> None:
        """Close the socket (the tlog stays open: it belongs to the caller). Idempotent."""
        if self._closed:
            return
        self._closed = True
        self._sock.close()

    def __enter__(self) -> MavlinkUdp:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.close()

    def __repr__(self) -> str:
        state = "closed" if self._closed else f"local={self._local_address[0]}:{self._local_address[1]}"
        return f"MavlinkUdp({self._endpoint.url}, {state})"
