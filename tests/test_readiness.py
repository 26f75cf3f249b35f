"""smcpilot.udplink.readiness: the readable ones of a set of real UDP sockets on 127.0.0.1, with
epoll and with the select fallback."""

from __future__ import annotations

import select
import socket

import pytest

from smcpilot.udplink.readiness import Readiness


@pytest.fixture(params=["epoll", "select"])
def backend(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> str:
    if request.param == "select":
        monkeypatch.delattr(select, "epoll", raising=False)
    elif not hasattr(select, "epoll"):
        pytest.skip("no epoll on this platform")
    return str(request.param)


def test_only_the_sockets_with_a_datagram_are_readable(backend: str) -> None:
    socks = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(3)]
    try:
        for s in socks:
            s.bind(("127.0.0.1", 0))
        with Readiness([s.fileno() for s in socks]) as ready:
            assert (ready._epoll is not None) == (backend == "epoll")
            assert ready.wait(0.0) == []
            socks[0].sendto(b"x", socks[2].getsockname())
            assert ready.wait(1.0) == [socks[2].fileno()]
            assert ready.wait(0.0) == [socks[2].fileno()]  # (still unread: level-triggered)
            socks[2].recv(16)
            assert ready.wait(0.0) == []
            ready.watch([socks[0].fileno(), socks[1].fileno()])  # another set: the old one forgotten
            socks[2].sendto(b"y", socks[2].getsockname())
            socks[2].sendto(b"z", socks[1].getsockname())
            assert ready.wait(1.0) == [socks[1].fileno()]
        assert ready._epoll is None  # closed with the block
    finally:
        for s in socks:
            s.close()
