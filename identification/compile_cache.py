"""XLA's compiled programs kept between runs of the command line (JAX's persistent compilation cache).

Most of a short ``odocompass`` run is XLA:CPU compiling the estimator's scan for the drive's
shape and mode, the same programs every time the same kind of log comes back: ``odocompass demo
--quick`` took 96 s with an empty cache and 40 s with the one its first run left (4.7 MB, 10
programs; docs/benchmarks.md).  ``estimate_drive`` pads a log to its length bucket
(``drive_log.bucket_length``, at most 12.5 % more samples), so logs of nearby lengths share one program: a
second log of 6,050 samples after one of 5,986 took 8.5-9.1 s with its own program and 3.0-3.1 s with the shared
one (stop 43).  The cache changes how fast a program is obtained, never what it computes.

Where (the first that applies):

* ``JAX_COMPILATION_CACHE_DIR`` set: JAX's own setting, used as it is (nothing done here);
* ``ODOCOMPASS_CACHE_DIR`` set: that folder; empty, ``0`` or ``off`` switches the cache off;
* otherwise ``$XDG_CACHE_HOME/odocompass/jax`` (``~/.cache/odocompass/jax``).

A folder that cannot be created or written leaves the cache off, silently: a read-only home must
not stop an estimate.  The cache is bounded (``MAX_BYTES``, least recently used programs go first).
"""

from __future__ import annotations

import os
from pathlib import Path

ENV_DIR = "ODOCOMPASS_CACHE_DIR"
OFF_VALUES = ("", "0", "off", "no", "none", "false")
MAX_BYTES = 1 << 30
"""Bound of the cache folder (1 GiB; an estimate's programs are 0.3-1 MB each)."""
MIN_COMPILE_S = 0.5
"""Programs that compile faster than this are not kept (JAX's default is 1 s)."""


def cache_dir(environ=None) -> Path | None:
    """The folder the command line should keep compiled programs in, or None (off, or JAX's own
    ``JAX_COMPILATION_CACHE_DIR`` is set).  Creates the folder; None if it cannot be written."""
    environ = os.environ if environ is None else environ
    if environ.get("JAX_COMPILATION_CACHE_DIR"):
        return None
    chosen = environ.get(ENV_DIR)
    if chosen is not None and chosen.strip().lower() in OFF_VALUES:
        return None
    try:
        if chosen is not None:
            path = Path(chosen).expanduser()
        else:
            base = environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
            path = Path(base).expanduser() / "odocompass" / "jax"
        path.mkdir(parents=True, exist_ok=True)
    except (OSError, RuntimeError):  # RuntimeError: no home folder to be found ("~" with HOME unset, no passwd entry)
        return None
    if not (path.is_dir() and os.access(path, os.W_OK | os.X_OK)):
        return None
    return path


def configure(environ=None) -> Path | None:
    """Point JAX's persistent compilation cache at ``cache_dir(environ)``; returns that folder or None."""
    path = cache_dir(environ)
    if path is None:
        return None
    import jax

    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_S)
    jax.config.update("jax_compilation_cache_max_size", MAX_BYTES)
    return path
