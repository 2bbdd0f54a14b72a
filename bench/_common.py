"""Shared set-up of the identification bars (bench/bench_identify.py, bench/bench_identify_fixes.py):
the working folder, the start file, and the simulated training and held-out drives written as CSV."""

from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import jaxmodel as jm
from identification.drive_log import write_drive
from identification.simulate import simulate


def rmse_deg(heading_deg, ref_rad) -> float:
    """RMS (deg) of the wrapped difference between a heading in degrees and a reference in radians."""
    e = np.angle(np.exp(1j * (np.radians(heading_deg) - ref_rad)))
    return float(np.degrees(np.sqrt(np.mean(e**2))))


@dataclass
class BarDrives:
    work: Path               # the working folder (kept with --keep, else a fresh temporary one)
    start: object            # Params of the start file (work / "start.json")
    true_params: object      # the start file with the vehicle's values
    train: list[Path]        # training drive logs
    held: list[Path]         # held-out drive logs (always with ref_heading_deg)


def simulated_bar_drives(keep, prefix: str, start: dict, vehicle: dict, train, held_out, seed: int,
                         fixes_sigma: float | None = None, train_reference: bool = True) -> BarDrives:
    """Write start.json, ``train_<scenario>.csv`` (simulation seeds 100 seed + i) and
    ``heldout_<scenario>.csv`` (100 seed + 50 + i) of a vehicle with ``vehicle``'s parameters into
    ``keep`` (or a temporary folder named ``prefix``...); ``fixes_sigma``: 1 Hz fixes of that sigma;
    ``train_reference`` False: the training drives lose ``ref_heading_deg`` (the held-out ones keep it
    for scoring)."""
    work = Path(keep) if keep else Path(tempfile.mkdtemp(prefix=prefix))
    work.mkdir(parents=True, exist_ok=True)
    start_p = jm.make_params(start)
    jm.save_params(work / "start.json", start_p)
    true_params = jm.make_params(dict(jm.params_to_dict(start_p), **vehicle))
    paths = {"train": [], "heldout": []}
    for tag, drives, offset in (("train", train, 0), ("heldout", held_out, 50)):
        for i, (sc, dur) in enumerate(drives):
            path = work / f"{tag}_{sc}.csv"
            cols = simulate(sc, dur, seed=seed * 100 + offset + i, params=vehicle, fixes_sigma=fixes_sigma)[0]
            if tag == "train" and not train_reference:
                cols.pop("ref_heading_deg")
            write_drive(path, cols)
            paths[tag].append(path)
    return BarDrives(work, start_p, true_params, paths["train"], paths["heldout"])
