"""Crash-safe files the FC writes, off the control loop.

:func:`atomic_write_text` writes a file so that a SIGKILL at any moment leaves the previous or the
new version, never a torn one: a temporary file beside it (``NAME.<random>.tmp``), ``fsync``,
``rename`` over the old one, ``fsync`` of the directory. :func:`clean_leftovers` removes the
temporary files of writes a kill interrupted (run at start, before the file is read).

:class:`BackgroundWriter` does those writes on a thread of its own, so that a ``PARAM_SET`` (or
a burst of 72) costs the control loop one reference assignment, not an ``fsync``: changes apply
at once in memory, :meth:`BackgroundWriter.submit` hands over the newest content, and the thread
writes only the newest one (a burst coalesces into one or two writes: group commit). Each
submission may carry a *token*; once the write that holds it is on disk (fsync of the file and of
its directory), the token comes back through :meth:`BackgroundWriter.completed` with the content
written, and only then does the FC acknowledge the change (a ``PARAM_VALUE``): what a ground
station was told is saved survives a SIGKILL. A write that fails hands its tokens to the next
write if one is pending, and back with the error if none is. :meth:`close` writes what is pending
and stops the thread (the FC calls it at exit).
"""

from __future__ import annotations

import os
import tempfile
import threading
from collections import deque
from collections.abc import Callable
from pathlib import Path

__all__ = ["BackgroundWriter", "atomic_write_text", "clean_leftovers", "TMP_SUFFIX"]

#: temporary files are ``<name>.<random>.tmp`` in the target's directory.
TMP_SUFFIX = ".tmp"


def atomic_write_text(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` atomically (temporary file + fsync + rename + directory fsync).
    Raises OSError; the temporary file is removed on any error."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=path.name + ".", suffix=TMP_SUFFIX, dir=str(path.parent))
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
    try:  # the rename itself survives a power cut only once the directory is on disk
        dfd = os.open(str(path.parent), os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(dfd)
    except OSError:
        pass
    finally:
        os.close(dfd)


def clean_leftovers(path: Path) -> list[Path]:
    """Remove the temporary files interrupted writes of ``path`` left (``NAME.*.tmp`` beside it);
    return those removed."""
    removed: list[Path] = []
    try:
        candidates = list(path.parent.glob(path.name + ".*" + TMP_SUFFIX))
    except OSError:
        return removed
    for tmp in candidates:
        try:
            tmp.unlink()
            removed.append(tmp)
        except OSError:
            pass
    return removed


class BackgroundWriter:
    """Writes the newest content of one file atomically on a daemon thread (see the module doc).

    ``render`` turns what :meth:`submit` was given into the file's text; it runs on the writer
    thread (give it immutable values). ``on_error`` hears an OSError of a write (on the writer
    thread; keep it cheap and thread-safe, e.g. a counter).
    """

    def __init__(self, path: Path, render: Callable[[object], str], on_error: Callable[[OSError], None] | None = None) -> None:
        self.path = path
        self._render = render
        self._on_error = on_error
        self._cond = threading.Condition()
        self._pending: object | None = None
        self._has_pending = False
        #: tokens of the submissions the pending content holds.
        self._tokens: list[object] = []
        #: (content written or None, its tokens, the OSError or None), appended by the writer thread
        #: as writes end, taken by :meth:`completed` (a deque: appends and pops are thread-safe).
        self._done: deque[tuple[object | None, list[object], OSError | None]] = deque()
        self._busy = False
        self._closed = False
        #: writes done, submissions received (writes <= submissions: a burst coalesces).
        self.writes = 0
        self.submissions = 0
        self.errors = 0
        self._thread = threading.Thread(target=self._run, name=f"writer:{path.name}", daemon=True)
        self._thread.start()

    def submit(self, content: object, token: object | None = None) -> None:
        """Hand over the newest content (returns at once; replaces anything not yet written); the
        ``token`` comes back through :meth:`completed` once a write holding this content is durable."""
        with self._cond:
            if self._closed:
                raise RuntimeError("writer closed")
            self._pending = content
            self._has_pending = True
            if token is not None:
                self._tokens.append(token)
            self.submissions += 1
            self._cond.notify()

    def completed(self) -> list[tuple[object | None, list[object], OSError | None]]:
        """The writes that ended since the last call, oldest first: (the content on disk now, the
        tokens it made durable, None) or (None, the tokens that could not be made durable, the error)."""
        out = []
        done = self._done
        while done:
            out.append(done.popleft())
        return out

    def flush(self, timeout_s: float | None = 10.0) -> bool:
        """Wait until everything submitted is on disk; False on timeout."""
        with self._cond:
            return self._cond.wait_for(lambda: not self._has_pending and not self._busy, timeout_s)

    def close(self, timeout_s: float = 10.0) -> None:
        """Write what is pending, then stop the thread. Idempotent."""
        with self._cond:
            if self._closed:
                return
            self._closed = True
            self._cond.notify_all()
        self._thread.join(timeout_s)

    def _run(self) -> None:
        while True:
            with self._cond:
                self._cond.wait_for(lambda: self._has_pending or self._closed)
                if not self._has_pending:
                    self._cond.notify_all()
                    return
                content = self._pending
                tokens = self._tokens
                self._pending = None
                self._tokens = []
                self._has_pending = False
                self._busy = True
            try:
                atomic_write_text(self.path, self._render(content))
                self.writes += 1
                self._done.append((content, tokens, None))
            except OSError as exc:
                self.errors += 1
                with self._cond:
                    if self._has_pending:  # the next write holds these changes too: it answers for them
                        self._tokens[:0] = tokens
                        tokens = []
                if tokens:
                    self._done.append((None, tokens, exc))
                if self._on_error is not None:
                    self._on_error(exc)
            finally:
                with self._cond:
                    self._busy = False
                    self._cond.notify_all()
