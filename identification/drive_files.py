"""Drive log files (SPEC §4): the column schema, and the raw table read from or written to disk.

The format follows the file extension: ``.csv``, ``.parquet`` (or ``.pq``), ``.mf4`` (ASAM MDF4,
read and written with asammdf); anything else is refused.

``read_table`` returns the raw columns (int64 for integer columns, float64 for numbers, NaN for
empty cells); checking them and building the model inputs is ``drive_log.drive_from_columns``.
A file that cannot be read is refused with a one-line ``DriveLogError`` naming the file and,
where it applies, the 1-based data row and the column: an unknown extension, a missing, empty or
unreadable file, a duplicated column name, a CSV row with the wrong number of fields, an
unparseable cell of a schema column.

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
import tempfile
import warnings
from contextlib import contextmanager
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
    # true/false are flags (0/1), never a count, a time or a field: refused in the other schema columns
    booleans_ok = name in FLAG_COLUMNS or not strict
    if arr.dtype == np.bool_:
        if not booleans_ok:
            raise DriveLogError(f"{source}: column {name!r} holds true/false values; it needs numbers")
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
        if isinstance(cell, bool) and booleans_ok:
            out[i] = float(cell)
            continue
        if isinstance(cell, str):
            text = cell.strip()
            low = text.lower()
            if low in ("", "nan", "-nan", "na", "n/a", "null", "none"):
                out[i] = np.nan
                continue
            if low in ("true", "false") and booleans_ok:
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
        # Arrow reads "0x10" as 16; a log's numbers are decimal, so such a cell goes row by row and is refused there.
        hex_text = pc.any(pc.match_substring_regex(col, r"^\s*[+-]?0[xX]")).as_py()
        for target in () if hex_text else (pa.int64(), pa.float64(), pa.bool_()):
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

    # Names checked before reading: Arrow's own error on a repeated name is a dump of the schema.
    _check_names(path, pq.read_schema(path).names)
    table = pq.read_table(path)
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
    # asammdf copies an unfinalised MDF 4.10+ file into its temporary folder and deletes the copy on close,
    # which a corrupt file never reaches: a private folder, removed whatever happens, leaves nothing behind.
    with tempfile.TemporaryDirectory(prefix="odocompass-mf4-") as scratch:
        return _read_mf4_channels(MDF, path, scratch)


def _read_mf4_channels(MDF, path: Path, scratch: str) -> dict[str, np.ndarray]:
    mdf = MDF(path, temporary_folder=scratch)
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
        for name, places in occurrences.items():
            if name in SCHEMA_COLUMNS and name != "time_s" and len(places) > 1:
                (g1, _), (g2, _) = places[:2]
                where_twice = f"MDF channel group {g1}" if g1 == g2 else f"MDF channel groups {g1} and {g2}"
                raise DriveLogError(f"{path}: column {name!r} appears twice ({where_twice})")
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
