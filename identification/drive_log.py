"""Drive logs (SPEC §4): read, check and write one table per drive in CSV, Parquet or MDF4.

The format follows the file extension: ``.csv``, ``.parquet`` (or ``.pq``), ``.mf4`` (ASAM MDF4,
read and written with asammdf); anything else is refused.

``read_table`` returns the raw columns; ``read_drive`` / ``drive_from_columns`` check them and
build the model inputs.  A bad log is refused with a one-line ``DriveLogError`` naming the file,
the 1-based data row (with its time) and the column: a missing required column, an empty log,
a non-finite or non-increasing time, a pulse count that is not a finite non-negative integer,
a flag that is not 0/1, an unparseable cell, an unreadable file.  Bad compass samples (NaN or
inf) are *not* refused: they are kept, the model skips them, and they are counted in
``metadata["bad_compass_samples"]``.  NaN in the optional map/fix columns marks the map heading
or the fix invalid at those rows (counted in the metadata).  NaN in ``ref_heading_deg`` is kept
as NaN (a reference dropout): whoever compares against it must mask it (``stack_reference``).

``write_drive`` writes atomically (temporary file in the same folder, then rename) and keeps
integer columns integer (pulse counters and flags round-trip exactly in all three formats).
In MDF4 the drive is one channel group whose master channel is ``time_s``.
"""

from __future__ import annotations

import csv
import gc
import logging
import math
import os
import re
import sys
import warnings
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping

import numpy as np

from .errors import DriveLogError

REQUIRED_COLUMNS = ("time_s", "left_pulses", "right_pulses", "compass_x", "compass_y")
OPTIONAL_COLUMNS = ("ref_heading_deg", "map_heading_deg", "map_valid", "compass_unreliable_area",
                    "fix_east_m", "fix_north_m", "fix_valid")
SCHEMA_COLUMNS = REQUIRED_COLUMNS + OPTIONAL_COLUMNS
PULSE_COLUMNS = ("left_pulses", "right_pulses")
FLAG_COLUMNS = ("map_valid", "compass_unreliable_area", "fix_valid")
INTEGER_COLUMNS = PULSE_COLUMNS + FLAG_COLUMNS
"""Columns stored as integers when every value is a finite integer (exact round trip)."""

UNITS = {"time_s": "s", "left_pulses": "counts", "right_pulses": "counts", "ref_heading_deg": "deg",
         "map_heading_deg": "deg", "fix_east_m": "m", "fix_north_m": "m", "heading_deg": "deg",
         "wheel_heading_deg": "deg", "compass_heading_deg": "deg", "x_m": "m", "y_m": "m", "speed_mps": "m/s",
         "a": "s2/m2", "effective_track_m": "m"}

FORMATS = {".csv": "csv", ".parquet": "parquet", ".pq": "parquet", ".mf4": "mf4"}
MAX_EXACT_COUNT = 2.0**53
"""Pulse counts above this are not exactly representable in float64 and are refused."""


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


# ----------------------------------------------------------------------------------------------
# helpers


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    text = re.sub(r"'?<mmap\.mmap [^>]*>'?", "the file", text)  # asammdf names the file by its mmap
    return text or type(exc).__name__


def _format_of(path: Path) -> str:
    fmt = FORMATS.get(path.suffix.lower())
    if fmt is None:
        shown = path.suffix or "(none)"
        raise DriveLogError(f"{path}: unknown file extension {shown!r} (expected .csv, .parquet or .mf4)")
    return fmt


def wrap_rad(angle):
    """Wrap rad to (-pi, pi] (numpy twin of jaxmodel.angles.wrap); NaN stays NaN."""
    angle = np.asarray(angle, dtype=np.float64)
    wrapped = angle - 2.0 * np.pi * np.floor((angle + np.pi) / (2.0 * np.pi))
    return np.where(wrapped <= -np.pi, wrapped + 2.0 * np.pi, wrapped)


def wrap_deg(angle):
    """Wrap degrees to (-180, 180]; NaN stays NaN."""
    angle = np.asarray(angle, dtype=np.float64)
    wrapped = angle - 360.0 * np.floor((angle + 180.0) / 360.0)
    return np.where(wrapped <= -180.0, wrapped + 360.0, wrapped)


