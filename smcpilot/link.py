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

The parts. :class:`MavlinkUdp` is a facade composing one part of each kind from
:mod:`smcpilot.udplink`, all sharing the link's :class:`LinkCounters`:

- :class:`~smcpilot.udplink.udpsocket.UdpSocket` (``udplink/udpsocket.py``): the socket opened for
  an :class:`Endpoint` (``udplink/endpoint.py``), counted sends and receives, refusals;
- :class:`~smcpilot.udplink.peers.PeerTable` (``udplink/peers.py``): who "every peer" is;
- :class:`~smcpilot.udplink.encoder.Encoder` (``udplink/encoder.py``): sequence numbers,
  encoding, signing;
- :class:`~smcpilot.udplink.parser.DatagramParser` (``udplink/parser.py``): a datagram to its
  good, checked messages;
- :class:`~smcpilot.udplink.impairment.LinkImpairer` (``udplink/impairment.py``, only with an
  active impairment): a bad network in each direction;
- :class:`~smcpilot.udplink.logtap.LogTap` (``udplink/logtap.py``, only with a tlog): the tlog's
  copy of the traffic.

One send path. Every send (:meth:`~MavlinkUdp.send`, :meth:`~MavlinkUdp.send_many` limited or
not, :meth:`~MavlinkUdp.send_to`, :meth:`~MavlinkUdp.send_many_to`,
:meth:`~MavlinkUdp.send_packets`, :meth:`~MavlinkUdp.send_packets_to` and ``link.mav.*_send``)
encodes what it has into packets, if they are messages, picks its destinations, and hands both to
``MavlinkUdp._transmit``: the one function that signs the packets, packs them into datagrams of
at most ``max_datagram_bytes``, sends each datagram to each destination (through the impairment,
if any) and copies the packets to the tlog. Signing, packing, the impairment of what is sent and
the tlog's copy of it are applied there and nowhere else. (``tx_messages`` counts sequence numbers
as the encoder hands them out; ``tx_datagrams`` and ``tx_errors`` are counted by the socket, which
also sends the held datagrams the impairer releases later, on :meth:`~MavlinkUdp.pump`.)

