"""odocompass identification: drive logs, simulator, loss, optimisation, reports and the CLI."""

from .errors import DriveLogError, OdoCompassError

__all__ = ["DriveLogError", "OdoCompassError", "read_drive", "write_drive", "Drive"]


def __getattr__(name):  # lazy: `import identification` stays cheap for the CLI's --help
    if name in ("read_drive", "write_drive", "Drive"):
        from . import drive_log

        return getattr(drive_log, name)
    raise AttributeError(name)
