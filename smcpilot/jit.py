"""The project's one way to compile: pure functions, with numba when it is there.

The hot path (the pipeline, the laws, the estimate, the plant, the flight kernel of
:mod:`lab.fast`) is written once, as plain Python functions in the pure style
(:mod:`fc.control.purity`). CPython runs them as they are. :func:`compile_pure` makes compiled
*twins* of a set of them: each twin is the same code with its own copy of the module's globals in
which every other function of the set is its twin, so compiled code calls compiled code, and the
originals stay untouched (CPython callers keep calling plain Python, never a compiled function
once per tick with its arguments unboxed: that crossing is what costs).

Switches: ``SMCPILOT_JIT=0`` (or numba's own ``NUMBA_DISABLE_JIT=1``) runs everything in CPython;
a platform without numba does the same and says so once. Nothing imports numba until a compiled
path is first used, so commands that do not fly (``--help``, ``gcs``, ``log``) never load it.

Compiled code is cached on disk (numba's cache: next to the sources when that is writable, else in
the user's cache directory). A twin's name carries a hash of the sources of the whole set it was
compiled with, so a change in any function of the set compiles afresh instead of reusing code
compiled from older sources (numba itself checks only the file of the function it caches).
"""

from __future__ import annotations

import hashlib
import inspect
import os
import sys
import types
from collections.abc import Callable, Iterable, Mapping
from typing import Any

__all__ = [
    "JIT_ENV",
    "jit_enabled",
    "jit_unavailable_reason",
    "numba_module",
    "compile_pure",
    "sources_hash",
    "say_once",
    "addressed",
    "cache_index",
    "AUTO_MIN_LOCKSTEP_S",
    "JIT_POLICIES",
    "compile_in_background",
    "compile_lock",
    "release_compile_lock",
]

#: the processes' ``--jit`` choices: use the compiled code when it is cached (else fly in CPython
#: and compile it in the background for later runs); compile it first if need be; never.
JIT_POLICIES = ("auto", "wait", "off")
#: ``--jit auto`` loads compiled code in a lockstep flight at least this long (or open-ended): loading
#: costs a process about a second of CPU (numba's import and registries), which a tick some
#: 15-25 µs cheaper repays in about a minute of flight.
AUTO_MIN_LOCKSTEP_S = 60.0

#: environment variable: "0" (or "off", "false", "no") runs every compiled path in CPython.
JIT_ENV = "SMCPILOT_JIT"
_OFF = {"0", "off", "false", "no"}
_said: set[str] = set()


def say_once(text: str) -> None:
    """Print ``text`` to stderr once per process (notes about compiling and fallbacks)."""
    if text in _said:
        return
    _said.add(text)
    print(f"smcpilot: {text}", file=sys.stderr, flush=True)


def jit_unavailable_reason() -> str | None:
    """Why compiled paths are off in this process (None: they are on)."""
    if os.environ.get(JIT_ENV, "").strip().lower() in _OFF:
        return f"{JIT_ENV}={os.environ[JIT_ENV]}"
    if os.environ.get("NUMBA_DISABLE_JIT", "").strip() not in ("", "0"):
        return "NUMBA_DISABLE_JIT is set"
    try:
        import numba  # noqa: F401
    except Exception as exc:  # no wheel for this platform, or a broken install
        return f"numba is not available ({type(exc).__name__}: {exc})"
    return None


def jit_enabled(*, say: bool = True) -> bool:
    """Compiled paths are on: numba imports and neither switch turns them off. When they are
    off, says why once (with ``say``)."""
    why = jit_unavailable_reason()
    if why is not None and say:
        say_once(f"compiled flight path off ({why}): flying in CPython, the same code, slower")
    return why is None


def numba_module() -> Any:
    """numba (imported on first use)."""
    import numba

    return numba


def sources_hash(functions: Iterable[Callable[..., Any]], extra: str = "") -> str:
    """A short hash of the source files of ``functions`` (and ``extra``): names cache entries."""
    h = hashlib.sha256(extra.encode())
    files = sorted({inspect.getsourcefile(f) or f.__code__.co_filename for f in functions})
    for path in files:
        try:
            with open(path, "rb") as fh:
                h.update(fh.read())
        except OSError:
            h.update(path.encode())
    return h.hexdigest()[:12]