A link is not thread-safe: one thread owns it.
"""

from __future__ import annotations

import math
import socket
import time
from collections.abc import Callable, Iterable, Sequence
from types import TracebackType

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from smcpilot.errors import EndpointError, LinkClosedError, LinkError
from smcpilot.impair import LinkImpairment
from smcpilot.signing import Signing
from smcpilot.tlog import TlogWriter
from smcpilot.udplink.counters import LinkCounters
from smcpilot.udplink.encoder import Encoder, PacketSink, PacketWriter
from smcpilot.udplink.endpoint import Address, Endpoint, parse_endpoint
from smcpilot.udplink.impairment import LinkImpairer
from smcpilot.udplink.logtap import LogTap, log_copy, wall_clock_us
from smcpilot.udplink.parser import DatagramParser, Received
from smcpilot.udplink.peers import DEFAULT_MAX_PEERS, DEFAULT_PEER_TIMEOUT_S, PEER_QUIET_S, PeerTable
from smcpilot.udplink.udpsocket import UdpSocket, udp_kernel_drops

__all__ = [
    "Address",
    "Endpoint",
    "LinkCounters",
    "MavlinkUdp",
    "PacketSink",
    "parse_endpoint",
    "DEFAULT_PEER_TIMEOUT_S",
    "DEFAULT_MAX_DATAGRAM_BYTES",
    "DEFAULT_MAX_PEERS",
    "PEER_QUIET_S",
    "udp_kernel_drops",
]

#: :meth:`MavlinkUdp.send_many` starts a new datagram before one would exceed this size (bytes);
#: 1400 stays under an Ethernet/Wi-Fi MTU, so datagrams are not fragmented on the way to a GCS.
DEFAULT_MAX_DATAGRAM_BYTES = 1400

# Names the link's parts now hold, kept here for code that reached for them.
_LinkWriter = PacketWriter
_wall_clock_us = wall_clock_us


def pack_datagrams(packets: Sequence[bytes], max_bytes: int) -> list[bytes]:
    """``packets`` joined, in order, into as few datagrams of at most ``max_bytes`` as fit (a
    packet bigger than that goes alone); ``[b""]`` for no packets."""
    datagrams: list[bytes] = []
    batch: list[bytes] = []
    size = 0
    for packet in packets:
        if size + len(packet) > max_bytes and batch:
            datagrams.append(b"".join(batch))
            batch, size = [], 0
        batch.append(packet)
        size += len(packet)
    datagrams.append(b"".join(batch))
    return datagrams


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
        ``monotonic_s`` is the real-time clock (s) for peer expiry (injectable for tests).
        ``peer_timeout_s``: a peer silent this long (s) is no longer sent to. ``max_datagram_bytes``:
        the largest datagram :meth:`send_many` packs.
        ``signing`` (shared by the process's links) signs and checks packets while its key is
        set, this link's packets carrying ``link_id``; ``accept_unsigned`` replaces the signing's
        list of messages accepted unsigned on this link (e.g. a trusted link that also takes
        ``SETUP_SIGNING``).
        ``impairment`` (:mod:`smcpilot.impair`) degrades what this link sends and what it receives,
        each direction with its own stream seeded from ``impair_seed``, timed by ``monotonic_s``.
        Raises :class:`~smcpilot.errors.EndpointError` for a bad endpoint and
        :class:`~smcpilot.errors.LinkError` for a bad argument or a socket that cannot be opened.
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

        self._closed = True
        self._endpoint = endpoint
        self._max_datagram_bytes = max_datagram_bytes
        self._monotonic_s = monotonic_s
        self._signing = signing
        self.counters = counters = LinkCounters()

        # The parts (see the module docstring), all counting into ``counters``.
        self._encoder = Encoder(
            PacketWriter(self._send_encoded), source_system=source_system, source_component=source_component,
            counters=counters, fast_codec=fast_codec, signing=signing, link_id=link_id,
        )  # fmt: skip
        self._tap = LogTap(tlog, clock_us if clock_us is not None else wall_clock_us) if tlog is not None else None
        self._parser = DatagramParser(
            counters, accept_system=accept_system, signing=signing, accept_unsigned=accept_unsigned, tap=self._tap,
            fast_codec=fast_codec,
        )  # fmt: skip
        self._udp = udp = UdpSocket(endpoint, counters, bind_port=bind_port)
        self._peers = PeerTable(
            udp.initial_destination, timeout_s=peer_timeout_s, max_peers=max_peers, monotonic_s=monotonic_s,
            counters=counters,
        )  # fmt: skip
        self._impair = LinkImpairer.for_link(impairment, impair_seed, monotonic_s=monotonic_s, sendto=udp.sendto)
        # Bound once, for the send path: a message's encoding, and a datagram's way out (straight
        # to the socket, or through the impairer).
        self._encode = self._encoder.encode
        self._send_datagram = udp.sendto if self._impair is None else self._impair.send
        #: the raw socket (for code that sets socket options on it).
        self._sock: socket.socket = udp.sock
        #: the parser's :meth:`~smcpilot.udplink.parser.DatagramParser.parse_into`.
        self._parse_datagram = self._parser.parse_into
        self._closed = False

    # ------------------------------------------------------------------ properties

    @property
    def endpoint(self) -> Endpoint:
        """The endpoint this link was opened on."""
        return self._endpoint

    @property
    def local_address(self) -> Address:
        """``(host, port)`` our socket is bound to."""
        return self._udp.local_address

    @property
    def mav(self) -> mavlink.MAVLink:
        """pymavlink encoder: ``link.mav.attitude_encode(...)`` builds a message for :meth:`send`;
        ``link.mav.heartbeat_send(...)`` sends at once to every peer. Its ``seq`` is the link's
        sequence counter."""
        return self._encoder.mav

    @property
    def peers(self) -> tuple[Address, ...]:
        """Addresses :meth:`send` currently reaches: the initial destination, then every address
        that has written good packets to us within ``peer_timeout_s``."""
        return self._peers.current()

    @property
    def signing(self) -> Signing | None:
        """The signing state this link uses (None: never signs)."""
        return self._signing

    @property
    def link_id(self) -> int:
        """The link id this link's signed packets carry."""
        return self._encoder.link_id

    @property
    def source(self) -> tuple[int, int]:
        """(source system, source component) this link sends as."""
        return self._encoder.source

    @property
    def closed(self) -> bool:
        """True once :meth:`close` has run."""
        return self._closed

    @property
    def peer_refused(self) -> bool:
        """True once a send was refused by the peer's host (its port is closed: the peer process
        is gone); reported on receive only after :meth:`report_peer_errors`."""
        return self._udp.peer_refused

    @peer_refused.setter
    def peer_refused(self, value: bool) -> None:
        self._udp.peer_refused = value

    def kernel_drops(self) -> int | None:
        """Datagrams the kernel dropped for this socket because its receive buffer was full (a
        flood faster than we take datagrams off it): Linux's per-socket count in ``/proc/net/udp``;
        None where there is none (another OS, a closed socket)."""
        return self._udp.kernel_drops()

    def fileno(self) -> int:
        """The socket's file descriptor, for the caller's own ``select``."""
        return self._udp.fd

    # ------------------------------------------------------------------ sending

    def send(self, msg: mavlink.MAVLink_message) -> None:
        """Encode ``msg`` (next sequence number) and send it to every peer; log it once."""
        if self._closed:
            raise self._closed_error()
        self._transmit((self._encode(msg),))

    def send_many(self, msgs: Iterable[mavlink.MAVLink_message], *, others_limit: int | None = None) -> int:
        """Encode several messages and send them in as few datagrams as fit
        ``max_datagram_bytes`` (normally one) to every peer; all logged with one timestamp.

        ``others_limit``: the initial destination and the pinned peers get them always; of the
        other peers (learnt from their traffic alone) at most this many, taken in turn from one
        call to the next, so a table full of strangers costs a bounded number of sends (None:
        every peer). Returns how many peers were left out."""
        packets = self._encode_all(msgs)
        if not packets:
            return 0
        if others_limit is None:
            self._transmit(packets)
            return 0
        dests, skipped = self._peers.limited(others_limit)
        self._transmit(packets, dests)
        return skipped

    def send_to(self, msg: mavlink.MAVLink_message, addr: Address) -> None:
        """Encode ``msg`` and send it to ``addr`` only (e.g. a COMMAND_ACK to the requester)."""
        if self._closed:
            raise self._closed_error()
        self._transmit((self._encode(msg),), (addr,))

    def send_many_to(self, msgs: Iterable[mavlink.MAVLink_message], addr: Address) -> None:
        """Like :meth:`send_many`, to ``addr`` only (e.g. a parameter list to the station that asked)."""
        packets = self._encode_all(msgs)
        if packets:
            self._transmit(packets, (addr,))

    def send_packets(self, packets: Sequence[bytes]) -> None:
        """Send already-encoded packets (numbered with :meth:`take_seq`) to every peer in as few
        datagrams as fit, then log them: the hot-path variant of :meth:`send_many`."""
        if self._closed:
            raise self._closed_error()
        self._transmit(packets)

    def send_packets_to(self, packets: Sequence[bytes], addr: Address) -> None:
        """:meth:`send_packets` to ``addr`` only (e.g. the one simulator a link answers)."""
        if self._closed:
            raise self._closed_error()
        self._transmit(packets, (addr,))

    def send_datagram_to(self, packet: bytes, addr: Address) -> None:
        """:meth:`send_packets_to` of one packet (numbered with :meth:`take_seq`), without the
        general path where nothing of it applies (a link that signs nothing and logs nothing)."""
        if self._closed:
            raise self._closed_error()
        signing = self._signing
        if self._tap is not None or (signing is not None and signing.enabled):
            self._transmit((packet,), (addr,))
        else:
            self._send_datagram(packet, addr)

    def peek_seq(self) -> int:
        """The sequence number :meth:`take_seq` gives next (not consumed)."""
        return int(self._encoder.mav.seq)

    @property
    def logged(self) -> bool:
        """What this link sends and receives is copied to a ``.tlog``."""
        return self._tap is not None

    @property
    def max_datagram_bytes(self) -> int:
        """The largest datagram :meth:`send_packets` makes of several packets."""
        return self._max_datagram_bytes

    def take_seq(self) -> int:
        """The next sequence number, consumed: for packets encoded by :mod:`smcpilot.fastcodec`
        directly (no message object) and sent with :meth:`send_packets`."""
        return self._encoder.take_seq()

    def _send_encoded(self, packet: bytes) -> None:
        """Send a packet pymavlink's ``MAVLink.send`` has encoded (it advances ``seq`` itself)."""
        if self._closed:
            raise self._closed_error()
        self.counters.tx_messages += 1
        self._transmit((bytes(packet),))

    def _encode_all(self, msgs: Iterable[mavlink.MAVLink_message]) -> list[bytes]:
        """Each message encoded (a sequence number each), unsigned; raises on a closed link."""
        encode = self._encode
        packets = []
        for msg in msgs:
            if self._closed:
                raise self._closed_error()
            packets.append(encode(msg))
        return packets

    def _transmit(self, packets: Sequence[bytes], dests: Sequence[Address] | None = None) -> None:
        """THE send path: sign ``packets`` (while signing has a key), pack them into datagrams of
        at most ``max_datagram_bytes`` (a single packet is its own datagram), send every datagram
        to every address of ``dests`` (None: every current peer; through the impairment if any;
        counted by the socket), then copy the packets to the tlog with one timestamp."""
        signing = self._signing
        if signing is not None and signing.enabled:
            packets = self._encoder.sign(packets)
        if dests is None:
            peers = self._peers
            if peers.next_prune_s <= self._monotonic_s():
                peers.prune()
            dests = peers.destinations
        send = self._send_datagram
        if len(packets) == 1:
            datagram = packets[0]
            for addr in dests:
                send(datagram, addr)
        elif packets:
            for datagram in pack_datagrams(packets, self._max_datagram_bytes):
                for addr in dests:
                    send(datagram, addr)
        tap = self._tap
        if tap is not None and packets:
            tap.write(packets)

    #: what the tlog gets of a packet (the log tap's :func:`~smcpilot.udplink.logtap.log_copy`).
    _log_copy = staticmethod(log_copy)

    def _closed_error(self) -> LinkClosedError:
        return LinkClosedError(f"link {self._endpoint.url} is closed")

    # ------------------------------------------------------------------ receiving

    def recv(self, timeout_s: float, *, max_datagrams: int = 256) -> Received:
        """Wait up to ``timeout_s`` seconds for a datagram, then take every datagram already queued
        (at most ``max_datagrams``) without waiting; return their good messages with the sender's
        address, in arrival order. ``timeout_s <= 0`` only polls. Returns ``[]`` on timeout, or
        when everything that arrived was dropped."""
        if self._closed:
            raise self._closed_error()
        if self._impair is not None:
            return self._recv_impaired(timeout_s, max_datagrams)
        udp = self._udp
        received: Received = []
        if timeout_s > 0 and not udp.wait_readable(timeout_s):
            return received
        parser = self._parser
        parse = parser.parse_into
        heard = self._peers.heard
        now_s = -1.0
        for data, addr in udp.take(max_datagrams):
            if parse(data, addr, received):
                if now_s < 0:
                    now_s = self._monotonic_s()
                heard(addr, now_s, parser.signed)
        return received

    def recv_datagrams(self, max_datagrams: int = 256) -> list[tuple[bytes, Address]]:
        """Take up to ``max_datagrams`` datagrams already queued (after the receiving impairment,
        if any), unparsed, without waiting: the cheap first half of :meth:`recv`, for an owner that
        decides what to parse and when (:meth:`parse` is the second half)."""
        if self._closed:
            raise self._closed_error()
        impair = self._impair
        if impair is None:
            return self._udp.take(max_datagrams)
        impair.pump()
        return impair.receive(self._udp.take(max_datagrams), self._monotonic_s())

    def parse(self, data: bytes, addr: Address) -> Received:
        """The good messages of one datagram from :meth:`recv_datagrams` (counted, checked, logged
        and the peer noted exactly as :meth:`recv` does)."""
        received: Received = []
        parser = self._parser
        if parser.parse_into(data, addr, received):
            self._peers.heard(addr, self._monotonic_s(), parser.signed)
        return received

    def heard(self, addr: Address, messages: int) -> None:
        """A datagram from :meth:`recv_datagrams` that its owner decoded itself (an unsigned one:
        on a link with signing on, use :meth:`parse`): count its ``messages`` good messages and
        refresh the sender's peer entry, as :meth:`parse` would have."""
        self.counters.rx_messages += messages
        self._peers.heard(addr, self._monotonic_s())

    def _recv_impaired(self, timeout_s: float, max_datagrams: int) -> Received:
        """:meth:`recv` through the receiving impairer: datagrams are taken off the socket at once
        and parsed when the impairer releases them."""
        impair = self._impair
        assert impair is not None
        udp, parser, peers = self._udp, self._parser, self._peers
        mono = self._monotonic_s
        received: Received = []
        end_s = mono() + max(0.0, timeout_s)
        while True:
            impair.pump()
            now_s = mono()
            for data, addr in impair.receive(udp.take(max_datagrams), now_s):
                if parser.parse_into(data, addr, received):
                    peers.heard(addr, now_s, parser.signed)
            remaining = end_s - now_s
            if received or remaining <= 0:
                return received
            udp.wait_readable(min(remaining, impair.wait_s()))

    # ------------------------------------------------------------------ impairment, dead peers

    def report_peer_errors(self) -> None:
        """Ask the OS to report ICMP errors for our sends (Linux ``IP_RECVERR``): a datagram sent
        to a closed port (the peer process died) then sets :attr:`peer_refused` on a later
        :meth:`recv`. A stopped (SIGSTOP) peer keeps its port open and is not reported. Meant for
        the simulator link, where the peer is one process on this machine."""
        self._udp.report_peer_errors()

    def pump(self) -> None:
        """Release the impaired datagrams whose time has come (sending side; the receiving side is
        released by :meth:`recv`). Nothing to do without an impairment."""
        if self._impair is not None:
            self._impair.pump()

    def impair_wait_s(self) -> float:
        """Seconds until an impaired datagram is due, either direction (``inf``: none held), for
        the owner's ``select`` timeout."""
        return math.inf if self._impair is None else self._impair.wait_s()

    @property
    def impair_counters(self) -> dict[str, dict[str, int]] | None:
        """What the impairment did, per direction (None without one)."""
        return None if self._impair is None else self._impair.counters

    # ------------------------------------------------------------------ peers

    def pin_peer(self, addr: Address) -> None:
        """Keep ``addr`` (a station that sent a command) in the peer table: new addresses never
        evict it, only its own silence for ``peer_timeout_s`` does."""
        self._peers.pin(addr)

    @property
    def pinned_peers(self) -> frozenset[Address]:
        """The peers kept against floods (signed packets or commands came from them)."""
        return frozenset(self._peers.pinned)

    # ------------------------------------------------------------------ lifetime

    def close(self) -> None:
        """Close the socket (the tlog stays open: it belongs to the caller). Idempotent."""
        if self._closed:
            return
        self._closed = True
        self._udp.close()

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
        state = "closed" if self._closed else "local={}:{}".format(*self._udp.local_address)
        return f"MavlinkUdp({self._endpoint.url}, {state})"