def _num(v) -> str:
    """A value as a user reads it: integers without '.0', floats in their shortest exact form."""
    v = float(v)
    if v.is_integer() and abs(v) < 1e16:
        return str(int(v))
    return repr(v)


def _where(source: str, row: int, time_s=None) -> str:
    """'FILE: row R (time_s=T)' with R the 1-based data row."""
    if time_s is None or not np.isfinite(time_s):
        return f"{source}: row {row + 1}"
    return f"{source}: row {row + 1} (time_s={_num(time_s)})"


@contextmanager
def _quiet_libraries():
    """Keep asammdf/pyarrow log records, warnings and __del__ noise off stderr (one-line errors)."""
    logger = logging.getLogger("asammdf")
    old_disabled, old_hook = logger.disabled, sys.unraisablehook
    logger.disabled = True
    sys.unraisablehook = lambda unraisable: None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            yield
    finally:
        logger.disabled = old_disabled
        sys.unraisablehook = old_hook


def _to_numeric(name: str, values: np.ndarray, source: str, strict: bool) -> np.ndarray:
    """int64 or float64 array of a column; object/str cells parsed one by one, naming a bad row.

    Non-schema columns that are not numeric are returned unchanged when ``strict`` is False.
    """
    arr = np.asarray(values)
    if arr.dtype == np.bool_:
        return arr.astype(np.int64)
    if np.issubdtype(arr.dtype, np.integer):
        return arr.astype(np.int64)
    if np.issubdtype(arr.dtype, np.floating):
        return arr.astype(np.float64)
    out = np.empty(arr.shape[0], dtype=np.float64)
    for i, cell in enumerate(arr.tolist()):
        if cell is None:
            out[i] = np.nan
            continue
        if isinstance(cell, bytes):
            cell = cell.decode("utf-8", "replace")
        if isinstance(cell, bool):
            out[i] = float(cell)
            continue
        if isinstance(cell, str):
            text = cell.strip()
            low = text.lower()
            if low in ("", "nan", "-nan", "na", "n/a", "null", "none"):
                out[i] = np.nan
                continue
            if low in ("true", "false"):
                out[i] = 1.0 if low == "true" else 0.0
                continue
            try:
                out[i] = float(text)
                continue
            except ValueError:
                pass
        else:
            try:
                out[i] = float(cell)
                continue
            except (TypeError, ValueError):
                pass
        if not strict:
            return arr
        raise DriveLogError(f"{_where(source, i)}, column {name!r}: cannot read {cell!r} as a number")
    if np.all(np.isfinite(out)) and np.all(out == np.round(out)) and np.all(np.abs(out) <= MAX_EXACT_COUNT) \
            and name in INTEGER_COLUMNS:
        return out.astype(np.int64)
    return out


# ----------------------------------------------------------------------------------------------
# reading


def read_table(path) -> dict[str, np.ndarray]:
    """Raw columns of a drive log, by file extension: int64 for integer columns, float64 for
    numbers (NaN for empty cells), unchanged for non-numeric columns outside the schema.

    Raises DriveLogError (one line, naming the file and, where it applies, row and column).
    """
    path = Path(path)
    fmt = _format_of(path)
    if not path.exists():
        raise DriveLogError(f"{path}: file not found")
    if not path.is_file():
        raise DriveLogError(f"{path}: not a file")
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise DriveLogError(f"{path}: cannot read: {_one_line(exc)}") from None
    if size == 0:
        raise DriveLogError(f"{path}: empty log (the file has 0 bytes)")
    reader = {"csv": _read_csv, "parquet": _read_parquet, "mf4": _read_mf4}[fmt]
    error = None
    with _quiet_libraries():
        try:
            columns = reader(path)
        except DriveLogError as exc:
            error = str(exc)
        except MemoryError:
            error = f"{path}: too large to read into memory"
        except Exception as exc:  # any library failure on a corrupt file: one line, never a traceback
            error = f"{path}: cannot read as {fmt.upper()}: {_one_line(exc)}"
        if error is not None:
            # The failed exception (and the half-built reader objects its traceback holds) is gone
            # now; finalise them while their __del__ noise is muted (asammdf's MDF4.__del__ raises
            # on a file it could not open), and raise a fresh error that holds no context.
            gc.collect()
    if error is not None:
        raise DriveLogError(error)
    return columns


