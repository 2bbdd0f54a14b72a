"""Drive logs (SPEC §4): check a drive's columns into a ``Drive``, read one, batch several.

``read_drive`` reads a file (``drive_files.read_table``: CSV, Parquet or MDF4 by extension) and
``drive_from_columns`` checks the raw columns and builds the model inputs.  A bad log is refused
with a one-line ``DriveLogError`` naming the file, the 1-based data row (with its time) and the
column: a missing required column, an empty log, a non-finite or non-increasing time, a pulse
count that is not a finite non-negative integer, a flag that is not 0/1, an unparseable cell, an
unreadable file.  Bad compass samples (NaN or inf) are *not* refused: they are kept, the model
skips them, and they are counted in ``metadata["bad_compass_samples"]``.  NaN in the optional
map/fix columns marks the map heading or the fix invalid at those rows (counted in the
metadata).  NaN in ``ref_heading_deg`` is kept as NaN (a reference dropout): whoever compares
against it must mask it (``stack_reference``).

``stack_drives`` / ``stack_reference`` pad drives of different lengths into one batch.
The schema, ``read_table`` and ``write_drive`` live in ``drive_files`` and are re-exported here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

# The schema, read_table, write_drive and _format_of are re-exported: callers import them from here.
from .drive_files import (  # noqa: F401
    FLAG_COLUMNS, FORMATS, INTEGER_COLUMNS, MAX_EXACT_COUNT, OPTIONAL_COLUMNS, PULSE_COLUMNS, REQUIRED_COLUMNS,
    SCHEMA_COLUMNS, UNITS, _format_of, _num, _to_numeric, _where, read_table, write_drive)
from .errors import DriveLogError


@dataclass
class Drive:
    """One checked drive.

    inputs: ``jaxmodel.Inputs`` of numpy float64 arrays of shape (N,) (map heading in rad).
    ref_heading: reference heading in rad wrapped to (-pi, pi] (NaN where the log has none), or
    None when the log has no ``ref_heading_deg`` column.
    metadata: path, format, n_samples, columns (present, in file order), extra_columns,
    duration_s, bad_compass_samples, missing_ref_samples, map_invalidated_samples,
    fix_invalidated_samples.
    """

    inputs: Any
    ref_heading: np.ndarray | None
    metadata: dict = field(default_factory=dict)

    @property
    def n_samples(self) -> int:
        return int(self.metadata["n_samples"])

    @property
    def path(self) -> str:
        return str(self.metadata.get("path", "<columns>"))


def wrap_rad(angle):
    """Wrap rad to (-pi, pi] (numpy twin of jaxmodel.angles.wrap); NaN stays NaN."""
    angle = np.asarray(angle, dtype=np.float64)
    wrapped = angle - 2.0 * np.pi * np.floor((angle + np.pi) / (2.0 * np.pi))
    return np.where(wrapped <= -np.pi, wrapped + 2.0 * np.pi, wrapped)


def counter_increments(counts, modulus):
    """Per-sample increments of cumulative pulse counters (..., N) along the last axis, a wrap at ``modulus``
    decoded as the shortest step (numpy twin of jaxmodel.odometer.decode_counter); the first sample's is 0, a
    non-finite count gives a non-finite increment."""
    counts = np.asarray(counts, dtype=np.float64)
    d = np.diff(counts, axis=-1, prepend=counts[..., :1])
    return d - modulus * np.round(d / modulus)


def wrap_deg(angle):
    """Wrap degrees to (-180, 180]; NaN stays NaN."""
    angle = np.asarray(angle, dtype=np.float64)
    wrapped = angle - 360.0 * np.floor((angle + 180.0) / 360.0)
    return np.where(wrapped <= -180.0, wrapped + 360.0, wrapped)


def read_drive(path) -> Drive:
    """Read and check a drive log (SPEC §4); raises DriveLogError naming file, row and column."""
    path = Path(path)
    columns = read_table(path)
    drive = drive_from_columns(columns, source=str(path))
    drive.metadata["format"] = _format_of(path)
    return drive


# ----------------------------------------------------------------------------------------------
# checking


def drive_from_columns(columns: Mapping[str, Any], source: str = "<columns>") -> Drive:
    """Check raw columns (as from ``read_table`` or a simulator) and build the Drive.

    ``source`` names the file in error messages and is stored as metadata["path"].  The checks run in the order
    of the module docstring (columns, time, pulse counters, flags, map and fix columns); the first problem found
    is the one refused.
    """
    import jaxmodel

    names = list(columns.keys())
    cols = _checked_columns(columns, source)
    n = len(cols["time_s"])
    t = cols["time_s"].astype(np.float64)
    _check_time(t, source)
    _check_pulse_counters(cols, t, source)
    flags, flag_nan = _checked_flags(cols, t, source)
    # Compass: NaN/inf kept (skipped and counted by the model), counted here.
    cx = cols["compass_x"].astype(np.float64)
    cy = cols["compass_y"].astype(np.float64)
    bad_compass = int(np.count_nonzero(~(np.isfinite(cx) & np.isfinite(cy))))
    map_heading, map_valid, map_invalidated = _map_columns(cols, flags, t, source)
    fix_east, fix_north, fix_valid, fix_invalidated = _fix_columns(cols, flags, t, source)
    ref, missing_ref = _reference_heading(cols)

    inputs = jaxmodel.Inputs(
        time_s=t, left_pulses=cols["left_pulses"].astype(np.float64),
        right_pulses=cols["right_pulses"].astype(np.float64),
        compass_x=cx, compass_y=cy, map_heading=np.asarray(map_heading, np.float64),
        map_valid=np.asarray(map_valid, np.float64),
        compass_unreliable_area=np.asarray(flags.get("compass_unreliable_area", np.zeros(n)), np.float64),
        fix_east_m=np.asarray(fix_east, np.float64), fix_north_m=np.asarray(fix_north, np.float64),
        fix_valid=np.asarray(fix_valid, np.float64))
    metadata = {
        "path": source,
        "format": "columns",
        "n_samples": n,
        "columns": names,
        "extra_columns": [c for c in names if c not in SCHEMA_COLUMNS],
        "duration_s": float(t[-1] - t[0]),
        "bad_compass_samples": bad_compass,
        "has_ref_heading": ref is not None,
        "missing_ref_samples": missing_ref,
        "map_invalidated_samples": map_invalidated + flag_nan.get("map_valid", 0),
        "fix_invalidated_samples": fix_invalidated + flag_nan.get("fix_valid", 0),
    }
    return Drive(inputs=inputs, ref_heading=ref, metadata=metadata)


def _checked_columns(columns, source):
    """The schema's columns present in ``columns`` as one-dimensional numeric arrays of one length, at least one
    row; the required ones all there."""
    missing = [c for c in REQUIRED_COLUMNS if c not in columns]
    if missing:
        listed = ", ".join(repr(c) for c in missing)
        raise DriveLogError(f"{source}: missing required column{'s' if len(missing) > 1 else ''} {listed}")
    cols: dict[str, np.ndarray] = {}
    for name in SCHEMA_COLUMNS:
        if name in columns:
            raw = np.asarray(columns[name])
            if raw.ndim != 1:
                raise DriveLogError(f"{source}: column {name!r} must be one-dimensional, got shape {raw.shape}")
            cols[name] = _to_numeric(name, raw, source, strict=True)
    n = len(cols["time_s"])
    for name, arr in cols.items():
        if len(arr) != n:
            raise DriveLogError(f"{source}: column {name!r} has {len(arr)} values, time_s has {n}")
    if n == 0:
        raise DriveLogError(f"{source}: empty log (no data rows)")
    return cols


def _check_time(t, source):
    """time_s (s): finite and strictly increasing."""
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        i = int(bad[0])
        raise DriveLogError(f"{_where(source, i)}, column 'time_s': time is {_num(t[i])} (must be finite)")
    back = np.flatnonzero(np.diff(t) <= 0.0)
    if back.size:
        i = int(back[0]) + 1
        raise DriveLogError(f"{_where(source, i, t[i])}, column 'time_s': time does not increase "
                            f"(previous row {i}: {_num(t[i - 1])} s); time must be strictly increasing")


def _check_pulse_counters(cols, t, source):
    """Pulse counters: finite non-negative integers, exact in float64; the earliest bad row is named."""
    for name in PULSE_COLUMNS:
        p = cols[name].astype(np.float64)
        problems = [(~np.isfinite(p), "is {v} (must be a finite integer)"),
                    (np.isfinite(p) & (p != np.round(p)), "{v} is not an integer"),
                    (np.isfinite(p) & (p < 0.0), "{v} is negative; pulse counters count up from 0 and wrap "
                                                   "at counter_modulus"),
                    (np.isfinite(p) & (p > MAX_EXACT_COUNT), "{v} exceeds 2**53 (not exact in float64)")]
        first = None
        for mask, text in problems:
            idx = np.flatnonzero(mask)
            if idx.size and (first is None or idx[0] < first[0]):
                first = (int(idx[0]), text)
        if first is not None:
            i, text = first
            raise DriveLogError(f"{_where(source, i, t[i])}, column {name!r}: pulse count "
                                + text.format(v=_num(p[i])))


def _checked_flags(cols, t, source):
    """The flag columns present, 0/1 (NaN means 0 at that row): (flags by name, their NaN counts by name)."""
    flags: dict[str, np.ndarray] = {}
    flag_nan: dict[str, int] = {}
    for name in FLAG_COLUMNS:
        if name not in cols:
            continue
        f = cols[name].astype(np.float64)
        finite = np.isfinite(f)
        idx = np.flatnonzero(finite & (f != 0.0) & (f != 1.0))
        if idx.size:
            i = int(idx[0])
            raise DriveLogError(f"{_where(source, i, t[i])}, column {name!r}: flag is {_num(f[i])} "
                                f"(must be 0 or 1)")
        flag_nan[name] = int(np.count_nonzero(~finite))
        flags[name] = np.where(finite, f, 0.0)
    return flags, flag_nan


def _refuse_flag_without_column(valid, t, source, column, flag):
    """A set ``flag`` whose data ``column`` is absent from the log: refused at its first row."""
    idx = np.flatnonzero(valid > 0.5)
    if idx.size:
        i = int(idx[0])
        raise DriveLogError(f"{_where(source, i, t[i])}, column {column!r}: missing, but {flag} is set")


def _map_columns(cols, flags, t, source):
    """Map-heading selector inputs: (map heading rad, map_valid, rows whose set map_valid a NaN heading cleared)."""
    zeros = np.zeros(len(t), dtype=np.float64)
    if "map_heading_deg" not in cols:
        map_valid = flags.get("map_valid", zeros.copy())
        _refuse_flag_without_column(map_valid, t, source, "map_heading_deg", "map_valid")
        return zeros.copy(), map_valid, 0
    mh = cols["map_heading_deg"].astype(np.float64)
    mh_ok = np.isfinite(mh)
    map_valid = flags.get("map_valid", np.where(mh_ok, 1.0, 0.0))
    invalidated = int(np.count_nonzero((map_valid > 0.5) & ~mh_ok))
    map_heading = np.where(mh_ok, wrap_rad(np.deg2rad(np.where(mh_ok, mh, 0.0))), 0.0)
    return map_heading, np.where(mh_ok, map_valid, 0.0), invalidated


def _fix_columns(cols, flags, t, source):
    """Position fixes: (east m, north m, fix_valid, rows whose set fix_valid a NaN east or north cleared)."""
    zeros = np.zeros(len(t), dtype=np.float64)
    has_fix_xy = ("fix_east_m" in cols, "fix_north_m" in cols)
    if not any(has_fix_xy):
        fix_valid = flags.get("fix_valid", zeros.copy())
        _refuse_flag_without_column(fix_valid, t, source, "fix_east_m", "fix_valid")
        return zeros.copy(), zeros.copy(), fix_valid, 0
    if not all(has_fix_xy):
        other = "fix_north_m" if has_fix_xy[0] else "fix_east_m"
        raise DriveLogError(f"{source}: column {other!r} missing (fix_east_m and fix_north_m come together)")
    fe = cols["fix_east_m"].astype(np.float64)
    fn = cols["fix_north_m"].astype(np.float64)
    fix_ok = np.isfinite(fe) & np.isfinite(fn)
    fix_valid = flags.get("fix_valid", np.where(fix_ok, 1.0, 0.0))
    invalidated = int(np.count_nonzero((fix_valid > 0.5) & ~fix_ok))
    return np.where(fix_ok, fe, 0.0), np.where(fix_ok, fn, 0.0), np.where(fix_ok, fix_valid, 0.0), invalidated


def _reference_heading(cols):
    """(reference heading rad wrapped, NaN where missing, or None without the column; its missing rows)."""
    if "ref_heading_deg" not in cols:
        return None, 0
    r = cols["ref_heading_deg"].astype(np.float64)
    ok = np.isfinite(r)
    return np.where(ok, wrap_rad(np.deg2rad(np.where(ok, r, 0.0))), np.nan), int(np.count_nonzero(~ok))


# ----------------------------------------------------------------------------------------------
# batching


def pad_inputs(inputs, n: int):
    """Inputs of (..., n0) arrays extended to (..., n) samples (unchanged if n <= n0), the padding rules of a batch:
    time goes on with each row's last time step, counters stay unchanged (no distance), compass, map heading and fix
    values repeat the last sample, and the map/fix flags are 0."""
    import jaxmodel

    out = {}
    for k in jaxmodel.Inputs._fields:
        v = np.asarray(getattr(inputs, k), dtype=np.float64)
        n0 = v.shape[-1]
        pad = n - n0
        if pad <= 0:
            out[k] = v
            continue
        steps = np.arange(1, pad + 1, dtype=np.float64)
        if k == "time_s":
            step = v[..., -1:] - v[..., -2:-1] if n0 > 1 else np.ones_like(v[..., -1:])
            ext = v[..., -1:] + step * steps
        elif k in ("map_valid", "fix_valid"):
            ext = np.zeros(v.shape[:-1] + (pad,))
        else:
            ext = np.repeat(v[..., -1:], pad, axis=-1)
        out[k] = np.concatenate([v, ext], axis=-1)
    return jaxmodel.Inputs(**out)


def bucket_length(n: int) -> int:
    """n rounded up to a multiple of 2**(floor(log2 n) - 3) (at least 64): padding <= 12.5 %, and few distinct
    lengths, so that one compiled program (and the persistent compilation cache's entry) serves many logs."""
    n = max(int(n), 1)
    q = 2 ** max(int(math.floor(math.log2(n))) - 3, 6)
    return int(math.ceil(n / q) * q)


def stack_drives(drives: list[Drive], length: int | None = None):
    """Batch drives for ``jaxmodel.run_batch``: (Inputs of (batch, N) float64 arrays, mask (batch, N)).

    Shorter drives are padded to the longest (or to ``length`` samples, if that is longer) by
    ``pad_inputs``.  mask is 1.0 on real samples, 0.0 on padding.
    """
    import jaxmodel

    drives = list(drives)
    if not drives:
        raise ValueError("stack_drives needs at least one drive")
    n_max = max([len(d.inputs.time_s) for d in drives] + [int(length or 0)])
    mask = np.zeros((len(drives), n_max), dtype=np.float64)
    for b, d in enumerate(drives):
        mask[b, :len(d.inputs.time_s)] = 1.0
    padded = [pad_inputs(d.inputs, n_max) for d in drives]
    inputs = jaxmodel.Inputs(*(np.stack(v) for v in zip(*padded)))
    return inputs, mask


def stack_reference(drives: list[Drive]):
    """Reference headings for a batch: (ref (batch, N) rad with 0.0 where absent, mask (batch, N)).

    mask is 1.0 where the sample is real *and* its reference is finite, so a loss
    ``sum(mask * loss(heading - ref))`` never sees a NaN.
    """
    drives = list(drives)
    if not drives:
        raise ValueError("stack_reference needs at least one drive")
    n_max = max(len(d.inputs.time_s) for d in drives)
    ref = np.zeros((len(drives), n_max), dtype=np.float64)
    mask = np.zeros((len(drives), n_max), dtype=np.float64)
    for b, d in enumerate(drives):
        if d.ref_heading is None:
            raise DriveLogError(f"{d.path}: no reference heading (column 'ref_heading_deg' is missing)")
        r = np.asarray(d.ref_heading, dtype=np.float64)
        ok = np.isfinite(r)
        ref[b, :len(r)] = np.where(ok, r, 0.0)
        mask[b, :len(r)] = ok
    return ref, mask
