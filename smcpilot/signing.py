"""MAVLink 2 message signing: keys, timestamps, the stream table, and the unsigned-accepted list.

A signed MAVLink 2 packet carries 13 more bytes after its CRC: a link id (1 byte), a timestamp
(6 bytes, little-endian, units of 10 µs since 2015-01-01 00:00 UTC) and the first 6 bytes of
``SHA-256(secret_key + header + payload + crc + link_id + timestamp)``; its ``incompat_flags`` has
bit 0 (``MAVLINK_IFLAG_SIGNED``) set. This module produces and checks exactly what pymavlink's
``MAVLink.setup_signing`` and MAVProxy's ``signing`` module produce and check.

- :func:`load_key` reads a key file: one line holding either 64 hexadecimal digits (the 32-byte
  key itself) or a passphrase (the key is its SHA-256, as MAVProxy's ``signing setup PASSPHRASE``
  makes it).
- :class:`Signing` is the signing state of one process, shared by all of its links: the key, the
  outgoing timestamp (wall clock, strictly increasing, never from simulated time), one stream
  table for every link, and the list of messages accepted unsigned (:data:`ACCEPT_UNSIGNED`).
  Incoming packets are checked *before* their stream's timestamp advances: a forged packet with a
  future timestamp changes nothing (pymavlink records the timestamp before it checks the
  signature, so one such packet locks a real sender out; we don't).
- :class:`TimestampStore` keeps the outgoing timestamp across restarts: saved atomically (temp
  file, fsync, rename) every few wall seconds by a background thread and at close; a process
  starts from ``max(wall clock, saved + margin)``, so a clock that went back after a restart
  still gives timestamps the peers accept.

Everything here is I/O-free except :class:`TimestampStore` and :func:`load_key`.
"""

from __future__ import annotations

import hashlib
import hmac
import os
import struct
import threading
import time
from collections.abc import Callable, Iterable
from pathlib import Path

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from smcpilot.errors import ConfigError

__all__ = [
    "ACCEPT_UNSIGNED",
    "KEY_BYTES",
    "MAVLINK_EPOCH_UNIX_S",
    "NEW_STREAM_WINDOW",
    "OK",
    "REJECT_BAD_SIGNATURE",
    "REJECT_OLD_TIMESTAMP",
    "REJECT_STREAM_WINDOW",
    "REJECT_UNSIGNED",
    "REJECT_REASONS",
    "Signing",
    "SigningKeyError",
    "TimestampStore",
    "key_from_text",
    "load_key",
    "redact_setup_signing",
    "wall_timestamp",
]

#: Length of a MAVLink 2 signing key, bytes.
KEY_BYTES = 32
#: The MAVLink signing epoch, 2015-01-01 00:00:00 UTC, in Unix seconds.
MAVLINK_EPOCH_UNIX_S = 1_420_070_400
#: Signing timestamps count units of 10 µs.
TIMESTAMP_UNITS_PER_S = 100_000
#: A stream never heard before is accepted only if its timestamp is within this many units
#: (one minute) of our own clock.
NEW_STREAM_WINDOW = 60 * TIMESTAMP_UNITS_PER_S

#: Messages accepted without a signature while signing is on: HEARTBEAT (so a ground station
#: that does not sign still sees the vehicle and can be told what is wrong, and an unsigned
#: vehicle is still listed) and RADIO_STATUS (sent by radio modems, which cannot sign). Every
#: other unsigned or badly signed packet is dropped and counted.
ACCEPT_UNSIGNED: frozenset[int] = frozenset({mavlink.MAVLINK_MSG_ID_HEARTBEAT, mavlink.MAVLINK_MSG_ID_RADIO_STATUS})

#: Results of :meth:`Signing.check`.
OK = 0
REJECT_UNSIGNED = 1
REJECT_BAD_SIGNATURE = 2
REJECT_OLD_TIMESTAMP = 3
REJECT_STREAM_WINDOW = 4
#: result -> counter name (as in :class:`smcpilot.link.LinkCounters`).
REJECT_REASONS: dict[int, str] = {
    REJECT_UNSIGNED: "rx_unsigned",
    REJECT_BAD_SIGNATURE: "rx_bad_signature",
    REJECT_OLD_TIMESTAMP: "rx_old_timestamp",
    REJECT_STREAM_WINDOW: "rx_stream_window",
}

