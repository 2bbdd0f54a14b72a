"""Safe outputs: every command checks where it will write *before* the work, never writes over
one of its inputs, and writes each file atomically (issue 11).

* ``check_output_file(path, inputs)`` (inputs: paths or (description, path) pairs) refuses, with one line naming the path, an output that
  resolves (symlinks and hard links included) to any input, a directory where a file is
  expected, a path under an existing file, and a location that cannot be written (the nearest
  existing folder is not writable).  Nothing is created: a refused command leaves no trace.
* ``check_output_dir(path, inputs)`` the same for an output folder (``--plots``, ``--out-dir``).
* ``atomic(path)`` is a context manager yielding a temporary path beside the target (same folder,
  so the final rename is atomic; same suffix, for libraries that choose the format by it); on
  success the temporary file replaces the target, on failure it is removed and the previous
  target, if any, is left untouched.
* ``staged(paths)`` does the same for several files written together (a drive and its truth
  files): they are written into a hidden folder beside the first one and renamed into place
  only when all were written.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Iterable, Iterator, Sequence

from .errors import OdoCompassError


class OutputError(OdoCompassError):
    """An output location is unusable or would overwrite an input."""


def _resolved(path: Path) -> Path:
    return Path(os.path.realpath(os.path.abspath(os.path.expanduser(str(path)))))


def same_file(a, b) -> bool:
    """True if ``a`` and ``b`` name the same file: equal after resolving symlinks, or (both
    existing) the same inode (hard links, bind mounts)."""
    a, b = Path(a), Path(b)
    if _resolved(a) == _resolved(b):
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def _nearest_existing(path: Path) -> Path:
    p = _resolved(path)
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


def _writable_folder(path: Path, anc: Path, label: str) -> None:
    """``anc`` (an existing folder) accepts a new file: asked of the system, then tried with a hidden
    probe file that is removed at once (permissions alone say nothing for root or read-only mounts)."""
    problem = None
    if not os.access(anc, os.W_OK | os.X_OK):
        problem = "is not writable"
    else:
        try:
            fd, probe = tempfile.mkstemp(prefix=".odocompass-probe.", dir=anc)
            os.close(fd)
            os.unlink(probe)
        except OSError as exc:
            problem = f"is not writable ({exc.strerror or exc})"
    if problem:
        raise OutputError(f"{path}: cannot write {label}: folder {anc} {problem}")


def _check_location(path: Path, label: str) -> None:
    """The folder that will hold ``path`` exists or can be created there, and is writable."""
    parent = _resolved(path).parent
    anc = _nearest_existing(parent)
    if not anc.is_dir():
        raise OutputError(f"{path}: cannot write {label}: {anc} is a file, not a folder")
    _writable_folder(path, anc, label)


def _named_inputs(inputs: Iterable) -> list[tuple[str, Path]]:
    """Inputs given as paths or (description, path) pairs; None entries are skipped."""
    out = []
    for item in inputs:
        what, inp = item if isinstance(item, tuple) else ("the input", item)
        if inp is not None:
            out.append((what, Path(inp)))
    return out


def _check_not_input(path: Path, inputs: Iterable, label: str) -> None:
    for what, inp in _named_inputs(inputs):
        if same_file(path, inp):
            shown = f"{what} itself" if str(path) == str(inp) else f"{what} {inp} (the same file)"
            raise OutputError(f"{path}: {label} is {shown}; refusing to write over an input, "
                              f"choose another output name")


def check_output_file(path, inputs: Iterable = (), label: str = "--out", suffixes: Sequence[str] | None = None) -> Path:
    """Check an output *file* before the work (see the module docstring); returns it as a Path."""
    path = Path(path)
    _check_not_input(path, inputs, label)
    if path.is_dir() or str(path).endswith(os.sep):
        raise OutputError(f"{path}: {label} is a folder; give a file name")
    if suffixes is not None and path.suffix.lower() not in suffixes:
        raise OutputError(f"{path}: {label} must end in {' or '.join(suffixes)}, got {path.suffix or '(none)'!r}")
    _check_location(path, label)
    return path


def check_output_dir(path, inputs: Iterable = (), label: str = "--out-dir") -> Path:
    """Check an output *folder* before the work; returns it as a Path."""
    path = Path(path)
    for what, inp in _named_inputs(inputs):
        if same_file(path, inp):
            raise OutputError(f"{path}: {label} is {what} {inp}; choose another folder")
    anc = _nearest_existing(path)
    if not anc.is_dir():
        what = "is a file, not a folder" if anc == _resolved(path) else "is a file, not a folder, in the way"
        raise OutputError(f"{path}: cannot write {label}: {anc} {what}")
    _writable_folder(path, anc, label)
    return path


def check_folder_files(out_dir, names: Iterable[str], inputs: Iterable, label: str = "--out") -> None:
    """OutputError when a file ``names`` that a command writes into ``out_dir`` already exists as one of ``inputs``
    ((description, path) pairs): the fleet commands' tables and files beside the logs they read."""
    inputs = list(inputs)
    for name in names:
        target = Path(out_dir) / name
        for what, inp in inputs:
            if target.exists() and same_file(target, inp):
                raise OutputError(f"{target}: {label} would write over {what} {inp}; choose another folder")


