"""Errors a user can fix. The CLI prints them as one line (what, where, how to fix) and exits 2."""

from __future__ import annotations


class UserError(Exception):
    """A problem the operator can fix: bad config, missing port, wrong id.

    ``str(err)`` is the single line shown to the user; ``fix`` says what to do about it.
    """

    exit_code = 2

    def __init__(self, what: str, *, where: str = "", fix: str = ""):
        self.what, self.where, self.fix = what, where, fix
        parts = [f"{where}: {what}" if where else what]
        if fix:
            parts.append(f"fix: {fix}")
        super().__init__(" -- ".join(parts))


class ConfigError(UserError):
    """A rig file, arm description or device config is malformed."""


class DeviceNotFound(UserError):
    """A serial port, CAN channel, servo or motor id does not answer."""


class DeviceError(UserError):
    """A device answered but is in a state we cannot work with (wrong mode, error flags, too slow)."""