_IFLAG_SIGNED = mavlink.MAVLINK_IFLAG_SIGNED
_SIGNATURE_BYTES = mavlink.MAVLINK_SIGNATURE_BLOCK_LEN  # 13
_MAGIC_V2 = mavlink.PROTOCOL_MARKER_V2
_HEADER_V2_BYTES = 10
_LINK_TS = struct.Struct("<BQ")
_TS48 = struct.Struct("<IH")
_MAX_TIMESTAMP = (1 << 48) - 1
_crc16 = mavlink.mcrf4xx
if _crc16 is None:  # pragma: no cover - pymavlink without fastcrc

    def _crc16(data: bytes, initial: int | None = None) -> int:
        crc = mavlink.x25crc()
        if initial is not None:
            crc.crc = initial
        crc.accumulate(bytes(data))
        return int(crc.crc)


_CRC_EXTRA: dict[int, int] = {mid: cls.crc_extra for mid, cls in mavlink.mavlink_map.items()}
_SETUP_SIGNING = mavlink.MAVLINK_MSG_ID_SETUP_SIGNING
#: secret_key's place in SETUP_SIGNING's payload (after initial_timestamp u64 and two u8 targets).
_SETUP_KEY_SLICE = slice(_HEADER_V2_BYTES + 10, _HEADER_V2_BYTES + 10 + KEY_BYTES)


class SigningKeyError(ConfigError):
    """A signing key file is missing, unreadable or holds neither 64 hex digits nor a passphrase."""


def key_from_text(text: str, *, source: str = "key") -> bytes:
    """The 32-byte key a key file's text stands for: 64 hex digits are the key, anything else on
    one line is a passphrase whose SHA-256 is the key (MAVProxy's ``signing setup``)."""
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    if len(lines) != 1:
        raise SigningKeyError(f"{source}: expected one line (64 hex digits, or a passphrase), found {len(lines)} non-empty lines")
    line = lines[0]
    if len(line) == 2 * KEY_BYTES and all(c in "0123456789abcdefABCDEF" for c in line):
        return bytes.fromhex(line)
    return hashlib.sha256(line.encode("utf-8")).digest()


