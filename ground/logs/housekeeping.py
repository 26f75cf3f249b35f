"""Keeping a log directory small: compress flight logs, delete old flights.

A *flight* in a log directory is a ``.tlog`` (or a compressed ``.tlog.gz``) and what every SITL
launch leaves beside it under the same stem: ``<stem>.scenario.toml`` (to fly it again), the
run's own parameter file ``<stem>.parm`` and ``<stem>-plots/`` (``smcpilot plot``'s default).
Other files (a parameter file kept with ``--param-file``, say) belong to no flight and are never
touched. Flights are ordered by the modification time of their log.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass, field
from pathlib import Path

from ground.logs.load import LogError
from smcpilot.errors import TlogError
from smcpilot.tlog import GZIP_SUFFIX, compress_tlog

__all__ = ["DEFAULT_KEEP", "KEEP_PLAIN", "IDLE_S", "compress_old_flights", "CleanReport", "CompressResult", "clean_logs", "compress_logs", "flight_stem", "format_bytes"]

#: Flights ``smcpilot log clean`` keeps by default.
DEFAULT_KEEP = 10

#: Newest flights whose logs ``smcpilot sitl`` / ``demo`` leave uncompressed (for pymavlink).
KEEP_PLAIN = 5

#: A log not modified for this many seconds is no longer being written (the FC writes several
#: times a second while it runs, even on the ground).
IDLE_S = 60.0

_TLOG = ".tlog"


def flight_stem(log: Path) -> str:
    """``a/b/sitl-1.tlog`` or ``a/b/sitl-1.tlog.gz`` -> ``sitl-1``."""
    name = log.name
    for suffix in (_TLOG + GZIP_SUFFIX, _TLOG):
        if name.endswith(suffix):
            return name[: -len(suffix)]
    return log.stem


def format_bytes(n: int) -> str:
    """``9751416`` -> ``9.75 MB`` (decimal units, as ``ls -h --si`` and disk makers count)."""
    for unit, scale in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= scale:
            return f"{n / scale:.2f} {unit}"
    return f"{n} B"


@dataclass(frozen=True)
class CompressResult:
    """One compressed log: the new path and the sizes before and after, bytes."""

    path: Path
    bytes_before: int
    bytes_after: int


def _tlogs_in(paths: list[Path]) -> list[Path]:
    out: list[Path] = []
    for p in paths:
        if p.is_dir():
            out.extend(sorted(q for q in p.iterdir() if q.name.endswith(_TLOG) and q.is_file()))
        elif p.name.endswith(_TLOG + GZIP_SUFFIX):
            continue  # already compressed
        elif p.is_file():
            out.append(p)
        else:
            raise LogError(f"no such log or directory: {p}")
    return out


def compress_logs(paths: list[Path]) -> list[CompressResult]:
    """Compress every ``.tlog`` named or found in the directories named (not recursively)."""
    results = []
    for log in _tlogs_in(paths):
        before = log.stat().st_size
        try:
            new = compress_tlog(log)
        except TlogError as exc:
            raise LogError(str(exc)) from None
        results.append(CompressResult(new, before, new.stat().st_size))
    return results


@dataclass
class CleanReport:
    """What :func:`clean_logs` did (or would do): flights found, paths touched, bytes freed."""

    flights: int = 0
    touched: list[Path] = field(default_factory=list)
    bytes_freed: int = 0


def _size(path: Path) -> int:
    if path.is_dir():
        return sum(q.stat().st_size for q in path.rglob("*") if q.is_file())
    return path.stat().st_size


def clean_logs(directory: Path, *, keep: int = DEFAULT_KEEP, compress: bool = False, dry_run: bool = False) -> CleanReport:
    """Delete (or with ``compress`` gzip) every flight in ``directory`` but the newest ``keep``."""
    if not directory.is_dir():
        raise LogError(f"no such log directory: {directory}")
    logs = [q for q in directory.iterdir() if q.is_file() and (q.name.endswith(_TLOG) or q.name.endswith(_TLOG + GZIP_SUFFIX))]
    logs.sort(key=lambda q: (q.stat().st_mtime, q.name), reverse=True)
    report = CleanReport(flights=len(logs))
    for log in logs[keep:]:
        if compress:
            if log.name.endswith(GZIP_SUFFIX):
                continue
            before = log.stat().st_size
            report.touched.append(log)
            if dry_run:
                continue
            try:
                after = compress_tlog(log).stat().st_size
            except TlogError as exc:
                raise LogError(str(exc)) from None
            report.bytes_freed += before - after
            continue
        stem = flight_stem(log)
        for path in (log, directory / f"{stem}.scenario.toml", directory / f"{stem}.parm", directory / f"{stem}-plots"):
            if not path.exists():
                continue
            report.touched.append(path)
            report.bytes_freed += _size(path)
            if dry_run:
                continue
            if path.is_dir():
                shutil.rmtree(path)
            else:
                path.unlink()
    return report


def compress_old_flights(directory: Path, *, keep_plain: int = KEEP_PLAIN, idle_s: float = IDLE_S, now_s: float | None = None) -> list[CompressResult]:
    """Compress the plain logs in ``directory`` older than its newest ``keep_plain`` flights and idle
    for ``idle_s`` seconds (so never a log still being written). What ``smcpilot sitl`` and
    ``smcpilot demo`` do after each flight, so that a log directory grows by about 40 % of each
    flight's size rather than all of it."""
    import time

    if not directory.is_dir():
        return []
    now = time.time() if now_s is None else now_s
    logs = [q for q in directory.iterdir() if q.is_file() and (q.name.endswith(_TLOG) or q.name.endswith(_TLOG + GZIP_SUFFIX))]
    logs.sort(key=lambda q: (q.stat().st_mtime, q.name), reverse=True)
    old = [q for q in logs[keep_plain:] if q.name.endswith(_TLOG) and now - q.stat().st_mtime >= idle_s]
    try:
        return compress_logs(old)
    except LogError:
        return []  # housekeeping must never fail a flight that has been flown