def check_drive_outputs(drive, companions=None, inputs: Iterable = ()) -> list[Path]:
    """``check_output_file`` for a drive log (known extension) and the files written beside it;
    ``companions(drive)`` gives their paths (truth files, a parameter file).  Returns
    [drive, *companions] as Paths."""
    from .drive_log import _format_of

    inputs = list(inputs)
    drive = check_output_file(drive, inputs=inputs, label="--out")
    _format_of(drive)
    others = list(companions(drive)) if companions is not None else []
    return [drive] + [check_output_file(p, inputs=inputs, label=f"--out's companion {Path(p).name}") for p in others]


def temporary_beside(path) -> Path:
    """A fresh hidden name beside ``path`` with the same suffix (not created)."""
    path = Path(path)
    fd, name = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f".tmp{path.suffix}", dir=path.parent)
    os.close(fd)
    os.unlink(name)
    return Path(name)


def _cannot_write(path: Path, exc: OSError) -> OutputError:
    return OutputError(f"{path}: cannot write: {exc.strerror or exc}")


@contextmanager
def atomic(path) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success it replaces ``path`` (see module docstring)."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = temporary_beside(path)
    except OSError as exc:
        raise _cannot_write(path, exc) from None
    try:
        yield tmp
        if not tmp.exists():
            raise OutputError(f"{path}: nothing was written")
        os.replace(tmp, path)
    except OSError as exc:
        raise _cannot_write(path, exc) from None
    finally:
        _remove(tmp)


def write_text(path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    path = Path(path)
    with atomic(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return path


@contextmanager
def staged(paths: Sequence) -> Iterator[list[Path]]:
    """Yield temporary paths (same names, in a hidden folder beside the first path) for files that
    are written together; all replace their targets only once the block has succeeded."""
    paths = [Path(p) for p in paths]
    try:
        paths[0].parent.mkdir(parents=True, exist_ok=True)
        stage = Path(tempfile.mkdtemp(prefix=f".{paths[0].stem}.", suffix=".tmp", dir=paths[0].parent))
    except OSError as exc:
        raise _cannot_write(paths[0], exc) from None
    try:
        tmps = [stage / p.name for p in paths]
        yield tmps
        for p, t in zip(paths, tmps):
            if not t.exists():
                raise OutputError(f"{p}: nothing was written")
        for p, t in zip(paths, tmps):
            try:
                p.parent.mkdir(parents=True, exist_ok=True)
                os.replace(t, p)
            except OSError as exc:
                raise _cannot_write(p, exc) from None
    finally:
        shutil.rmtree(stage, ignore_errors=True)


def _remove(p: Path) -> None:
    try:
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)
        elif os.path.lexists(p):
            p.unlink()
    except OSError:
        pass
