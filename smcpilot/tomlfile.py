"""Reading a TOML file with errors a user can act on (the one reader of vehicle, plan and
scenario files)."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

from smcpilot.errors import ConfigError


def read_toml(path: str | Path, error: type[ConfigError], what: str) -> dict[str, Any]:
    """The parsed document at ``path``; an unreadable file (missing, a directory, not UTF-8) or
    invalid TOML raises ``error`` naming the file (``what`` says what kind of file, e.g. "plan")."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise error(f"cannot read {what} {p}: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise error(f"cannot read {what} {p}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{p}: not valid TOML: {exc}") from None
