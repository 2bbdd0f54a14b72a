"""Write the example input and reference output of the OdoCompass FMU (Reference-FMUs convention).

``python -m fmu.make_examples [--fmu build/OdoCompass.fmu] [--out fmu/examples]`` writes

* ``OdoCompass_in.csv``: ``time`` plus the FMU inputs ``left_pulses, right_pulses, compass_x,
  compass_y`` -- a 60 s simulated urban drive at 10 Hz (``identification.simulate``, seed 3);
* ``OdoCompass_ref.csv``: ``time`` plus eight outputs, as ``fmpy.simulate_fmu(fmu, input=...,
  output_interval=0.1)`` computes them (the file fmusim / the FMU Compliance Checker compare
  with).  Under such a master the input row at time t is set before ``doStep(t, 0.1)`` and the
  FMU stamps it ``t + 0.1``: the output at t + 0.1 is the estimate after the row of t (the
  first row is also the initialization sample, so it is processed twice, the second time as a
  sample without motion).

Regenerate the pair whenever ``jaxmodel``'s results change.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
OUTPUTS = ("heading", "wheel_heading", "compass_heading", "x", "y", "speed", "a_current", "heading_reliability")
INPUTS = ("left_pulses", "right_pulses", "compass_x", "compass_y")


def example_inputs(duration_s: float = 60.0, seed: int = 3) -> dict[str, np.ndarray]:
    """A simulated urban drive on an exact 0.1 s grid (counts as integers)."""
    from identification.simulate import simulate

    cols, _ = simulate("urban", duration_s + 5.0, seed, anomalies=True)
    t_src = np.asarray(cols["time_s"], dtype=np.float64)
    grid = np.round(np.arange(0.0, duration_s + 1e-9, 0.1), 10)
    out = {"time": grid}
    for name in INPUTS:
        src = np.asarray(cols[name], dtype=np.float64)
        if name.endswith("pulses"):
            idx = np.clip(np.searchsorted(t_src, grid + t_src[0], side="right") - 1, 0, len(src) - 1)
            out[name] = src[idx].astype(np.int64)
        else:
            out[name] = np.interp(grid + t_src[0], t_src, src)
    return out


def write_csv(path: Path, columns: dict[str, np.ndarray]) -> None:
    names = list(columns)
    with open(path, "w") as f:
        f.write(",".join(names) + "\n")
        for k in range(len(columns[names[0]])):
            row = []
            for n in names:
                v = columns[n][k]
                row.append(str(int(v)) if np.issubdtype(np.asarray(columns[n]).dtype, np.integer) else repr(float(v)))
            f.write(",".join(row) + "\n")


def reference(fmu: str | Path, inputs_csv: str | Path, stop_time: float) -> dict[str, np.ndarray]:
    from fmpy import simulate_fmu
    from fmpy.util import read_csv

    res = simulate_fmu(str(fmu), input=read_csv(str(inputs_csv)), output=list(OUTPUTS), output_interval=0.1,
                       stop_time=stop_time, start_time=0.0)
    return {"time": np.asarray(res["time"]), **{n: np.asarray(res[n]) for n in OUTPUTS}}


def write_examples(out_dir: str | Path = HERE / "examples", fmu: str | Path | None = None) -> tuple[Path, Path]:
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    if fmu is None:
        from .build import build_estimator

        fmu = build_estimator(out_dir.parent / "_example_build" / "OdoCompass.fmu")
    cols = example_inputs()
    in_path = out_dir / "OdoCompass_in.csv"
    write_csv(in_path, cols)
    ref = reference(fmu, in_path, float(cols["time"][-1]))
    ref_path = out_dir / "OdoCompass_ref.csv"
    write_csv(ref_path, ref)
    return in_path, ref_path


def main(argv=None) -> int:
    import jax

    jax.config.update("jax_enable_x64", True)
    ap = argparse.ArgumentParser(prog="python -m fmu.make_examples", description=__doc__.splitlines()[0])
    ap.add_argument("--fmu", default=None, help="a built OdoCompass.fmu (default: build one)")
    ap.add_argument("--out", default=str(HERE / "examples"))
    args = ap.parse_args(argv)
    for p in write_examples(args.out, args.fmu):
        print("wrote", p)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