def _check_names(path: Path, names: Iterable[str]) -> None:
    seen = set()
    for name in names:
        if name in seen:
            raise DriveLogError(f"{path}: column {name!r} appears twice")
        seen.add(name)


def _read_csv(path: Path) -> dict[str, np.ndarray]:
    import pyarrow as pa
    import pyarrow.compute as pc
    import pyarrow.csv as pcsv

    with open(path, newline="", encoding="utf-8-sig", errors="replace") as fh:
        header = next(csv.reader(fh), None)
    if not header or all(not h.strip() for h in header):
        raise DriveLogError(f"{path}: empty log (no header line)")
    header = [h.strip() for h in header]
    _check_names(path, header)
    convert = pcsv.ConvertOptions(column_types={h: pa.string() for h in header}, strings_can_be_null=True)
    read = pcsv.ReadOptions(column_names=header, skip_rows=1)
    try:
        table = pcsv.read_csv(path, read_options=read, convert_options=convert)
    except pa.ArrowInvalid as exc:
        _locate_csv_row_error(path, len(header))
        raise DriveLogError(f"{path}: not a readable CSV table: {_one_line(exc)}") from None
    out: dict[str, np.ndarray] = {}
    for name in header:
        col = table.column(name)
        values = None
        for target in (pa.int64(), pa.float64(), pa.bool_()):
            try:
                cast = pc.cast(col, target)
            except (pa.ArrowInvalid, pa.ArrowNotImplementedError):
                continue
            if target == pa.int64() and cast.null_count:
                continue  # empty cells: read as float with NaN
            values = cast.to_numpy(zero_copy_only=False)
            break
        if values is None:
            values = np.asarray(col.to_pylist(), dtype=object)
        out[name] = _to_numeric(name, values, str(path), strict=name in SCHEMA_COLUMNS)
    return out


def _locate_csv_row_error(path: Path, n_columns: int) -> None:
    """Find the data row whose number of fields differs from the header's, and refuse naming it."""
    try:
        with open(path, newline="", encoding="utf-8", errors="replace") as fh:
            reader = csv.reader(fh)
            next(reader, None)
            for i, row in enumerate(reader):
                if row and len(row) != n_columns:
                    raise DriveLogError(f"{path}: row {i + 1} (line {reader.line_num}): {len(row)} fields, "
                                        f"the header has {n_columns}")
    except (csv.Error, UnicodeError) as exc:
        raise DriveLogError(f"{path}: not a readable CSV table: {_one_line(exc)}") from None


def _read_parquet(path: Path) -> dict[str, np.ndarray]:
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pq.read_table(path)
    _check_names(path, table.column_names)
    out: dict[str, np.ndarray] = {}
    for name in table.column_names:
        col = table.column(name)
        if pa.types.is_integer(col.type) and col.null_count:
            values = col.cast(pa.float64()).to_numpy(zero_copy_only=False)
        elif pa.types.is_boolean(col.type) and col.null_count:
            values = col.cast(pa.float64()).to_numpy(zero_copy_only=False)
        elif pa.types.is_integer(col.type) or pa.types.is_floating(col.type) or pa.types.is_boolean(col.type):
            values = col.to_numpy(zero_copy_only=False)
        else:
            values = np.asarray(col.to_pylist(), dtype=object)
        out[name] = _to_numeric(name, values, str(path), strict=name in SCHEMA_COLUMNS)
    return out