def compile_pure(
    functions: Iterable[Callable[..., Any]],
    *,
    cache: bool = True,
    rebind: Mapping[Callable[..., Any], Mapping[str, Any]] | None = None,
    inline: Iterable[Callable[..., Any]] = (),
) -> dict[Callable[..., Any], Any]:
    """Compiled twins of ``functions`` (a closed set: every pure function they call by name is in
    it): ``{original: numba dispatcher}``. Compilation itself happens lazily, at a twin's first
    call with new argument types.

    ``rebind`` gives a function of the set its own globals in which some names call other
    functions of the set (e.g. a kernel written against one step function, compiled with another),
    or name a tuple (a NamedTuple) of functions of the set: the tuple of their twins, which
    compiled code calls directly, as constants.
    Twins use numba's "numpy" error model: a division by zero gives inf or NaN instead of raising,
    so compiled code never stops half-way; callers check what comes out for finiteness and let
    CPython fly the step that went wrong, which raises as it always has.

    ``inline``: functions of the set whose twins are inlined into their compiled callers (numba's
    ``inline="always"``, at the level of its own IR), so a caller that calls them every tick pays
    no call: neither the copying of their tuple arguments (some hundreds of floats for a pipeline's
    parameters) nor the barrier a call puts in the optimiser's way. The same operations on the same
    values: the results do not change by a bit. The choice is part of the twins' names, so cached
    code compiled with another choice is never reused.
    """
    numba = numba_module()
    fns: tuple[Any, ...] = tuple(dict.fromkeys(functions))
    rebind = rebind or {}
    inlined = frozenset(inline)
    tag = sources_hash(fns, extra=repr(sorted((f.__qualname__, sorted((n, _rebound_name(t)) for n, t in m.items())) for f, m in rebind.items()))
                       + (repr(sorted(f"{f.__module__}.{f.__qualname__}" for f in inlined)) if inlined else ""))
    per_module: dict[int, dict[str, Any]] = {}  # one globals copy per module; a rebound function gets its own
    copies: list[tuple[dict[str, Any], Mapping[str, Callable[..., Any]]]] = []
    twins: dict[Callable[..., Any], Any] = {}
    for f in fns:
        g = per_module.get(id(f.__globals__))
        if g is None or f in rebind:
            g = dict(f.__globals__)
            copies.append((g, rebind.get(f, {})))
            if f not in rebind:
                per_module[id(f.__globals__)] = g
        twin = types.FunctionType(f.__code__, g, f.__name__, f.__defaults__, f.__closure__)
        twin.__qualname__ = f"{f.__qualname__}__{tag}"
        twin.__module__ = f.__module__
        twin.__doc__ = f.__doc__
        twins[f] = numba.njit(cache=cache, error_model="numpy", inline="always" if f in inlined else "never")(twin)
    for g, names in copies:  # now every twin exists: point the copies' names at them
        for name, value in list(g.items()):
            if isinstance(value, types.FunctionType) and value in twins:
                g[name] = twins[value]
        for name, target in names.items():
            g[name] = type(target)(*(twins[t] for t in target)) if isinstance(target, tuple) else twins[target]
    return twins


def _rebound_name(target: Any) -> str:
    """What :func:`compile_pure`'s tag records of a rebound name's target (a function, or a tuple of them)."""
    if isinstance(target, tuple):
        return f"{type(target).__name__}({', '.join(t.__qualname__ for t in target)})"
    return str(target.__qualname__)


_ADDRESSED: Any = None


def addressed(dispatcher: Any, sig: Any) -> Any:
    """A compiled function (``dispatcher``'s overload for ``sig``) as a first-class function object
    numba unboxes from its address (the wrapper address protocol) instead of looking the address
    up on every call: what a compiled entry point takes for a law's functions."""
    global _ADDRESSED
    if _ADDRESSED is None:

        class Addressed(numba_module().types.WrapperAddressProtocol):  # type: ignore[misc,name-defined]
            def __init__(self, fn: Any, sig: Any, addr: int) -> None:
                self.fn, self.sig, self.addr = fn, sig, addr  # fn: keeps the compiled code alive

            def __wrapper_address__(self) -> int:
                return self.addr

            def signature(self) -> Any:
                return self.sig

        _ADDRESSED = Addressed
    cres = dispatcher.overloads[sig.args]
    addr = cres.library.get_pointer_to_function(cres.fndesc.llvm_cfunc_wrapper_name)
    return _ADDRESSED(dispatcher, sig, addr)


def cache_index(dispatcher: Any) -> str | None:
    """Where numba keeps the on-disk cache index of ``dispatcher`` (None: unknown); it exists once
    the dispatcher has been compiled and cached for some signature."""
    try:
        return str(dispatcher._cache._cache_file._index_path)
    except AttributeError:
        return None


def entry_point(dispatcher: Any, sig: Any) -> Any:
    """``dispatcher`` compiled (or loaded from the cache) for ``sig``: its entry point, called
    without numba's dispatch on the argument types."""
    dispatcher.compile(sig)
    return dispatcher.overloads[sig].entry_point


def cached_entry(dispatcher: Any, sig: Any, *, compile_new: bool) -> Any:
    """:func:`entry_point` when it is in the on-disk cache, or compiled first when ``compile_new``;
    None when it is not cached and not ``compile_new``."""
    index = cache_index(dispatcher)
    if not compile_new and (index is None or not os.path.exists(index)):
        return None
    return entry_point(dispatcher, sig)


def _lock_path() -> str:
    import tempfile

    return os.path.join(tempfile.gettempdir(), f"smcpilot-compile-{os.getuid() if hasattr(os, 'getuid') else 0}.lock")


_LOCK: Any = None


def compile_lock(*, blocking: bool) -> Any:
    """The machine-wide compile lock (an advisory lock on a file in the temporary directory,
    released when its holder exits): one background compile at a time on a machine. The lock
    (truthy), or None when another process holds it and ``blocking`` is False."""
    global _LOCK
    try:
        import fcntl
    except ImportError:  # no advisory locks here: compile anyway
        return True
    f = open(_lock_path(), "a")  # noqa: SIM115 (held until release or exit)
    try:
        fcntl.flock(f, fcntl.LOCK_EX | (0 if blocking else fcntl.LOCK_NB))
    except OSError:
        f.close()
        return None
    _LOCK = f
    return f


def release_compile_lock() -> None:
    """Release :func:`compile_lock` (if this process holds it)."""
    global _LOCK
    if _LOCK is not None:
        _LOCK.close()
        _LOCK = None


def compile_in_background(module: str, *args: str) -> int | None:
    """Start ``python -m module args...`` (a command that compiles and caches something, at a low
    priority, under :func:`compile_lock`), unless another process is compiling: its pid, or None
    when none was started. Later processes then load what it cached."""
    import subprocess

    if compile_lock(blocking=False) is None:
        return None  # another process compiles: it holds the lock (released when it exits)
    release_compile_lock()
    proc = subprocess.Popen(
        [sys.executable, "-m", module, *args],
        stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
    )  # fmt: skip
    return proc.pid