def load_key(path: str | os.PathLike[str]) -> bytes:
    """Read a key file (see :func:`key_from_text`); :class:`SigningKeyError` naming the file if
    it cannot be read. The key is never printed."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise SigningKeyError(f"signing key file not found: {p}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise SigningKeyError(f"signing key file {p}: cannot read it: {exc}") from None
    key = key_from_text(text, source=f"signing key file {p}")
    if key == bytes(KEY_BYTES):
        raise SigningKeyError(f"signing key file {p}: the all-zero key means 'no signing'; use a real key")
    return key


def wall_timestamp(unix_s: float | None = None) -> int:
    """The signing timestamp of a wall-clock time (default now): 10 µs units since 2015-01-01."""
    t = time.time() if unix_s is None else unix_s
    return max(0, int((t - MAVLINK_EPOCH_UNIX_S) * TIMESTAMP_UNITS_PER_S))


def redact_setup_signing(packet: bytes) -> bytes:
    """A copy of a MAVLink 2 ``SETUP_SIGNING`` packet with its secret key zeroed and its CRC
    fixed (so logs stay readable and never hold the key); other packets unchanged."""
    if len(packet) < _HEADER_V2_BYTES + 2 or packet[0] != _MAGIC_V2 or (packet[7] | packet[8] << 8 | packet[9] << 16) != _SETUP_SIGNING:
        return packet
    body_end = _HEADER_V2_BYTES + packet[1]
    buf = bytearray(packet)
    start, stop = _SETUP_KEY_SLICE.start, min(_SETUP_KEY_SLICE.stop, body_end)
    if start < stop:
        buf[start:stop] = bytes(stop - start)
    crc = _crc16(bytes([_CRC_EXTRA[_SETUP_SIGNING]]), _crc16(bytes(buf[1:body_end])))
    buf[body_end : body_end + 2] = crc.to_bytes(2, "little")
    return bytes(buf)


class TimestampStore:
    """The saved outgoing signing timestamp (one decimal integer in a file).

    :meth:`boot` gives the timestamp to start from, ``max(wall, saved + margin)``; :meth:`start`
    runs a daemon thread that saves the latest timestamp every ``save_interval_s`` wall seconds
    (off the control loop); :meth:`close` saves once more. Saves are atomic: a kill at any moment
    leaves the previous or the new value, never a torn file; stale ``*.tmp`` leftovers of an
    interrupted save are removed at start.
    """

    def __init__(self, path: str | os.PathLike[str], *, save_interval_s: float = 10.0) -> None:
        if not save_interval_s > 0:
            raise ConfigError(f"save_interval_s must be > 0, got {save_interval_s!r}")
        self.path = Path(path)
        self.save_interval_s = float(save_interval_s)
        #: added to the saved value at boot: covers the timestamps used after the last save.
        self.margin = int(2 * self.save_interval_s * TIMESTAMP_UNITS_PER_S)
        self.saves = 0
        self._source: Callable[[], int] | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()
        self._last_saved = -1

    def load(self) -> int | None:
        """The saved timestamp, or None (no file, or a file that does not hold one)."""
        for leftover in self.path.parent.glob(self.path.name + ".*.tmp"):
            try:
                leftover.unlink()
            except OSError:
                pass
        try:
            text = self.path.read_text(encoding="ascii").strip()
        except (OSError, UnicodeDecodeError):
            return None
        return int(text) if text.isdigit() and int(text) <= _MAX_TIMESTAMP else None

    def boot(self, wall: int) -> int:
        """The timestamp to start from: ``max(wall, saved + margin)``."""
        saved = self.load()
        return wall if saved is None else max(wall, min(_MAX_TIMESTAMP, saved + self.margin))

    def save(self, timestamp: int) -> None:
        """Write ``timestamp`` atomically (temp file in the same directory, fsync, rename)."""
        with self._lock:
            if timestamp == self._last_saved:
                return
            self.path.parent.mkdir(parents=True, exist_ok=True)
            tmp = self.path.with_name(f"{self.path.name}.{os.getpid()}.tmp")
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
            try:
                os.write(fd, f"{timestamp}\n".encode("ascii"))
                os.fsync(fd)
            finally:
                os.close(fd)
            os.replace(tmp, self.path)
            try:
                dir_fd = os.open(self.path.parent, os.O_RDONLY)
            except OSError:  # pragma: no cover - e.g. a platform without directory fds
                pass
            else:
                try:
                    os.fsync(dir_fd)
                finally:
                    os.close(dir_fd)
            self._last_saved = timestamp
            self.saves += 1

    def start(self, source: Callable[[], int]) -> None:
        """Save ``source()`` every ``save_interval_s`` in a daemon thread until :meth:`close`."""
        self._source = source
        if self._thread is not None:
            return
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="signing-timestamps", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(self.save_interval_s):
            self._save_now()

    def _save_now(self) -> None:
        if self._source is not None:
            try:
                self.save(self._source())
            except OSError:
                pass  # retried at the next interval; the margin covers a missed save

    def close(self) -> None:
        """Stop the thread and save the latest timestamp (idempotent)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None
        self._save_now()


