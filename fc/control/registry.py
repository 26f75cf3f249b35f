"""Which laws exist: the built-ins, installed plug-ins and laws loaded from a file or a module.

A law is named by a **reference**:

- a built-in's name (``adaptive_pid_smc``, ``pid_smc``, ``cascade_pid``, ``sign_smc``);
- the name of an installed plug-in: an entry point in the group ``smcpilot.laws`` whose object is a
  :class:`fc.control.law.Law` (``[project.entry-points."smcpilot.laws"] my_law = "pkg.mod:LAW"``);
- ``path/to/file.py:NAME`` or ``package.module:NAME`` for code that is not packaged (``NAME`` a
  Law, or a function of no arguments returning one).

:func:`resolve` loads and validates one (:class:`fc.control.law.LawError` naming it otherwise);
loaded laws are kept for the process, as imported modules are. :func:`flight_laws` is the FC's
table: the built-ins in their fixed order, then every plug-in loaded so far, in load order -- the
values of ``FC_CONTROLLER``.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import sys
from dataclasses import replace
from importlib import metadata
from pathlib import Path

from fc.control.builtin import BUILTIN_LAWS
from fc.control.law import Law, LawError, validate_law
from smcpilot.lawref import is_file_reference, normalise_reference, note_loaded

__all__ = ["ENTRY_POINT_GROUP", "builtin_names", "entry_points", "flight_laws", "is_file_reference", "load_installed", "normalise_reference", "plugin_laws", "resolve"]

ENTRY_POINT_GROUP = "smcpilot.laws"
_BUILTIN = {law.name: law for law in BUILTIN_LAWS}
#: plug-ins loaded in this process, by name, in load order.
_PLUGINS: dict[str, Law] = {}
#: reference -> law name (a file reference resolves to the law it defines).
_REFS: dict[str, str] = {}


def builtin_names() -> tuple[str, ...]:
    return tuple(_BUILTIN)


def entry_points() -> dict[str, metadata.EntryPoint]:
    """The installed plug-ins' entry points, by name (not loaded)."""
    return {ep.name: ep for ep in metadata.entry_points(group=ENTRY_POINT_GROUP)}


def _register(law: object, where: str, origin: str) -> Law:
    if callable(law) and not isinstance(law, Law):
        try:
            law = law()
        except Exception as exc:  # a plug-in's own code: any error is its author's to read
            raise LawError(f"{where}: calling it to build the law failed: {type(exc).__name__}: {exc}") from None
    checked = validate_law(law, where)
    if checked.origin == "built-in":
        checked = replace(checked, origin=origin)
    name = checked.name
    if name in _BUILTIN:
        raise LawError(f"{where}: law name {name!r} is a built-in law's; choose another name")
    old = _PLUGINS.get(name)
    if old is not None and old.origin != checked.origin:
        raise LawError(f"{where}: law name {name!r} is already taken by {old.origin}")
    if old is not None:
        return old
    _PLUGINS[name] = checked
    note_loaded(name)
    return checked


def _load_object(ref: str) -> tuple[object, str]:
    """(the object a ``file.py:NAME`` / ``module:NAME`` reference names, its origin)."""
    head, _, attr = ref.rpartition(":")
    if not head or not attr.isidentifier():
        raise LawError(f"law {ref!r}: expected NAME, path/to/file.py:NAME or package.module:NAME")
    if is_file_reference(ref):
        path = Path(head).expanduser().resolve()
        if not path.is_file():
            raise LawError(f"law {ref!r}: no such file {path}")
        mod_name = "smcpilot_law_" + hashlib.sha1(str(path).encode()).hexdigest()[:12]
        module = sys.modules.get(mod_name)
        if module is None:
            spec = importlib.util.spec_from_file_location(mod_name, path)
            if spec is None or spec.loader is None:
                raise LawError(f"law {ref!r}: cannot import {path}")
            module = importlib.util.module_from_spec(spec)
            sys.modules[mod_name] = module
            try:
                spec.loader.exec_module(module)
            except Exception as exc:  # the plug-in's own code
                del sys.modules[mod_name]
                raise LawError(f"law {ref!r}: importing {path} failed: {type(exc).__name__}: {exc}") from None
        origin = f"file {path}"
    else:
        try:
            module = importlib.import_module(head)
        except Exception as exc:  # the plug-in's own code
            raise LawError(f"law {ref!r}: importing module {head} failed: {type(exc).__name__}: {exc}") from None
        origin = f"module {head}"
    if not hasattr(module, attr):
        raise LawError(f"law {ref!r}: {head} has no {attr}")
    return getattr(module, attr), origin


def _load_entry_point(ep: metadata.EntryPoint) -> Law:
    where = f"plug-in {ep.name!r} ({ep.value})"
    try:
        obj = ep.load()
    except Exception as exc:  # the plug-in's own code
        raise LawError(f"{where}: loading failed: {type(exc).__name__}: {exc}") from None
    dist = getattr(ep, "dist", None)
    law = _register(obj, where, f"entry point {dist.name if dist is not None else ep.value}")
    if law.name != ep.name:
        raise LawError(f"{where}: the entry point's name must be the law's name, {law.name!r}")
    return law


def resolve(ref: str) -> Law:
    """The law a reference names, loaded and validated (LawError naming it otherwise)."""
    if not isinstance(ref, str) or not ref:
        raise LawError(f"law reference must be a non-empty string, got {ref!r}")
    law = _BUILTIN.get(ref) or _PLUGINS.get(ref)
    if law is not None:
        return law
    if ref in _REFS:
        return _PLUGINS[_REFS[ref]]
    if ":" in ref:
        obj, origin = _load_object(ref)
        law = _register(obj, f"law {ref!r}", origin)
    else:
        eps = entry_points()
        if ref not in eps:
            known = ", ".join(tuple(_BUILTIN) + tuple(_PLUGINS) + tuple(n for n in sorted(eps) if n not in _PLUGINS))
            raise LawError(f"unknown control law {ref!r}; choose from: {known} (or path/to/file.py:NAME, package.module:NAME)")
        law = _load_entry_point(eps[ref])
    _REFS[ref] = law.name
    return law


def load_installed() -> tuple[Law, ...]:
    """Every installed plug-in, loaded (LawError for the first that fails, naming it)."""
    return tuple(resolve(name) if name in _PLUGINS else _load_entry_point(ep) for name, ep in sorted(entry_points().items()))


def flight_laws() -> tuple[Law, ...]:
    """The FC's law table (``FC_CONTROLLER`` values): built-ins, then plug-ins in load order."""
    return BUILTIN_LAWS + tuple(_PLUGINS.values())


def plugin_laws() -> tuple[Law, ...]:
    """The plug-ins loaded in this process, in load order."""
    return tuple(_PLUGINS.values())