def _read_mf4(path: Path) -> dict[str, np.ndarray]:
    from asammdf import MDF

    with open(path, "rb") as fh:
        magic = fh.read(8)
    if not magic.startswith(b"MDF"):
        raise DriveLogError(f"{path}: not an ASAM MDF file (no MDF identification block)")
    mdf = MDF(path)
    try:
        # The drive's channel group is the first that holds left_pulses; its master is time_s unless
        # it has a channel of that name.  Schema channels are taken from that group if it has them,
        # else from their first group (and must then share its time base); other groups' extra
        # channels are ignored.
        occurrences: dict[str, list[tuple[int, int]]] = {}
        for gi, group in enumerate(mdf.groups):
            for ci, ch in enumerate(group.channels):
                occurrences.setdefault(ch.name, []).append((gi, ci))
        if "left_pulses" not in occurrences:
            raise DriveLogError(f"{path}: missing required column 'left_pulses' (no MDF channel of that name)")
        drive_group = occurrences["left_pulses"][0][0]
        where: dict[str, tuple[int, int]] = {}
        for name, places in occurrences.items():
            own = [p for p in places if p[0] == drive_group]
            if own:
                where[name] = own[0]
            elif name in SCHEMA_COLUMNS and name != "time_s":
                where[name] = places[0]
        master = np.asarray(mdf.get_master(drive_group), dtype=np.float64)
        out: dict[str, np.ndarray] = {}
        if "time_s" not in where:
            out["time_s"] = master
        for name, (gi, ci) in where.items():
            sig = mdf.get(name, group=gi, index=ci, raw=False)
            samples = np.asarray(sig.samples)
            if samples.ndim != 1:
                if name in SCHEMA_COLUMNS:
                    raise DriveLogError(f"{path}: column {name!r} is not a scalar channel (shape {samples.shape})")
                continue
            if name in SCHEMA_COLUMNS and name != "time_s":
                stamps = np.asarray(sig.timestamps, dtype=np.float64)
                if stamps.shape != master.shape or not np.array_equal(stamps, master, equal_nan=True):
                    raise DriveLogError(f"{path}: column {name!r} is not sampled on the time base of "
                                        f"left_pulses (MDF channel group {gi} vs {drive_group})")
            if samples.dtype.kind in "SUO" and name not in SCHEMA_COLUMNS:
                continue
            out[name] = _to_numeric(name, samples, str(path), strict=name in SCHEMA_COLUMNS)
        return {"time_s": np.asarray(out.pop("time_s"), dtype=np.float64), **out}
    finally:
        mdf.close()


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

    ``source`` names the file in error messages and is stored as metadata["path"].
    """
    import jaxmodel

    names = list(columns.keys())
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

    # time_s: finite and strictly increasing.
    t = cols["time_s"].astype(np.float64)
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        i = int(bad[0])
        raise DriveLogError(f"{_where(source, i)}, column 'time_s': time is {_num(t[i])} (must be finite)")
    if n > 1:
        back = np.flatnonzero(np.diff(t) <= 0.0)
        if back.size:
            i = int(back[0]) + 1
            raise DriveLogError(f"{_where(source, i, t[i])}, column 'time_s': time does not increase "
                                f"(previous row {i}: {_num(t[i - 1])} s); time must be strictly increasing")

    # Pulse counters: finite non-negative integers (exact in float64).
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

    # Flags: 0/1 (NaN means 0 at that row).
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

    # Compass: NaN/inf kept (skipped and counted by the model), counted here.
    cx = cols["compass_x"].astype(np.float64)
    cy = cols["compass_y"].astype(np.float64)
    bad_compass = int(np.count_nonzero(~(np.isfinite(cx) & np.isfinite(cy))))

    # Map-heading selector inputs: NaN heading -> map invalid at that row.
    zeros = np.zeros(n, dtype=np.float64)
    map_invalidated = 0
    if "map_heading_deg" in cols:
        mh = cols["map_heading_deg"].astype(np.float64)
        mh_ok = np.isfinite(mh)
        map_valid = flags.get("map_valid", np.where(mh_ok, 1.0, 0.0))
        map_invalidated = int(np.count_nonzero((map_valid > 0.5) & ~mh_ok))
        map_valid = np.where(mh_ok, map_valid, 0.0)
        map_heading = np.where(mh_ok, wrap_rad(np.deg2rad(np.where(mh_ok, mh, 0.0))), 0.0)
    else:
        map_heading = zeros.copy()
        map_valid = flags.get("map_valid", zeros.copy())
        idx = np.flatnonzero(map_valid > 0.5)
        if idx.size:
            i = int(idx[0])
            raise DriveLogError(f"{_where(source, i, t[i])}, column 'map_heading_deg': missing, but map_valid "
                                f"is set")
    unreliable = flags.get("compass_unreliable_area", zeros.copy())

    # Position fixes: NaN east/north -> fix invalid at that row.
    fix_invalidated = 0
    has_fix_xy = ("fix_east_m" in cols, "fix_north_m" in cols)
    if any(has_fix_xy):
        if not all(has_fix_xy):
            other = "fix_north_m" if has_fix_xy[0] else "fix_east_m"
            raise DriveLogError(f"{source}: column {other!r} missing (fix_east_m and fix_north_m come together)")
        fe = cols["fix_east_m"].astype(np.float64)
        fn = cols["fix_north_m"].astype(np.float64)
        fix_ok = np.isfinite(fe) & np.isfinite(fn)
        fix_valid = flags.get("fix_valid", np.where(fix_ok, 1.0, 0.0))
        fix_invalidated = int(np.count_nonzero((fix_valid > 0.5) & ~fix_ok))
        fix_valid = np.where(fix_ok, fix_valid, 0.0)
        fix_east = np.where(fix_ok, fe, 0.0)
        fix_north = np.where(fix_ok, fn, 0.0)
    else:
        fix_east, fix_north = zeros.copy(), zeros.copy()
        fix_valid = flags.get("fix_valid", zeros.copy())
        idx = np.flatnonzero(fix_valid > 0.5)
        if idx.size:
            i = int(idx[0])
            raise DriveLogError(f"{_where(source, i, t[i])}, column 'fix_east_m': missing, but fix_valid is set")

    ref = None
    missing_ref = 0
    if "ref_heading_deg" in cols:
        r = cols["ref_heading_deg"].astype(np.float64)
        ok = np.isfinite(r)
        missing_ref = int(np.count_nonzero(~ok))
        ref = np.where(ok, wrap_rad(np.deg2rad(np.where(ok, r, 0.0))), np.nan)

    inputs = jaxmodel.Inputs(
        time_s=t, left_pulses=cols["left_pulses"].astype(np.float64), right_pulses=cols["right_pulses"].astype(np.float64),
        compass_x=cx, compass_y=cy, map_heading=np.asarray(map_heading, np.float64),
        map_valid=np.asarray(map_valid, np.float64), compass_unreliable_area=np.asarray(unreliable, np.float64),
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


# ----------------------------------------------------------------------------------------------
# batching


def _pad_last(x: np.ndarray, n: int) -> np.ndarray:
    return np.concatenate([x, np.full(n - len(x), x[-1], dtype=np.float64)]) if n > len(x) else x


def stack_drives(drives: list[Drive]):
    """Batch drives for ``jaxmodel.run_batch``: (Inputs of (batch, N) float64 arrays, mask (batch, N)).

    Shorter drives are padded to the longest: time goes on with the drive's last time step,
    counters stay unchanged (no distance), compass, map heading and fix values repeat the last
    sample, and the map/fix flags are 0.  mask is 1.0 on real samples, 0.0 on padding.
    """
    import jaxmodel

    drives = list(drives)
    if not drives:
        raise ValueError("stack_drives needs at least one drive")
    n_max = max(len(d.inputs.time_s) for d in drives)
    fields = {k: [] for k in jaxmodel.Inputs._fields}
    mask = np.zeros((len(drives), n_max), dtype=np.float64)
    for b, d in enumerate(drives):
        inp = d.inputs
        n = len(inp.time_s)
        mask[b, :n] = 1.0
        pad = n_max - n
        t = np.asarray(inp.time_s, dtype=np.float64)
        step = float(t[-1] - t[-2]) if n > 1 else 1.0
        for k in jaxmodel.Inputs._fields:
            v = np.asarray(getattr(inp, k), dtype=np.float64)
            if k == "time_s":
                v = np.concatenate([t, t[-1] + step * np.arange(1, pad + 1, dtype=np.float64)])
            elif k in ("map_valid", "fix_valid"):
                v = np.concatenate([v, np.zeros(pad)])
            else:
                v = _pad_last(v, n_max)
            fields[k].append(v)
    inputs = jaxmodel.Inputs(**{k: np.stack(v) for k, v in fields.items()})
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


# ----------------------------------------------------------------------------------------------
# writing


def _storage_array(name: str, values) -> np.ndarray:
    """int64 for integer data (and integer-valued pulse/flag columns), float64 otherwise."""
    arr = np.asarray(values)
    if arr.ndim != 1:
        raise ValueError(f"column {name!r} must be one-dimensional, got shape {arr.shape}")
    if arr.dtype == np.bool_ or np.issubdtype(arr.dtype, np.integer):
        return arr.astype(np.int64)
    if arr.dtype.kind in "SUO":
        raise ValueError(f"column {name!r} is not numeric (dtype {arr.dtype})")
    arr = arr.astype(np.float64)
    if name in INTEGER_COLUMNS and arr.size and np.all(np.isfinite(arr)) and np.all(arr == np.round(arr)) \
            and np.all(np.abs(arr) <= MAX_EXACT_COUNT):
        return arr.astype(np.int64)
    return arr


def _temporary(path: Path) -> Path:
    # Same folder (rename stays atomic), same suffix (asammdf keeps it), hidden name.
    return path.with_name(f".{path.stem}.tmp-{os.getpid()}{path.suffix}")


def write_drive(path, columns: Mapping[str, Any]) -> Path:
    """Write columns (name -> 1-D array, equal lengths) as a drive log, format by extension.

    Atomic: the file appears complete or not at all.  Integer columns (numpy integer dtype,
    or integer-valued pulse/flag columns) are stored as int64 and read back exactly; floats
    are written so that they read back bit for bit (CSV uses the shortest repr).  The contents
    are not checked (``read_drive`` does that), so tests can write bad logs on purpose.
    In MDF4, ``time_s`` is the master channel of the one channel group.
    """
    path = Path(path)
    fmt = _format_of(path)
    if "time_s" not in columns and fmt == "mf4":
        raise ValueError("an MDF4 drive log needs a 'time_s' column (it becomes the master channel)")
    data = {name: _storage_array(name, v) for name, v in columns.items()}
    lengths = {len(v) for v in data.values()}
    if len(lengths) > 1:
        raise ValueError("columns of a drive log must have equal lengths: "
                         + ", ".join(f"{k}={len(v)}" for k, v in data.items()))
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = _temporary(path)
    try:
        if fmt == "csv":
            _write_csv(tmp, data)
        elif fmt == "parquet":
            _write_parquet(tmp, data)
        else:
            written = _write_mf4(tmp, data)
            if written != tmp:
                os.replace(written, tmp)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


def _csv_strings(arr: np.ndarray) -> list[str]:
    if np.issubdtype(arr.dtype, np.integer):
        return [str(v) for v in arr.tolist()]
    out = []
    for v in arr.tolist():
        if math.isnan(v):
            out.append("nan")
        elif math.isinf(v):
            out.append("inf" if v > 0 else "-inf")
        else:
            out.append(repr(v))  # shortest string that reads back to the same float64
    return out


def _write_csv(path: Path, data: dict[str, np.ndarray]) -> None:
    names = list(data)
    cells = [_csv_strings(data[k]) for k in names]
    with open(path, "w", newline="", encoding="utf-8") as fh:
        fh.write(",".join(names) + "\n")
        for row in zip(*cells):
            fh.write(",".join(row) + "\n")


def _write_parquet(path: Path, data: dict[str, np.ndarray]) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pa.table({k: pa.array(v) for k, v in data.items()})
    pq.write_table(table, path)


def _write_mf4(path: Path, data: dict[str, np.ndarray]) -> Path:
    from asammdf import MDF, Signal

    time = data["time_s"].astype(np.float64)
    signals = [Signal(v, time, name=k, unit=UNITS.get(k, ""), master_metadata=("time_s", 1))
               for k, v in data.items() if k != "time_s"]
    with _quiet_libraries():
        mdf = MDF(version="4.10")
        try:
            if signals:
                mdf.append(signals, common_timebase=True)
            else:
                raise ValueError("an MDF4 drive log needs at least one column besides time_s")
            return Path(mdf.save(path, overwrite=True))
        finally:
            mdf.close()