class Signing:
    """The signing state of one process, shared by all its links (see the module docstring).

    ``key`` None: signing off (every packet is sent unsigned and accepted as before); set it
    later with :meth:`set_key` (e.g. from ``SETUP_SIGNING``). ``wall_s`` is the wall clock (Unix
    seconds) the timestamps come from; ``store`` keeps them across restarts.
    """

    def __init__(
        self,
        key: bytes | None = None,
        *,
        store: TimestampStore | None = None,
        accept_unsigned: Iterable[int] = ACCEPT_UNSIGNED,
        wall_s: Callable[[], float] = time.time,
    ) -> None:
        self._wall_s = wall_s
        self.store = store
        self.accept_unsigned = frozenset(accept_unsigned)
        #: (system, component, link id) -> the last accepted timestamp of that stream.
        self.streams: dict[tuple[int, int, int], int] = {}
        wall = self._wall()
        self._timestamp = store.boot(wall) if store is not None else wall
        self._key: bytes | None = None
        self.set_key(key)

    # -- the key --------------------------------------------------------------------------------
    @property
    def enabled(self) -> bool:
        """True while a key is set: packets are signed and checked."""
        return self._key is not None

    def set_key(self, key: bytes | None, initial_timestamp: int = 0) -> None:
        """Use ``key`` from now on; None or the all-zero key turns signing off. The outgoing
        timestamp becomes at least ``initial_timestamp``. The stream table is cleared (streams
        signed with the old key mean nothing under the new one)."""
        if key is not None:
            key = bytes(key)
            if len(key) != KEY_BYTES:
                raise SigningKeyError(f"a signing key has {KEY_BYTES} bytes, got {len(key)}")
            if key == bytes(KEY_BYTES):
                key = None
        self._key = key
        self.streams.clear()
        if 0 < initial_timestamp <= _MAX_TIMESTAMP:
            self._timestamp = max(self._timestamp, initial_timestamp)
        if key is not None and self.store is not None:
            self.store.start(lambda: self._timestamp)

    @property
    def timestamp(self) -> int:
        """The last outgoing timestamp used (10 µs units since 2015-01-01)."""
        return self._timestamp

    def _wall(self) -> int:
        return wall_timestamp(self._wall_s())

    def next_timestamp(self) -> int:
        """A new outgoing timestamp: the wall clock, but strictly after the previous one."""
        t = self._timestamp + 1
        wall = self._wall()
        if wall > t:
            t = wall
        self._timestamp = t
        return t

    # -- sending --------------------------------------------------------------------------------
    def sign(self, packet: bytes, link_id: int) -> bytes:
        """The signed form of an unsigned MAVLink 2 ``packet`` (its signed flag set, the CRC
        recomputed, the 13-byte signature block appended). Signing must be enabled; MAVLink 1
        and already signed packets are returned unchanged."""
        key = self._key
        if key is None or packet[0] != _MAGIC_V2 or packet[2] & _IFLAG_SIGNED:
            return packet
        body_end = _HEADER_V2_BYTES + packet[1]
        msg_id = packet[7] | packet[8] << 8 | packet[9] << 16
        extra = _CRC_EXTRA.get(msg_id)
        if extra is None:
            return packet
        header = bytes((_MAGIC_V2, packet[1], packet[2] | _IFLAG_SIGNED)) + packet[3:body_end]
        crc = _crc16(bytes((extra,)), _crc16(header[1:]))
        signed = header + crc.to_bytes(2, "little") + _LINK_TS.pack(link_id & 0xFF, self.next_timestamp())[:7]
        return signed + hashlib.sha256(key + signed).digest()[:6]

    # -- receiving ------------------------------------------------------------------------------
    def check(self, packet: bytes | bytearray, msg_id: int, accept_unsigned: frozenset[int] | None = None) -> int:
        """:data:`OK` or the reason to drop one incoming packet whose CRC was good.

        Unsigned (or MAVLink 1) packets pass only if ``msg_id`` is in :attr:`accept_unsigned`
        (or in the ``accept_unsigned`` given, a link's own list).
        A signed packet passes if its signature is right and its timestamp is newer than its
        stream's last one (a new stream: within :data:`NEW_STREAM_WINDOW` of our clock); only
        then does the stream's timestamp advance (and ours, if it was behind).
        Always :data:`OK` while signing is off.
        """
        key = self._key
        if key is None:
            return OK
        if packet[0] != _MAGIC_V2 or not packet[2] & _IFLAG_SIGNED or len(packet) < _HEADER_V2_BYTES + 2 + _SIGNATURE_BYTES:
            accepted = self.accept_unsigned if accept_unsigned is None else accept_unsigned
            return OK if msg_id in accepted else REJECT_UNSIGNED
        raw = bytes(packet)
        expected = hashlib.sha256(key + raw[:-6]).digest()[:6]
        if not hmac.compare_digest(expected, raw[-6:]):
            return REJECT_BAD_SIGNATURE
        low, high = _TS48.unpack_from(raw, len(raw) - 12)
        timestamp = low | high << 32
        stream = (raw[5], raw[6], raw[-13])
        last = self.streams.get(stream)
        if last is not None:
            if timestamp <= last:
                return REJECT_OLD_TIMESTAMP
        elif abs(timestamp - self._wall()) > NEW_STREAM_WINDOW:
            return REJECT_STREAM_WINDOW
        self.streams[stream] = timestamp
        if timestamp > self._timestamp:
            self._timestamp = timestamp
        return OK

    def close(self) -> None:
        """Save the timestamp (if a store is kept) and stop its thread."""
        if self.store is not None:
            self.store.close()

    def __repr__(self) -> str:  # never the key
        return f"Signing(enabled={self.enabled}, streams={len(self.streams)})"
