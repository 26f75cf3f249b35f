"""Where a link sends or listens: :class:`Endpoint` and the URL forms :func:`parse_endpoint` reads.

``udp:HOST:PORT`` or ``udpout:HOST:PORT`` send to HOST:PORT; ``udpin:HOST:PORT`` binds HOST:PORT
(``udpin::PORT`` = all interfaces; PORT 0 = any free port). See :mod:`smcpilot.link`.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Literal

from smcpilot.errors import EndpointError

__all__ = ["Address", "Endpoint", "parse_endpoint"]

#: A UDP peer address as the socket module gives it: ``(host, port)``.
Address = tuple[str, int]

_SCHEMES: dict[str, Literal["out", "in"]] = {"udp": "out", "udpout": "out", "udpin": "in"}
_HOST_RE = re.compile(r"^[A-Za-z0-9](?:[A-Za-z0-9.-]*[A-Za-z0-9])?$")
_ENDPOINT_FORMS = "udp:HOST:PORT, udpout:HOST:PORT or udpin:HOST:PORT"


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
