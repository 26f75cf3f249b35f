"""The parts :class:`smcpilot.link.MavlinkUdp` is composed of, one small module each.

:mod:`~smcpilot.udplink.endpoint` (where a link sends or listens), :mod:`~smcpilot.udplink.counters`
(its traffic statistics), :mod:`~smcpilot.udplink.udpsocket` (the socket), :mod:`~smcpilot.udplink.peers`
(who it sends to), :mod:`~smcpilot.udplink.encoder` (sequence numbers, encoding, signing),
:mod:`~smcpilot.udplink.parser` (datagrams to checked messages), :mod:`~smcpilot.udplink.impairment`
(a bad network acted out) and :mod:`~smcpilot.udplink.logtap` (the tlog's copy of the traffic).
Use them through :mod:`smcpilot.link`, which composes them and re-exports the public names; the
parts import nothing from it.
"""
