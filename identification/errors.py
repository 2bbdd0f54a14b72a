"""Errors the command line turns into one line and exit code 2."""


class OdoCompassError(Exception):
    """A user-facing error: the message names the file, row, column or key at fault."""


class DriveLogError(OdoCompassError):
    """A drive log is unreadable or violates SPEC §4."""
