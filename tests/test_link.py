"""MavlinkUdp and endpoint parsing, over real UDP sockets bound to 127.0.0.1 on ephemeral ports."""

from __future__ import annotations

import contextlib
import os
import socket
import sys
import time
from collections.abc import Iterator

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from smcpilot.errors import ConfigError, EndpointError, LinkClosedError, LinkError
from smcpilot.link import Endpoint, MavlinkUdp, parse_endpoint
from smcpilot.tlog import TlogWriter, read_tlog

LOOPBACK = "127.0.0.1"
#: Upper bound for waiting on a datagram that is already on its way over loopback.
ARRIVAL_TIMEOUT_S = 2.0


# ---------------------------------------------------------------------------------- helpers


@contextlib.contextmanager
def raw_socket() -> Iterator[socket.socket]:
    """A plain UDP socket on 127.0.0.1:ephemeral, with a receive timeout."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.bind((LOOPBACK, 0))
        sock.settimeout(ARRIVAL_TIMEOUT_S)
        yield sock
    finally:
        sock.close()


@contextlib.contextmanager
def listener(**kwargs: object) -> Iterator[MavlinkUdp]:
    """A ``udpin`` link on 127.0.0.1:ephemeral."""
    kwargs.setdefault("source_system", 1)
    kwargs.setdefault("source_component", 1)
    with MavlinkUdp(f"udpin:{LOOPBACK}:0", **kwargs) as link:  # type: ignore[arg-type]
        yield link


def url_of(link: MavlinkUdp) -> str:
    return f"udpout:{LOOPBACK}:{link.local_address[1]}"


def recv_messages(link: MavlinkUdp, count: int, timeout_s: float = ARRIVAL_TIMEOUT_S) -> list[tuple[object, tuple[str, int]]]:
    """Receive until ``count`` messages arrived or ``timeout_s`` passed (socket timeouts only)."""
    received: list[tuple[object, tuple[str, int]]] = []
    deadline_s = time.monotonic() + timeout_s
    while len(received) < count:
        remaining_s = deadline_s - time.monotonic()
        if remaining_s <= 0:
            break
        received += link.recv(remaining_s)
    return received


def encoder(system: int = 2, component: int = 1) -> mavlink.MAVLink:
    return mavlink.MAVLink(None, srcSystem=system, srcComponent=component)


def packet(mav: mavlink.MAVLink, msg: mavlink.MAVLink_message, **pack_kwargs: bool) -> bytes:
    data = msg.pack(mav, **pack_kwargs)
    mav.seq = (mav.seq + 1) & 0xFF
    return data


def heartbeat(mav: mavlink.MAVLink) -> mavlink.MAVLink_message:
    return mav.heartbeat_encode(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)


def attitude(mav: mavlink.MAVLink, t_ms: int = 1234) -> mavlink.MAVLink_message:
    return mav.attitude_encode(t_ms, 0.1, -0.2, 0.3, 0.01, -0.02, 0.03)


def parse_all(data: bytes) -> list[mavlink.MAVLink_message]:
    parser = mavlink.MAVLink(None)
    return parser.parse_buffer(data) or []


# ---------------------------------------------------------------------------------- endpoints


@pytest.mark.parametrize(
    ("url", "expected"),
    [
        ("udp:127.0.0.1:14550", Endpoint("out", "127.0.0.1", 14550)),
        ("udpout:10.0.0.7:14540", Endpoint("out", "10.0.0.7", 14540)),
        ("UDPOUT:localhost:5760", Endpoint("out", "localhost", 5760)),
        ("udpin:0.0.0.0:14550", Endpoint("in", "0.0.0.0", 14550)),
        ("udpin::14550", Endpoint("in", "0.0.0.0", 14550)),
        ("udpin:127.0.0.1:0", Endpoint("in", "127.0.0.1", 0)),
        (" udpin:my-host.local:65535 ", Endpoint("in", "my-host.local", 65535)),
    ],
)
def test_parse_endpoint_accepts(url: str, expected: Endpoint) -> None:
    assert parse_endpoint(url) == expected


@pytest.mark.parametrize(
    "url",
    [
        "",
        "127.0.0.1:14550",
        "tcp:127.0.0.1:5760",
        "udp://127.0.0.1:14550",
        "udpout:127.0.0.1",
        "udpout:127.0.0.1:",
        "udpout:127.0.0.1:port",
        "udpout:127.0.0.1:-1",
        "udpout:127.0.0.1:65536",
        "udpout:127.0.0.1:0",
        "udpout::14550",
        "udpin:[::1]:14550",
        "udpin:::1:14550",
        "udpin:bad host:14550",
        "udpin:-host:14550",
        "udpin:127.0.0.1:1\u0663",
    ],
)
def test_parse_endpoint_rejects_with_message_naming_the_url(url: str) -> None:
    with pytest.raises(EndpointError) as caught:
        parse_endpoint(url)
    assert isinstance(caught.value, ConfigError)
    assert repr(url) in str(caught.value)


def test_parse_endpoint_rejects_non_string() -> None:
    with pytest.raises(EndpointError):
        parse_endpoint(14550)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("mode", "host", "port"), [("sideways", "h", 1), ("out", "", 1), ("out", "h", 0), ("in", "h", 70000), ("in", "h", "1")]
)
def test_endpoint_dataclass_validates_itself(mode: str, host: str, port: int) -> None:
    with pytest.raises(EndpointError):
        Endpoint(mode, host, port)  # type: ignore[arg-type]


def test_endpoint_url_round_trips() -> None:
    endpoint = parse_endpoint("udp:127.0.0.1:14550")
    assert endpoint.url == "udpout:127.0.0.1:14550"
    assert parse_endpoint(endpoint.url) == endpoint
    with pytest.raises(AttributeError):
        endpoint.port = 1  # type: ignore[misc]  # frozen


def test_bad_link_arguments_raise_link_error() -> None:
    with pytest.raises(LinkError, match="source_system"):
        MavlinkUdp(f"udpin:{LOOPBACK}:0", source_system=256, source_component=1)
    with pytest.raises(LinkError, match="accept_system"):
        MavlinkUdp(f"udpin:{LOOPBACK}:0", source_system=1, source_component=1, accept_system=-1)
    with pytest.raises(LinkError, match="peer_timeout_s"):
        MavlinkUdp(f"udpin:{LOOPBACK}:0", source_system=1, source_component=1, peer_timeout_s=0)


def test_bind_failure_names_the_endpoint() -> None:
    with listener() as taken:
        url = f"udpin:{LOOPBACK}:{taken.local_address[1]}"
        with pytest.raises(LinkError, match=url):
            MavlinkUdp(url, source_system=1, source_component=1)


# ---------------------------------------------------------------------------------- traffic


def test_round_trip_out_to_in_and_back() -> None:
    with listener() as fc, MavlinkUdp(url_of(fc), source_system=2, source_component=1) as sim:
        assert sim.local_address[0] == LOOPBACK
        assert sim.peers == ((LOOPBACK, fc.local_address[1]),)
        sim.send(attitude(sim.mav, 42))
        [(msg, addr)] = recv_messages(fc, 1)
        assert msg.get_type() == "ATTITUDE"
        assert (msg.time_boot_ms, msg.get_srcSystem(), msg.get_srcComponent(), msg.get_seq()) == (42, 2, 1, 0)
        assert msg.roll == pytest.approx(0.1)
        assert addr == sim.local_address

        fc.send(fc.mav.local_position_ned_encode(7, 1.0, 2.0, -3.0, 0.1, 0.2, 0.3))
        [(reply, reply_addr)] = recv_messages(sim, 1)
        assert reply.get_type() == "LOCAL_POSITION_NED"
        assert (reply.time_boot_ms, reply.z, reply.get_srcSystem()) == (7, -3.0, 1)
        assert reply_addr == fc.local_address
        assert fc.counters.rx_messages == 1 and fc.counters.tx_datagrams == 1
        assert sim.counters.tx_messages == 1 and sim.counters.rx_datagrams == 1


def test_in_mode_has_no_peer_until_someone_writes_then_answers_them() -> None:
    with listener() as fc, raw_socket() as gcs:
        assert fc.peers == ()
        fc.send(attitude(fc.mav))  # nobody to send to: encoded and counted, not sent
        assert (fc.counters.tx_messages, fc.counters.tx_datagrams) == (1, 0)

        gcs.sendto(packet(encoder(255, 190), heartbeat(encoder(255, 190))), fc.local_address)
        [(msg, addr)] = recv_messages(fc, 1)
        assert msg.get_type() == "HEARTBEAT" and addr == gcs.getsockname()
        assert fc.peers == (gcs.getsockname(),)

        fc.send(attitude(fc.mav, 5))
        data, sender = gcs.recvfrom(65535)
        assert sender == fc.local_address
        [reply] = parse_all(data)
        assert reply.get_type() == "ATTITUDE" and reply.time_boot_ms == 5 and reply.get_seq() == 1


def test_two_peers_both_receive_send_and_send_to_reaches_one() -> None:
    with listener() as fc, raw_socket() as gcs_a, raw_socket() as gcs_b:
        for gcs in (gcs_a, gcs_b):
            gcs.sendto(packet(encoder(255), heartbeat(encoder(255))), fc.local_address)
        assert len(recv_messages(fc, 2)) == 2
        assert set(fc.peers) == {gcs_a.getsockname(), gcs_b.getsockname()}

        fc.send(attitude(fc.mav, 9))
        for gcs in (gcs_a, gcs_b):
            [msg] = parse_all(gcs.recvfrom(65535)[0])
            assert msg.time_boot_ms == 9
        assert fc.counters.tx_datagrams == 2

        fc.send_to(fc.mav.command_ack_encode(400, 0), gcs_b.getsockname())
        [ack] = parse_all(gcs_b.recvfrom(65535)[0])
        assert ack.get_type() == "COMMAND_ACK" and ack.command == 400
        gcs_a.settimeout(0.05)
        with pytest.raises(TimeoutError):
            gcs_a.recvfrom(65535)


def test_out_mode_also_answers_whoever_writes() -> None:
    with raw_socket() as sim, raw_socket() as gcs:
        with MavlinkUdp(f"udp:{LOOPBACK}:{sim.getsockname()[1]}", source_system=1, source_component=1) as fc:
            gcs.sendto(packet(encoder(255), heartbeat(encoder(255))), fc.local_address)
            assert len(recv_messages(fc, 1)) == 1
            assert fc.peers == (sim.getsockname(), gcs.getsockname())
            # the initial destination writing to us is not a second peer
            sim.sendto(packet(encoder(2), heartbeat(encoder(2))), fc.local_address)
            assert len(recv_messages(fc, 1)) == 1
            assert fc.peers == (sim.getsockname(), gcs.getsockname())
            fc.send(attitude(fc.mav))
            for sock in (sim, gcs):
                assert parse_all(sock.recvfrom(65535)[0])[0].get_type() == "ATTITUDE"


def test_send_many_packs_messages_into_one_datagram() -> None:
    with listener() as fc, raw_socket() as sim:
        sim.sendto(packet(encoder(2), heartbeat(encoder(2))), fc.local_address)
        recv_messages(fc, 1)
        mav = fc.mav
        fc.send_many([attitude(mav, 1), mav.local_position_ned_encode(1, 1, 2, 3, 4, 5, 6), heartbeat(mav)])
        data = sim.recvfrom(65535)[0]
        messages = parse_all(data)
        assert [m.get_type() for m in messages] == ["ATTITUDE", "LOCAL_POSITION_NED", "HEARTBEAT"]
        assert [m.get_seq() for m in messages] == [0, 1, 2]
        assert sum(len(m.get_msgbuf()) for m in messages) == len(data)
        assert (fc.counters.tx_messages, fc.counters.tx_datagrams) == (3, 1)
        fc.send_many([])
        assert fc.counters.tx_datagrams == 1


def test_send_many_splits_datagrams_at_max_datagram_bytes() -> None:
    with listener(max_datagram_bytes=300) as fc, raw_socket() as sim:
        sim.sendto(packet(encoder(2), heartbeat(encoder(2))), fc.local_address)
        recv_messages(fc, 1)
        fc.send_many([attitude(fc.mav, i) for i in range(10)])  # 10 x 40 bytes
        first = parse_all(sim.recvfrom(65535)[0])
        second = parse_all(sim.recvfrom(65535)[0])
        assert [m.time_boot_ms for m in first + second] == list(range(10))
        assert len(first) == 7 and fc.counters.tx_datagrams == 2


def test_several_packets_in_one_incoming_datagram_all_arrive() -> None:
    mav = encoder(2)
    data = b"".join(
        packet(mav, m)
        for m in (attitude(mav, 1), mav.local_position_ned_encode(1, 1, 2, 3, 4, 5, 6), heartbeat(mav), attitude(mav, 2))
    )
    with listener() as fc, raw_socket() as sim:
        sim.sendto(data, fc.local_address)
        received = recv_messages(fc, 4)
        assert [m.get_type() for m, _ in received] == ["ATTITUDE", "LOCAL_POSITION_NED", "HEARTBEAT", "ATTITUDE"]
        assert [m.get_seq() for m, _ in received] == [0, 1, 2, 3]
        assert (fc.counters.rx_datagrams, fc.counters.rx_messages, fc.counters.rx_bad) == (1, 4, 0)


def test_bad_datagrams_are_counted_and_dropped_and_the_next_good_message_arrives() -> None:
    mav = encoder(2)
    good = packet(mav, attitude(mav, 77))
    bad_crc = bytearray(packet(mav, attitude(mav, 1)))
    bad_crc[-1] ^= 0xFF
    truncated = packet(mav, mav.local_position_ned_encode(1, 1, 2, 3, 4, 5, 6))[:-5]
    foreign = packet(encoder(99), attitude(encoder(99), 3))
    with listener(accept_system=2) as fc, raw_socket() as sim:
        for datagram in (b"\x00\x01garbage\xff" * 5, truncated, bytes(bad_crc), foreign, b"\xfd", good):
            sim.sendto(datagram, fc.local_address)
        received = recv_messages(fc, 1)
        # let the rest of the queue (nothing) drain, then check nothing else came through
        received += fc.recv(0.0)
        assert [(m.get_type(), m.time_boot_ms) for m, _ in received] == [("ATTITUDE", 77)]
        c = fc.counters
        assert (c.rx_datagrams, c.rx_messages, c.rx_bad, c.rx_foreign_system) == (6, 1, 4, 1)
        # a foreign or garbage sender does not become a peer; the good one does
        assert fc.peers == (sim.getsockname(),)


def test_truncated_packet_does_not_corrupt_the_next_datagram_from_another_peer() -> None:
    mav = encoder(2)
    with listener() as fc, raw_socket() as peer_a, raw_socket() as peer_b:
        peer_a.sendto(packet(mav, heartbeat(mav))[:7], fc.local_address)
        peer_b.sendto(packet(mav, attitude(mav, 5)), fc.local_address)
        received = recv_messages(fc, 1)
        received += fc.recv(0.0)
        assert [(m.get_type(), addr) for m, addr in received] == [("ATTITUDE", peer_b.getsockname())]
        assert fc.counters.rx_bad == 1


def test_good_packet_after_garbage_or_bad_crc_in_the_same_datagram_arrives() -> None:
    mav = encoder(2)
    corrupted = bytearray(packet(mav, attitude(mav, 1)))
    corrupted[12] ^= 0x40  # payload bit flip -> CRC mismatch
    datagram = b"junk\xfe\x03" + bytes(corrupted) + packet(mav, attitude(mav, 2)) + b"\xfd\x05trailing"
    with listener() as fc, raw_socket() as sim:
        sim.sendto(datagram, fc.local_address)
        received = recv_messages(fc, 1)
        assert [m.time_boot_ms for m, _ in received] == [2]
        # one run of junk before the good packet, one after it
        assert fc.counters.rx_bad == 2


def test_unknown_message_id_is_counted_and_skipped() -> None:
    mav = encoder(2)
    payload = b"\x01\x02\x03"
    unknown = bytes([0xFD, len(payload), 0, 0, 0, 2, 1, 0xEF, 0xCD, 0xAB]) + payload + b"\x00\x00"
    with listener() as fc, raw_socket() as sim:
        sim.sendto(unknown + packet(mav, attitude(mav, 3)), fc.local_address)
        received = recv_messages(fc, 1)
        assert [m.get_type() for m, _ in received] == ["ATTITUDE"]
        assert (fc.counters.rx_unknown, fc.counters.rx_bad) == (1, 0)


def test_mavlink1_and_signed_packets_are_accepted() -> None:
    v1 = encoder(2)
    signed = encoder(2)
    signed.signing.secret_key = bytes(range(32))
    signed.signing.sign_outgoing = True
    datagram = packet(v1, attitude(v1, 10), force_mavlink1=True) + packet(signed, attitude(signed, 11))
    with listener() as fc, raw_socket() as sim:
        sim.sendto(datagram, fc.local_address)
        received = recv_messages(fc, 2)
        assert [m.time_boot_ms for m, _ in received] == [10, 11]
        assert received[0][0].get_msgbuf()[0] == mavlink.PROTOCOL_MARKER_V1
        assert received[1][0].get_header().incompat_flags & mavlink.MAVLINK_IFLAG_SIGNED


@settings(max_examples=200, deadline=None)
@given(garbage=st.binary(max_size=300).map(lambda b: b.replace(b"\xfd", b"\x00").replace(b"\xfe", b"\x00")))
def test_arbitrary_garbage_before_a_packet_never_raises_and_the_packet_survives(garbage: bytes) -> None:
    mav = encoder(2)
    good = packet(mav, attitude(mav, 123))
    with listener() as fc:
        received: list[tuple[mavlink.MAVLink_message, tuple[str, int]]] = []
        fc._parse_datagram(garbage + good + garbage, ("127.0.0.1", 9), received)
        assert [m.time_boot_ms for m, _ in received] == [123]


@settings(max_examples=300, deadline=None)
@given(data=st.binary(max_size=400))
def test_arbitrary_bytes_never_raise(data: bytes) -> None:
    with listener() as fc:
        received: list[tuple[mavlink.MAVLink_message, tuple[str, int]]] = []
        fc._parse_datagram(data, ("127.0.0.1", 9), received)
        assert fc.counters.rx_messages == len(received)


def test_recv_timeout_returns_empty_within_a_short_time() -> None:
    with listener() as fc:
        started_s = time.monotonic()
        assert fc.recv(0.05) == []
        elapsed_s = time.monotonic() - started_s
        assert 0.04 <= elapsed_s < 0.5
        started_s = time.monotonic()
        assert fc.recv(0.0) == []
        assert time.monotonic() - started_s < 0.05


def test_sending_to_a_closed_port_never_raises() -> None:
    with raw_socket() as gone:
        closed_port = gone.getsockname()[1]
    with MavlinkUdp(f"udpout:{LOOPBACK}:{closed_port}", source_system=1, source_component=1) as fc:
        if sys.platform == "linux":
            # Make Linux report ICMP "port unreachable" on this unconnected socket (as other
            # systems do), so the refusal really reaches send/recv.
            with socket.socket(fileno=os.dup(fc.fileno())) as same_socket:
                same_socket.setsockopt(socket.SOL_IP, getattr(socket, "IP_RECVERR", 11), 1)
        for i in range(6):
            fc.send(attitude(fc.mav, i))
            fc.send_many([attitude(fc.mav, i), heartbeat(fc.mav)])
            fc.recv(0.0)
        c = fc.counters
        assert c.tx_messages == 18
        assert c.tx_datagrams + c.tx_errors >= 12
        if sys.platform == "linux":
            assert c.tx_errors >= 1 and c.last_tx_errno != 0


def test_peers_expire_after_peer_timeout() -> None:
    now_s = [1000.0]
    with listener(peer_timeout_s=5.0, monotonic_s=lambda: now_s[0]) as fc, raw_socket() as gcs:
        gcs.sendto(packet(encoder(255), heartbeat(encoder(255))), fc.local_address)
        recv_messages(fc, 1)
        assert fc.peers == (gcs.getsockname(),)
        now_s[0] += 4.0
        assert fc.peers == (gcs.getsockname(),)
        gcs.sendto(packet(encoder(255), heartbeat(encoder(255))), fc.local_address)
        recv_messages(fc, 1)  # seen again at t = 1004
        now_s[0] += 4.0
        assert fc.peers == (gcs.getsockname(),)
        now_s[0] += 1.5
        assert fc.peers == ()
        fc.send(attitude(fc.mav))
        assert fc.counters.tx_datagrams == 0


def test_initial_destination_never_expires() -> None:
    now_s = [0.0]
    with raw_socket() as sim:
        url = f"udpout:{LOOPBACK}:{sim.getsockname()[1]}"
        with MavlinkUdp(url, source_system=1, source_component=1, monotonic_s=lambda: now_s[0]) as fc:
            now_s[0] = 1e6
            assert fc.peers == (sim.getsockname(),)


def test_a_new_peer_beyond_max_peers_replaces_a_quiet_one_only() -> None:
    now_s = [0.0]
    hb = packet(encoder(255), heartbeat(encoder(255)))
    with listener(max_peers=2, monotonic_s=lambda: now_s[0]) as fc, raw_socket() as a, raw_socket() as b, raw_socket() as c:
        for sock in (a, b, c):
            now_s[0] += 1.0  # a has been quiet 2 s when c arrives: still live (PEER_QUIET_S 2.5)
            sock.sendto(hb, fc.local_address)
            assert len(recv_messages(fc, 1)) == 1  # messages are always delivered
        assert set(fc.peers) == {a.getsockname(), b.getsockname()}
        assert fc.counters.peers_rejected == 1
        now_s[0] += 1.0  # a quiet 3 s now: it gives its place to c
        c.sendto(hb, fc.local_address)
        recv_messages(fc, 1)
        assert set(fc.peers) == {b.getsockname(), c.getsockname()}
        assert len(fc.peers) == 2  # never more than max_peers
        assert fc.counters.peers_rejected == 2


def test_a_pinned_peer_is_never_evicted_by_newcomers() -> None:
    now_s = [0.0]
    hb = packet(encoder(255), heartbeat(encoder(255)))
    with listener(max_peers=2, monotonic_s=lambda: now_s[0]) as fc, raw_socket() as gcs:
        gcs.sendto(hb, fc.local_address)
        recv_messages(fc, 1)
        fc.pin_peer(gcs.getsockname())
        for _ in range(3):  # a quiet pinned station (9 s < peer timeout), newcomers from new ports
            now_s[0] += 3.0
            with raw_socket() as newcomer:
                newcomer.sendto(hb, fc.local_address)
                recv_messages(fc, 1)
        assert gcs.getsockname() in fc.peers
        assert len(fc.peers) == 2


def test_fast_path_and_pymavlink_path_send_identical_bytes() -> None:
    def sent_bytes(fast_codec: bool) -> list[bytes]:
        with raw_socket() as sink:
            url = f"udpout:{LOOPBACK}:{sink.getsockname()[1]}"
            datagrams = []
            with MavlinkUdp(url, source_system=7, source_component=3, fast_codec=fast_codec) as link:
                mav = link.mav
                for i in range(100):  # 300 messages: past the sequence number wrap at 256
                    link.send_many(
                        [
                            attitude(mav, i),
                            mav.local_position_ned_encode(i, 0.0, 0.0, -1.5, 0.0, 0.0, 0.0),
                            mav.hil_actuator_controls_encode(i * 1000, [0.5] * 4 + [0.0] * 12, 0, 0),
                        ]
                    )
                    datagrams.append(sink.recvfrom(65535)[0])
                link.send(heartbeat(mav))
                datagrams.append(sink.recvfrom(65535)[0])
            return datagrams

    assert sent_bytes(True) == sent_bytes(False)


def test_fast_path_and_pymavlink_path_decode_identically() -> None:
    mav = encoder(2)
    data = b"".join(
        packet(mav, m)
        for m in (
            attitude(mav, 1),
            mav.local_position_ned_encode(1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
            mav.hil_actuator_controls_encode(5, [0.25] * 16, 1, 2),
        )
    )
    results = []
    for fast_codec in (True, False):
        with listener(fast_codec=fast_codec) as fc:
            received: list[tuple[mavlink.MAVLink_message, tuple[str, int]]] = []
            fc._parse_datagram(data, ("127.0.0.1", 9), received)
            results.append([m for m, _ in received])
    fast, slow = results
    assert len(fast) == len(slow) == 3
    for a, b in zip(fast, slow):
        assert type(a) is type(b) and a == b
        assert a.get_msgbuf() == b.get_msgbuf() and a.get_payload() == b.get_payload()
        assert vars(a.get_header()) == vars(b.get_header())


def test_mav_send_methods_go_through_the_link_with_one_sequence() -> None:
    with listener() as fc, MavlinkUdp(url_of(fc), source_system=2, source_component=1) as sim:
        sim.send(attitude(sim.mav))
        sim.mav.heartbeat_send(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 0)
        sim.send(attitude(sim.mav))
        received = recv_messages(fc, 3)
        assert [(m.get_type(), m.get_seq()) for m, _ in received] == [("ATTITUDE", 0), ("HEARTBEAT", 1), ("ATTITUDE", 2)]
        assert sim.counters.tx_messages == 3


def test_traffic_is_written_to_the_tlog_with_the_injected_clock(tmp_path: object) -> None:
    path = os.path.join(str(tmp_path), "fc.tlog")
    clock = iter(range(1_000, 100_000, 1_000))
    with TlogWriter(path) as tlog, listener(tlog=tlog, clock_us=lambda: next(clock)) as fc:
        with MavlinkUdp(url_of(fc), source_system=2, source_component=1) as sim:
            sim.send(heartbeat(sim.mav))
            recv_messages(fc, 1)  # logged at 1000
            fc.send_many([attitude(fc.mav, 1), fc.mav.local_position_ned_encode(1, 0, 0, 0, 0, 0, 0)])  # 2000
            fc.send_to(fc.mav.command_ack_encode(400, 0), sim.local_address)  # 3000
    records = [(t, m.get_type(), m.get_srcSystem()) for t, m in read_tlog(path)]
    assert records == [
        (1000, "HEARTBEAT", 2),
        (2000, "ATTITUDE", 1),
        (2000, "LOCAL_POSITION_NED", 1),
        (3000, "COMMAND_ACK", 1),
    ]


def test_closed_link_raises_and_close_is_idempotent() -> None:
    fc = MavlinkUdp(f"udpin:{LOOPBACK}:0", source_system=1, source_component=1)
    fc.close()
    fc.close()
    assert fc.closed
    with pytest.raises(LinkClosedError):
        fc.send(attitude(fc.mav))
    with pytest.raises(LinkClosedError):
        fc.recv(0.0)


def test_counters_snapshot_and_reset() -> None:
    with listener() as fc:
        fc.send(attitude(fc.mav))
        assert fc.counters.as_dict()["tx_messages"] == 1
        fc.counters.reset()
        assert set(fc.counters.as_dict().values()) == {0}


def test_send_packets_with_take_seq_numbers_like_send_and_logs(tmp_path) -> None:
    """The hot-path pair (fastcodec bytes + take_seq) keeps one gap-free sequence with send()."""
    from smcpilot import fastcodec

    path = tmp_path / "seq.tlog"
    with TlogWriter(path) as tlog, listener() as rx, MavlinkUdp(url_of(rx), source_system=3, source_component=7, tlog=tlog, clock_us=lambda: 42) as tx:
        tx.send(heartbeat(tx.mav))
        sysid, comp = tx.source
        tx.send_packets(
            (
                fastcodec.encode_attitude(tx.take_seq(), sysid, comp, 1, 0.1, 0.2, 0.3, 0.0, 0.0, 0.0),
                fastcodec.encode_local_position_ned(tx.take_seq(), sysid, comp, 1, 1.0, 2.0, 3.0, 0.0, 0.0, 0.0),
            )
        )
        tx.send(heartbeat(tx.mav))
        got = recv_messages(rx, 4)
        assert [m.get_seq() for m, _ in got] == [0, 1, 2, 3]
        assert [m.get_type() for m, _ in got] == ["HEARTBEAT", "ATTITUDE", "LOCAL_POSITION_NED", "HEARTBEAT"]
        assert {(m.get_srcSystem(), m.get_srcComponent()) for m, _ in got} == {(3, 7)}
        assert tx.counters.tx_messages == 4 and tx.counters.tx_datagrams == 3  # the pair in one datagram
    assert [(t, m.get_type()) for t, m in read_tlog(path)] == [
        (42, "HEARTBEAT"), (42, "ATTITUDE"), (42, "LOCAL_POSITION_NED"), (42, "HEARTBEAT")
    ]


def test_kernel_drops_count_what_a_full_receive_buffer_lost() -> None:
    import socket as _socket

    from smcpilot.link import MavlinkUdp

    with MavlinkUdp("udpin:127.0.0.1:0", source_system=1, source_component=1) as link:
        assert link.kernel_drops() == 0
        link._sock.setsockopt(_socket.SOL_SOCKET, _socket.SO_RCVBUF, 4096)
        with _socket.socket(_socket.AF_INET, _socket.SOCK_DGRAM) as flood:
            for _ in range(400):  # nobody reads: the buffer fills, the kernel drops the rest
                flood.sendto(b"\xfe" * 1000, link.local_address)
        drops = link.kernel_drops()
        assert drops is not None and drops > 300, drops


# ---------------------------------------------------------------------------------- the parts, the one send path


class _RecordingSocket:
    """Stands in for a link's socket: records each datagram sent and whether the one send path
    was running (``inside[0]``) when it was, then sends it for real."""

    def __init__(self, real: socket.socket, inside: list[bool]) -> None:
        self.real, self.inside = real, inside
        self.sent: list[tuple[bytes, tuple[str, int], bool]] = []

    def sendto(self, datagram: bytes, addr: tuple[str, int]) -> int:
        self.sent.append((bytes(datagram), addr, self.inside[0]))
        return self.real.sendto(datagram, addr)

    def __getattr__(self, name: str) -> object:
        return getattr(self.real, name)


def _split_packets(datagram: bytes) -> list[bytes]:
    """The MAVLink 2 packets of a datagram, by their length fields."""
    out, i = [], 0
    while i < len(datagram):
        end = i + 12 + datagram[i + 1] + (13 if datagram[i + 2] & 1 else 0)
        out.append(datagram[i:end])
        i = end
    return out


def _send_every_way(tx: MavlinkUdp, to: tuple[str, int]) -> None:
    """One call of each send entry point: 10 messages in 8 datagrams."""
    from smcpilot import fastcodec

    sysid, comp = tx.source
    tx.send(heartbeat(tx.mav))
    tx.send_many([attitude(tx.mav, 2), heartbeat(tx.mav)])
    tx.send_many([attitude(tx.mav, 3)], others_limit=0)
    tx.send_to(attitude(tx.mav, 4), to)
    tx.send_many_to([attitude(tx.mav, 5), heartbeat(tx.mav)], to)
    tx.send_packets([fastcodec.encode_attitude(tx.take_seq(), sysid, comp, 6, 0.1, 0.2, 0.3, 0.0, 0.0, 0.0)])
    tx.send_packets_to([fastcodec.encode_attitude(tx.take_seq(), sysid, comp, 7, 0.1, 0.2, 0.3, 0.0, 0.0, 0.0)], to)
    tx.mav.heartbeat_send(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)


def test_every_send_entry_point_goes_through_the_one_send_path_once(tmp_path) -> None:
    """send, send_many (limited or not), send_to, send_many_to, send_packets(_to) and mav.*_send
    each call MavlinkUdp._transmit once; no datagram leaves outside it; it logs and counts all."""
    path = tmp_path / "paths.tlog"
    with TlogWriter(path) as tlog, listener() as rx, MavlinkUdp(url_of(rx), source_system=2, source_component=1, tlog=tlog, clock_us=lambda: 7) as tx:
        inside = [False]
        calls: list[tuple[int, object]] = []
        one_path = tx._transmit

        def spy(packets, dests=None):  # type: ignore[no-untyped-def]
            calls.append((len(packets), None if dests is None else list(dests)))
            inside[0] = True
            try:
                one_path(packets, dests)
            finally:
                inside[0] = False

        tx._transmit = spy  # type: ignore[method-assign]
        sock = tx._udp.sock = _RecordingSocket(tx._udp.sock, inside)  # type: ignore[assignment]
        to = rx.local_address
        _send_every_way(tx, to)
        got = recv_messages(rx, 10)
        assert [n for n, _ in calls] == [1, 2, 1, 1, 2, 1, 1, 1]
        assert [d for _, d in calls] == [None, None, [to], [to], [to], None, [to], None]  # others_limit: a list
        assert len(sock.sent) == 8 and all(was_inside for _, _, was_inside in sock.sent)
        assert [m.get_seq() for m, _ in got] == list(range(10))
        assert tx.counters.tx_messages == 10 and tx.counters.tx_datagrams == 8 and tx.counters.tx_errors == 0
    assert [t for t, _ in read_tlog(path)] == [7] * 10


def test_every_send_entry_point_signs_and_logs_setup_signing_without_its_key(tmp_path) -> None:
    """Signing and the tlog's redaction are applied by the one send path, so every entry point
    signs, and a SETUP_SIGNING reaches the tlog with its key zeroed however it was sent."""
    from smcpilot.signing import Signing

    key = bytes(range(1, 33))
    path = tmp_path / "signed.tlog"
    with raw_socket() as rx, TlogWriter(path) as tlog:
        url = f"udpout:{LOOPBACK}:{rx.getsockname()[1]}"
        with MavlinkUdp(url, source_system=2, source_component=1, signing=Signing(key), link_id=5, tlog=tlog) as tx:
            to = rx.getsockname()
            _send_every_way(tx, to)
            packets = [p for _ in range(8) for p in _split_packets(rx.recv(65535))]
            setup = tx.mav.setup_signing_encode(1, 1, list(key), 99)
            tx.send_many([setup])
            tx.send_packets([setup.pack(mavlink.MAVLink(None, srcSystem=2, srcComponent=1))])
            sent_setups = [p for _ in range(2) for p in _split_packets(rx.recv(65535))]
    assert len(packets) == 10 and all(p[2] & 1 and p[-13] == 5 for p in packets)  # signed, link id 5
    assert all(key in p for p in sent_setups)  # the wire has the key ...
    logged = [m for _, m in read_tlog(path) if m.get_type() == "SETUP_SIGNING"]
    assert len(logged) == 2 and all(bytes(m.secret_key) == bytes(32) for m in logged)  # ... the tlog never


def test_the_parts_alone() -> None:
    """The parts MavlinkUdp composes work on their own."""
    from smcpilot.impair import LinkImpairment
    from smcpilot.link import LinkCounters, pack_datagrams
    from smcpilot.udplink.impairment import LinkImpairer
    from smcpilot.udplink.peers import PeerTable
    from smcpilot.udplink.udpsocket import UdpSocket

    assert pack_datagrams([b"a" * 200, b"b" * 200, b"c" * 200], 400) == [b"a" * 200 + b"b" * 200, b"c" * 200]
    assert pack_datagrams([b"x" * 500], 400) == [b"x" * 500]

    counters = LinkCounters()
    now_s = [0.0]
    initial = ("127.0.0.1", 1)
    table = PeerTable(initial, timeout_s=10.0, max_peers=4, monotonic_s=lambda: now_s[0], counters=counters)
    others = [("127.0.0.1", p) for p in (2, 3, 4)]
    for addr in others:
        table.heard(addr, now_s[0])
    table.heard(others[2], now_s[0], signed=True)
    assert table.current() == (initial, *others) and table.pinned == {others[2]}
    assert table.limited(1) == ([initial, others[2], others[0]], 1)
    assert table.limited(1) == ([initial, others[2], others[1]], 1)  # the others take turns
    now_s[0] = 11.0
    assert table.current() == (initial,) and not table.pinned  # silent for 11 s: forgotten

    with UdpSocket(parse_endpoint(f"udpin:{LOOPBACK}:0"), counters) as a, raw_socket() as b:
        a.sendto(b"hi", b.getsockname())
        assert b.recvfrom(100)[0] == b"hi" and counters.tx_datagrams == 1
        b.sendto(b"there", a.local_address)
        assert a.wait_readable(ARRIVAL_TIMEOUT_S) and a.take(8) == [(b"there", b.getsockname())]
        assert counters.rx_datagrams == 1
    assert a.closed

    sent: list[tuple[bytes, tuple[str, int]]] = []
    assert LinkImpairer.for_link(LinkImpairment(), 0, monotonic_s=lambda: 0.0, sendto=lambda d, a: None) is None
    lossy = LinkImpairer.for_link(LinkImpairment(delay_ms=5.0), 0, monotonic_s=lambda: now_s[0], sendto=lambda d, a: sent.append((d, a)))
    assert lossy is not None
    lossy.send(b"late", initial)
    assert sent == [] and lossy.wait_s() == pytest.approx(0.005)
    now_s[0] += 0.005
    lossy.pump()
    assert sent == [(b"late", initial)] and lossy.counters["tx"]["released"] == 1
