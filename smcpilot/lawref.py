"""Law references as the ground side and configuration files see them, without loading any law.

A control law is named by a built-in's name, an installed plug-in's name (an entry point of the
group ``smcpilot.laws``) or ``path/to/file.py:NAME`` / ``package.module:NAME``. The flight
controller loads and validates it (:mod:`fc.control.registry`); this module only says whether a
string can be one, so that a mission or campaign file with a typo fails when it is read, with the
names to choose from, and nothing here imports a law's code.
"""

from __future__ import annotations

import argparse
import re
from importlib import metadata
from pathlib import Path

from smcpilot.protocol import FC_CONTROLLERS

#: the entry-point group installed plug-in laws register in.
ENTRY_POINT_GROUP = "smcpilot.laws"
#: names of plug-in laws loaded in this process (the FC's registry notes each; a loaded law may then be
#: named by its name alone, as ``FC_CONTROLLER`` does).
_LOADED: set[str] = set()
_NAME_RE = re.compile(r"^[a-z][a-z0-9_]{0,39}$")
_MODULE_RE = re.compile(r"^[A-Za-z_][\w]*(\.[A-Za-z_][\w]*)*:[A-Za-z_]\w*$")


def note_loaded(name: str) -> None:
    """The FC's registry loaded a plug-in law of this name."""
    _LOADED.add(name)


def installed_law_names() -> tuple[str, ...]:
    """Names of the installed plug-in laws (entry points; not loaded), sorted."""
    return tuple(sorted({ep.name for ep in metadata.entry_points(group=ENTRY_POINT_GROUP)}))


def known_law_names() -> tuple[str, ...]:
    """The built-in laws, then the installed plug-ins."""
    return FC_CONTROLLERS + tuple(n for n in installed_law_names() if n not in FC_CONTROLLERS)


def is_code_reference(ref: str) -> bool:
    """``file.py:NAME`` or ``module:NAME`` (code that is not an installed plug-in)."""
    return ":" in ref


def is_file_reference(ref: str) -> bool:
    """``path.py:NAME`` (a file) rather than ``module:NAME``."""
    head = ref.rsplit(":", 1)[0]
    return head.endswith(".py") or "/" in head or "\\" in head


def normalise_reference(ref: str, base: Path | None = None) -> str:
    """A reference other processes can resolve too: a file path made absolute (against ``base``)."""
    if ":" in ref and is_file_reference(ref):
        head, name = ref.rsplit(":", 1)
        p = Path(head).expanduser()
        if not p.is_absolute():
            p = (base or Path.cwd()) / p
        return f"{p.resolve()}:{name}"
    return ref


def law_argument(text: str) -> str:
    """argparse ``type`` of ``--controller`` / ``--law``: a valid reference, file paths made absolute."""
    problem = law_reference_problem(text)
    if problem:
        raise argparse.ArgumentTypeError(problem)
    return normalise_reference(text)


def law_reference_problem(ref: object) -> str:
    """Why ``ref`` cannot name a law (one line with the choices), or "" if it can."""
    if not isinstance(ref, str) or not ref:
        return f"controller must be a law name, got {ref!r}"
    if is_code_reference(ref):
        head, _, name = ref.rpartition(":")
        if head and name.isidentifier() and (is_file_reference(ref) or _MODULE_RE.match(ref)):
            return ""
        return f"controller {ref!r}: expected path/to/file.py:NAME or package.module:NAME"
    if ref in FC_CONTROLLERS or ref in _LOADED:
        return ""
    if _NAME_RE.match(ref) and ref in installed_law_names():
        return ""
    return f"unknown controller {ref!r}; choose from: {', '.join(known_law_names())} (or path/to/file.py:NAME, package.module:NAME)"
