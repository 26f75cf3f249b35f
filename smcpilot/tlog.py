"""Telemetry logs in the standard ``.tlog`` format (QGroundControl, MAVProxy, pymavlink).

A ``.tlog`` is a plain concatenation of records; each record is an 8-byte big-endian unsigned
timestamp in microseconds followed by one raw MAVLink packet (v1 or v2, exactly as on the wire).
There is no file header, so any prefix made of whole records is itself a valid log.

:class:`TlogWriter` keeps whole records in a memory buffer and hands them to the operating system
with ``os.write`` only as whole records: a log cut short by a crash still ends on a record
boundary. Records the owner has written reach the file when the buffer fills, on :meth:`flush`
and on :meth:`close`. A process killed by SIGTERM runs no ``finally`` blocks unless the SIGTERM
handler raises (``signal.signal(signal.SIGTERM, lambda signum, frame: sys.exit(143))`` does), so
an owner that wants every record on disk installs such a handler and closes the writer in a
``finally`` or ``with`` block.

:func:`read_tlog` reads a log back as ``(time_us, message)`` pairs with exact integer timestamps
(pymavlink's own reader turns them into float seconds). It also reads a gzip-compressed log
(``.tlog.gz``, written by :func:`compress_tlog`; ``smcpilot log compress``), which pymavlink
itself does not: ``gunzip -k LOG.tlog.gz`` gives its plain ``.tlog`` back, byte for byte.
"""

from __future__ import annotations

import gzip
import os
import shutil
import struct
from collections.abc import Iterable, Iterator
from pathlib import Path
from types import TracebackType

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from smcpilot.errors import TlogError, TlogFormatError

__all__ = ["TlogWriter", "read_tlog", "compress_tlog", "GZIP_SUFFIX", "TIMESTAMP_BYTES"]

#: Suffix of a compressed log: ``flight.tlog`` -> ``flight.tlog.gz``.
GZIP_SUFFIX = ".gz"

#: Size of the timestamp that precedes every packet in a ``.tlog``.
TIMESTAMP_BYTES = 8

_TIMESTAMP = struct.Struct(">Q")
_TIMESTAMP_PACK = _TIMESTAMP.pack
_MAX_TIME_US = 2**64 - 1

_MAGIC_V1 = mavlink.PROTOCOL_MARKER_V1
_MAGIC_V2 = mavlink.PROTOCOL_MARKER_V2
_HEADER_V1_BYTES = 6
_HEADER_V2_BYTES = 10
_CRC_BYTES = 2
_SIGNATURE_BYTES = mavlink.MAVLINK_SIGNATURE_BLOCK_LEN
_IFLAG_SIGNED = mavlink.MAVLINK_IFLAG_SIGNED
_READ_CHUNK_BYTES = 1 << 20


class TlogWriter:
    """Write MAVLink packets with timestamps to a new ``.tlog`` file (truncates an existing one).

    Not thread-safe: one owner writes. Use as a context manager, or call :meth:`close` in a
    ``finally`` block.
    """

    def __init__(self, path: str | os.PathLike[str], *, buffer_bytes: int = 64 * 1024) -> None:
        """Create (or truncate) ``path``; records are buffered up to about ``buffer_bytes``."""
        if buffer_bytes < 0:
            raise TlogError(f"{path}: buffer_bytes must be >= 0, got {buffer_bytes}")
        self._path = Path(path)
        self._buffer_limit_bytes = buffer_bytes
        self._buffer = bytearray()
        self._records_written = 0
        try:
            self._fd = os.open(
                self._path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | getattr(os, "O_CLOEXEC", 0), 0o644
            )
        except OSError as exc:
            raise TlogError(f"cannot create tlog {self._path}: {exc.strerror}") from exc

    @property
    def path(self) -> Path:
        """The log file."""
        return self._path

    @property
    def closed(self) -> bool:
        """True once :meth:`close` has run."""
        return self._fd < 0

    @property
    def records_written(self) -> int:
        """Number of records accepted by :meth:`write` / :meth:`write_many` so far."""
        return self._records_written

    def write(self, time_us: int, packet: bytes | bytearray) -> None:
        """Append one record: ``time_us`` (µs, 0 ≤ t < 2**64) then the raw MAVLink ``packet``."""
        if self._fd < 0:
            raise TlogError(f"tlog {self._path} is closed")
        buffer = self._buffer
        try:
            buffer += _TIMESTAMP_PACK(time_us)
        except struct.error as exc:
            raise TlogError(
                f"tlog {self._path}: timestamp must be an integer in [0, {_MAX_TIME_US}] µs, got {time_us!r}"
            ) from exc
        buffer += packet
        self._records_written += 1
        if len(buffer) >= self._buffer_limit_bytes:
            self._drain()

    def write_many(self, time_us: int, packets: Iterable[bytes | bytearray]) -> None:
        """Append one record per packet, all with the same timestamp ``time_us``."""
        if self._fd < 0:
            raise TlogError(f"tlog {self._path} is closed")
        try:
            stamp = _TIMESTAMP_PACK(time_us)
        except struct.error as exc:
            raise TlogError(
                f"tlog {self._path}: timestamp must be an integer in [0, {_MAX_TIME_US}] µs, got {time_us!r}"
            ) from exc
        buffer = self._buffer
        for packet in packets:
            buffer += stamp
            buffer += packet
            self._records_written += 1
        if len(buffer) >= self._buffer_limit_bytes:
            self._drain()

    def write_records(self, records: bytes | bytearray, count: int) -> None:
        """Append ``count`` records already made (each a big-endian uint64 stamp in µs, then a raw
        MAVLink packet: e.g. a compiled tick's, :mod:`fc.lockstep_kernel`)."""
        if self._fd < 0:
            raise TlogError(f"tlog {self._path} is closed")
        buffer = self._buffer
        buffer += records
        self._records_written += count
        if len(buffer) >= self._buffer_limit_bytes:
            self._drain()

    def flush(self, *, fsync: bool = False) -> None:
        """Hand every buffered record to the OS; with ``fsync`` also wait until it is on disk."""
        if self._fd < 0:
            raise TlogError(f"tlog {self._path} is closed")
        self._drain()
        if fsync:
            os.fsync(self._fd)

    def close(self) -> None:
        """Flush and close the file. Calling it again does nothing."""
        if self._fd < 0:
            return
        try:
            self._drain()
        finally:
            fd, self._fd = self._fd, -1
            os.close(fd)

    def _drain(self) -> None:
        buffer = self._buffer
        if not buffer:
            return
        view = memoryview(buffer)
        written = 0
        try:
            while written < len(buffer):
                written += os.write(self._fd, view[written:])
        except OSError as exc:
            raise TlogError(f"cannot write tlog {self._path}: {exc.strerror}") from exc
        finally:
            view.release()
            del buffer[:written]

    def __enter__(self) -> TlogWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.close()

    def __repr__(self) -> str:
        state = "closed" if self.closed else f"{self._records_written} records"
        return f"TlogWriter({str(self._path)!r}, {state})"


