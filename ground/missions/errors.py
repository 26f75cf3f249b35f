"""The errors of scripted missions: a broken mission file, and a mission that could not be flown."""

from __future__ import annotations

from smcpilot.errors import ConfigError, SmcpilotError

__all__ = ["MissionFileError", "MissionRunError"]


class MissionFileError(ConfigError):
    """A mission file is unreadable or invalid.

    The message names the file, the section and the key; the parts are also attributes:
    ``path`` (the file, or the source name), ``section`` (``"item"``, ``"expect"``, ``"sitl"`` or
    None for the top level), ``number`` (1-based item/expectation number, None otherwise) and
    ``key`` (the offending key, None when the problem is not one key's).
    """

    def __init__(self, message: str, *, path: str, section: str | None = None, number: int | None = None, key: str | None = None) -> None:
        super().__init__(message)
        self.path = path
        self.section = section
        self.number = number
        self.key = key


class MissionRunError(SmcpilotError):
    """The mission could not be flown or assessed (SITL died, no log, no home position)."""
