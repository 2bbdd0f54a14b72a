"""The fleet manifest: which drive logs belong to which vehicle (``odocompass fleet ...``).

A CSV or Parquet table (by extension: ``.csv``, ``.parquet``/``.pq``), one row per drive log:

| column | meaning |
|---|---|
| ``vehicle_id`` | the vehicle; letters, digits, ``.``, ``_``, ``-`` (it names ``DIR/<vehicle_id>.json``), not starting with ``.`` |
| ``path`` | the drive log (CSV, Parquet or MDF4); a relative path is relative to the manifest's folder |
| ``role`` | ``train`` (fitted) or ``validate`` (only evaluated); optional for ``fleet evaluate`` |

Other columns are ignored.  A manifest that cannot be used at all (missing, unreadable, a
required column absent, an empty or unsafe ``vehicle_id``, an unknown role, the same drive twice
for one vehicle) is refused with one line naming the file, the row and the column (exit 2).
A drive log that is missing or bad is *not* a manifest error: it only marks its vehicle ``error``.
"""

from __future__ import annotations

import csv
import hashlib
import json
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

from .errors import OdoCompassError

ROLES = ("train", "validate")
SAFE_ID = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9._-]{0,199}$")


class ManifestError(OdoCompassError):
    """The manifest itself is unusable."""


@dataclass
class ManifestVehicle:
    vehicle_id: str
    train: list = field(default_factory=list)      # Paths
    validate: list = field(default_factory=list)   # Paths
    rows: list = field(default_factory=list)       # manifest row numbers (for messages)

    @property
    def drives(self) -> list:
        return [(p, "train") for p in self.train] + [(p, "validate") for p in self.validate]

    def size_hint(self) -> int:
        """Total bytes of the drive logs (0 for a missing one): sorts vehicles of similar length together."""
        total = 0
        for p, _ in self.drives:
            try:
                total += os.path.getsize(p)
            except OSError:
                pass
        return total


def _read_rows(path: Path) -> tuple[list[str], list[dict], str]:
    """(column names, rows as {column: str}, how rows are numbered)."""
    suffix = path.suffix.lower()
    if not path.exists():
        raise ManifestError(f"{path}: manifest not found")
    if path.is_dir():
        raise ManifestError(f"{path}: is a folder, not a manifest (a .csv or .parquet table)")
    if suffix == ".csv":
        try:
            with open(path, newline="", encoding="utf-8-sig") as fh:
                reader = csv.DictReader(fh)
                names = [n.strip() for n in (reader.fieldnames or [])]
                rows = []
                for raw in reader:
                    if None in raw:
                        raise ManifestError(f"{path}: line {reader.line_num}: more fields than the header's "
                                            f"{len(names)}")
                    rows.append({k.strip(): (v or "").strip() for k, v in raw.items() if k is not None})
        except UnicodeDecodeError as exc:
            raise ManifestError(f"{path}: not UTF-8 text (byte offset {exc.start})") from None
        except csv.Error as exc:
            raise ManifestError(f"{path}: not a valid CSV table: {' '.join(str(exc).split())}") from None
        return names, rows, "line"
    if suffix in (".parquet", ".pq"):
        try:
            import pyarrow.parquet as pq

            table = pq.read_table(path)
        except Exception as exc:  # noqa: BLE001 - pyarrow raises several kinds for a corrupt file
            raise ManifestError(f"{path}: not a readable Parquet table: {' '.join(str(exc).split())[:200]}") from None
        names = list(table.column_names)
        cols = {n: table.column(n).to_pylist() for n in names}
        rows = [{n: ("" if cols[n][i] is None else str(cols[n][i]).strip()) for n in names}
                for i in range(table.num_rows)]
        return names, rows, "row"
    raise ManifestError(f"{path}: unknown manifest format {suffix or '(no extension)'!r}; expected .csv or .parquet")


def read_manifest(path, require_role: bool = True) -> dict[str, ManifestVehicle]:
    """Vehicles in manifest order (see the module docstring); raises ManifestError naming file, row, column."""
    path = Path(path)
    names, rows, unit = _read_rows(path)
    required = ("vehicle_id", "path", "role") if require_role else ("vehicle_id", "path")
    missing = [c for c in required if c not in names]
    if missing:
        raise ManifestError(f"{path}: missing column{'s' if len(missing) > 1 else ''} {', '.join(missing)} "
                            f"(a manifest has columns vehicle_id, path, role; found {', '.join(names) or 'none'})")
    if not rows:
        raise ManifestError(f"{path}: the manifest has no rows")
    base = path.resolve().parent
    vehicles: dict[str, ManifestVehicle] = {}
    seen: dict[tuple, int] = {}
    for i, row in enumerate(rows):
        where = f"{path}: {unit} {i + 2 if unit == 'line' else i + 1}"
        vid = row.get("vehicle_id", "")
        if not vid:
            raise ManifestError(f"{where}: column vehicle_id is empty")
        if not SAFE_ID.match(vid):
            raise ManifestError(f"{where}: column vehicle_id {vid!r} is not usable as a file name (letters, digits, "
                                f"'.', '_', '-'; not starting with '.'; at most 200 characters)")
        raw_path = row.get("path", "")
        if not raw_path:
            raise ManifestError(f"{where}: column path is empty")
        role = row.get("role", "train").lower() or ("train" if not require_role else "")
        if role not in ROLES:
            raise ManifestError(f"{where}: column role is {row.get('role', '')!r}; expected train or validate")
        p = Path(os.path.expanduser(raw_path))
        p = p if p.is_absolute() else base / p
        key = (vid, os.path.normpath(str(p)))
        if key in seen:
            raise ManifestError(f"{where}: vehicle {vid} lists {raw_path} again (first at {unit} {seen[key]})")
        seen[key] = i + 2 if unit == "line" else i + 1
        veh = vehicles.setdefault(vid, ManifestVehicle(vid))
        (veh.train if role == "train" else veh.validate).append(p)
        veh.rows.append(seen[key])
    return vehicles


def fingerprint(vehicle: ManifestVehicle, settings: dict) -> str:
    """A hash of what a vehicle's result depends on: the settings (start parameters, fit set,
    options) and each drive's path, role, size and modification time.  A finished vehicle is
    skipped on a rerun only while its fingerprint is unchanged."""
    drives = []
    for p, role in vehicle.drives:
        try:
            st = os.stat(p)
            drives.append([str(p), role, st.st_size, st.st_mtime_ns])
        except OSError:
            drives.append([str(p), role, None, None])
    text = json.dumps({"settings": settings, "drives": drives}, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:24]