def read_tlog(path: str | os.PathLike[str]) -> Iterator[tuple[int, mavlink.MAVLink_message]]:
    """Yield ``(time_us, message)`` for every record of the ``.tlog`` at ``path``, in file order.

    Messages are decoded by pymavlink (ardupilotmega dialect, which includes common); an id the
    dialect does not know is yielded as ``MAVLink_unknown``. Each message also gets pymavlink's
    ``_timestamp`` attribute (float seconds). A bad magic byte, a bad CRC or a record cut short
    raises :class:`~smcpilot.errors.TlogFormatError` naming the byte offset, after every record
    before it has been yielded.
    """
    decoder = mavlink.MAVLink(None)
    decode = decoder.decode
    path = Path(path)
    try:
        handle = gzip.open(path, "rb") if path.name.endswith(GZIP_SUFFIX) else open(path, "rb")
    except OSError as exc:
        raise TlogError(f"cannot open tlog {path}: {exc.strerror}") from exc
    with handle:
        data = bytearray()
        start = 0  # index into data of the next record
        offset = 0  # file offset of data[0]
        at_eof = False
        while True:
            if not at_eof and len(data) - start < 8 + 280 + _SIGNATURE_BYTES:
                del data[:start]
                offset += start
                start = 0
                try:
                    chunk = handle.read(_READ_CHUNK_BYTES)
                except (OSError, EOFError) as exc:  # a damaged or cut .tlog.gz
                    raise TlogFormatError(f"{path}: cannot decompress after byte {offset + len(data)}: {exc}") from exc
                if chunk:
                    data += chunk
                else:
                    at_eof = True
            available = len(data) - start
            if available == 0 and at_eof:
                return
            where = offset + start
            if available < TIMESTAMP_BYTES + 3:
                if at_eof:
                    raise TlogFormatError(f"{path}: record at byte {where} is cut short")
                continue
            magic = data[start + TIMESTAMP_BYTES]
            length = data[start + TIMESTAMP_BYTES + 1]
            if magic == _MAGIC_V2:
                flags = data[start + TIMESTAMP_BYTES + 2]
                total = _HEADER_V2_BYTES + length + _CRC_BYTES
                if flags & _IFLAG_SIGNED:
                    total += _SIGNATURE_BYTES
            elif magic == _MAGIC_V1:
                total = _HEADER_V1_BYTES + length + _CRC_BYTES
            else:
                raise TlogFormatError(
                    f"{path}: record at byte {where} does not hold a MAVLink packet (byte 0x{magic:02x} "
                    f"after the timestamp, expected 0xfd or 0xfe)"
                )
            end = start + TIMESTAMP_BYTES + total
            if end > len(data):
                if at_eof:
                    raise TlogFormatError(f"{path}: record at byte {where} is cut short")
                continue
            (time_us,) = _TIMESTAMP.unpack_from(data, start)
            try:
                message = decode(data[start + TIMESTAMP_BYTES : end])
            except mavlink.MAVError as exc:
                raise TlogFormatError(f"{path}: bad MAVLink packet at byte {where + TIMESTAMP_BYTES}: {exc}") from exc
            message._timestamp = time_us * 1.0e-6
            start = end
            yield time_us, message


def compress_tlog(path: str | os.PathLike[str], *, level: int = 6) -> Path:
    """Compress the ``.tlog`` at ``path`` to ``path + '.gz'`` (gzip) and delete the original.

    The compressed file is written beside it under a temporary name and renamed only when
    complete, so an interrupted call leaves the original in place. Returns the new path.
    """
    src = Path(path)
    dst = src.with_name(src.name + GZIP_SUFFIX)
    tmp = src.with_name(src.name + GZIP_SUFFIX + ".part")
    try:
        with open(src, "rb") as fin, open(tmp, "wb") as raw:
            with gzip.GzipFile(filename=src.name, mode="wb", compresslevel=level, fileobj=raw) as fout:
                shutil.copyfileobj(fin, fout, _READ_CHUNK_BYTES)
        os.replace(tmp, dst)
        src.unlink()
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise TlogError(f"cannot compress tlog {src}: {exc.strerror or exc}") from exc
    return dst
