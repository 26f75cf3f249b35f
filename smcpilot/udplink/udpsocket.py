"""The socket of a link: :class:`UdpSocket`, one non-blocking IPv4 UDP socket opened for an
:class:`~smcpilot.udplink.endpoint.Endpoint`, counting every datagram it sends and takes.

Sending never raises on network errors (an unreachable ground station must not stop the control
loop): they are counted in ``tx_errors``; a refusal (the peer's port is closed: its process is
gone) also sets :attr:`UdpSocket.peer_refused`, whether the OS reports it on the send or on a
later receive.
"""

from __future__ import annotations

import errno
import ipaddress
import math
import os
import select
import socket
from types import TracebackType

from smcpilot.errors import LinkError
from smcpilot.udplink.counters import LinkCounters
from smcpilot.udplink.endpoint import Address, Endpoint

__all__ = ["UdpSocket", "udp_kernel_drops"]

#: Bytes asked of each ``recvfrom``: the largest UDP payload, so no datagram is ever cut.
RECV_BUFFER_BYTES = 65535
_FD_SETSIZE = 1024
#: Linux's IP_RECVERR: report ICMP errors (a closed peer port) on an unconnected UDP socket.
_IP_RECVERR = getattr(socket, "IP_RECVERR", 11)


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


class UdpSocket:
    """A non-blocking UDP socket bound for ``endpoint``; a context manager that closes it.

    An ``in`` endpoint binds its host and port. An ``out`` endpoint binds ``bind_port`` (0: any
    free port) on loopback when its host is a loopback address, else on all interfaces, and its
    resolved address is :attr:`initial_destination`. Raises :class:`~smcpilot.errors.LinkError`
    when the host does not resolve or the bind fails.
    """

    __slots__ = ("endpoint", "sock", "fd", "local_address", "initial_destination", "counters", "peer_refused", "closed")

    def __init__(self, endpoint: Endpoint, counters: LinkCounters, *, bind_port: int = 0) -> None:
        self.endpoint = endpoint
        self.counters = counters
        #: set once a send was refused by the peer's host (its port is closed: the peer process is
        #: gone); reported on receive only after :meth:`report_peer_errors`.
        self.peer_refused = False
        #: where an ``out`` endpoint sends before anyone has written to us (None for ``in``).
        self.initial_destination: Address | None = None
        self.closed = True
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
                sock.bind(("127.0.0.1" if loopback else "0.0.0.0", int(bind_port)))
                self.initial_destination = address
            sock.setblocking(False)
        except OSError as exc:
            sock.close()
            raise LinkError(f"endpoint {endpoint.url}: cannot bind UDP socket: {exc.strerror or exc}") from exc
        self.sock = sock
        #: the socket's file descriptor.
        self.fd: int = sock.fileno()
        #: ``(host, port)`` the socket is bound to.
        self.local_address: Address = sock.getsockname()[:2]
        self.closed = False

    def sendto(self, datagram: bytes, addr: Address) -> None:
        """Send one datagram to ``addr``: counted in ``tx_datagrams``, or in ``tx_errors`` (never raises)."""
        counters = self.counters
        try:
            self.sock.sendto(datagram, addr)
        except OSError as exc:
            counters.tx_errors += 1
            counters.last_tx_errno = exc.errno or 0
            if exc.errno == errno.ECONNREFUSED:
                self.peer_refused = True
        else:
            counters.tx_datagrams += 1

    def take(self, max_datagrams: int) -> list[tuple[bytes, Address]]:
        """Up to ``max_datagrams`` datagrams off the socket (counted in ``rx_datagrams``), without
        waiting. A refusal of an earlier send reported here is counted as a failed send."""
        recvfrom = self.sock.recvfrom
        counters = self.counters
        out: list[tuple[bytes, Address]] = []
        for _ in range(max_datagrams):
            try:
                data, addr = recvfrom(RECV_BUFFER_BYTES)
            except BlockingIOError:
                break
            except (ConnectionRefusedError, ConnectionResetError) as exc:
                self.refused(exc)  # an ICMP "port unreachable" for an earlier send
                continue
            counters.rx_datagrams += 1
            out.append((data, addr))
        return out

    def refused(self, exc: OSError) -> None:
        """A send of ours was refused by the peer's host (its port is closed), reported on receive."""
        counters = self.counters
        counters.tx_errors += 1
        counters.last_tx_errno = exc.errno or 0
        self.peer_refused = True

    def wait_readable(self, timeout_s: float) -> bool:
        """Wait up to ``timeout_s`` seconds for a datagram; True if one is queued."""
        if self.fd < _FD_SETSIZE:
            readable, _, _ = select.select((self.fd,), (), (), timeout_s)
            return bool(readable)
        poller = select.poll()  # pragma: no cover - only in processes with > 1024 open files
        poller.register(self.fd, select.POLLIN)
        return bool(poller.poll(math.ceil(timeout_s * 1000.0)))

    def report_peer_errors(self) -> None:
        """Ask the OS to report ICMP errors for our sends (Linux ``IP_RECVERR``)."""
        try:
            self.sock.setsockopt(socket.IPPROTO_IP, _IP_RECVERR, 1)
        except OSError:  # pragma: no cover - not Linux: the watchdogs still notice
            pass

    def kernel_drops(self) -> int | None:
        """Datagrams the kernel dropped for this socket (:func:`udp_kernel_drops`)."""
        return udp_kernel_drops(self.sock)

    def close(self) -> None:
        """Close the socket. Idempotent."""
        if self.closed:
            return
        self.closed = True
        self.sock.close()

    def __enter__(self) -> UdpSocket:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.close()
