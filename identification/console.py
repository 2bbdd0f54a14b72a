"""What the command line says on stderr: information (silenced by ``-q``), warnings (always),
and progress bars (only when stderr is a terminal and not ``-q``).

The CLI sets ``QUIET`` once from ``-q/--quiet``; library callers never print through here
unless they ask to.
"""

from __future__ import annotations

import sys

QUIET = False


def set_quiet(quiet: bool) -> None:
    global QUIET
    QUIET = bool(quiet)


def info(msg: str) -> None:
    """An informational line on stderr (``odocompass: ...``), unless quiet."""
    if not QUIET:
        print(f"odocompass: {msg}", file=sys.stderr, flush=True)


def warn(msg: str) -> None:
    """A warning line on stderr: the result is probably wrong (shown even when quiet)."""
    print(f"odocompass: warning: {msg}", file=sys.stderr, flush=True)


def progress_enabled() -> bool:
    """Progress bars only on a terminal: a log file would collect every carriage-return update."""
    try:
        return (not QUIET) and sys.stderr.isatty()
    except (AttributeError, ValueError):
        return False


def status(msg: str) -> None:
    """A 'working on ...' line before a long step, on a terminal only (logs get the summary line)."""
    if progress_enabled():
        print(f"odocompass: {msg} ...", file=sys.stderr, flush=True)
