"""Write the example input and reference output of the OdoCompass FMUs (Reference-FMUs convention).

``python -m fmu.make_examples [--fmu FMU] [--out fmu/examples]`` builds the FMU (the native one,
default parameters; both FMUs give the same outputs within 1e-12) unless one is given, and writes

* ``OdoCompass_in.csv``: ``time`` plus the FMU inputs ``left_pulses, right_pulses, compass_x,
  compass_y`` -- a 60 s simulated urban drive (``identification.simulate``, seed 3) sampled as a
  real 10 Hz sensor is: every row holds the counters and the field AT its own time (counters
  interpolated along the travelled distance, never a repeated count while the car moves).  The
  first row is at the start time; the others are stamped ``ROW_LEAD_S`` (1e-11 s) before their
  communication point, so a master that picks "the row at or before t" cannot alias onto the
  previous row through rounding of its accumulated time (the FMU Compliance Checker adds up h);
* ``OdoCompass_ref.csv``: ``time`` plus eight outputs as ``fmpy.simulate_fmu(fmu, input=...,
  output_interval=0.1)`` computes them.  ``checker_replay`` reproduces the Compliance Checker's own
  input sampling (time accumulated step by step, Integer inputs from the row at or before t, Real
  inputs interpolated linearly); the tests check that it gives the reference within 1e-9 with a
  freshly built FMU, so a stale reference fails.

Regenerate the pair whenever ``jaxmodel``'s results change.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
OUTPUTS = ("heading", "wheel_heading", "compass_heading", "x", "y", "speed", "a_current", "heading_reliability")
INPUTS = ("left_pulses", "right_pulses", "compass_x", "compass_y")
ROW_LEAD_S = 1e-11
"""Rows are stamped this much before their communication point: far above the drift of a master that
adds up h (~5e-13 s after 600 steps), far below fmpy's event tolerance (math.isclose, 1e-9 relative),
so every master picks the same row, and fmpy takes no extra steps."""


def example_inputs(duration_s: float = 60.0, seed: int = 3, step: float = 0.1) -> dict[str, np.ndarray]:
    """The sensor rows: t = 0, then half-way between communication points (see the module text)."""
    from identification.simulate import simulate

    cols, truth = simulate("urban", duration_s + 5.0, seed, anomalies=True)
    modulus = 65536.0
    t_src = np.asarray(cols["time_s"], dtype=np.float64) - float(cols["time_s"][0])
    grid = np.round(np.arange(step, duration_s + 0.5 * step, step), 10)
    rows = np.concatenate([[0.0], grid - ROW_LEAD_S])
    out = {"time": rows}
    for name in INPUTS:
        src = np.asarray(cols[name], dtype=np.float64)
        if name.endswith("pulses"):  # the counter at the row's own time: unwrap, interpolate, floor, wrap
            unwrapped = src[0] + np.concatenate([[0.0], np.cumsum(np.mod(np.diff(src) + modulus / 2, modulus)
                                                                   - modulus / 2)])
            out[name] = np.mod(np.floor(np.interp(rows, t_src, unwrapped)), modulus).astype(np.int64)
        else:
            out[name] = np.interp(rows, t_src, src)
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


def checker_replay(fmu: str | Path, inputs_csv: str | Path, stop_time: float, step: float = 0.1,
                   start_values: dict | None = None) -> dict[str, np.ndarray]:
    """The FMU driven as the FMU Compliance Checker drives it: time accumulated step by step
    (``t += h``), inputs at t before ``doStep(t, h)``: Integer inputs from the row at or before t,
    Real inputs interpolated linearly; outputs after each step (and after initialization)."""
    from fmpy.util import read_csv

    from .cosim import Slave

    inp = read_csv(str(inputs_csv))
    times = np.asarray(inp["time"], dtype=np.float64)

    def sample(t):
        k = max(0, int(np.searchsorted(times, t, side="right")) - 1)
        return {"left_pulses": int(inp["left_pulses"][k]), "right_pulses": int(inp["right_pulses"][k]),
                "compass_x": float(np.interp(t, times, inp["compass_x"])),
                "compass_y": float(np.interp(t, times, inp["compass_y"]))}

    s = Slave(fmu, "checker")
    try:
        s.initialize(0.0, start_values, sample(0.0))
        rows = [(0.0, s.get(OUTPUTS))]
        t = 0.0
        while t < stop_time - 0.5 * step:
            s.set(sample(t))
            s.step(t, step)
            t += step
            rows.append((t, s.get(OUTPUTS)))
    finally:
        s.close()
    return {"time": np.array([r[0] for r in rows]), **{n: np.array([r[1][n] for r in rows]) for n in OUTPUTS}}


def write_examples(out_dir: str | Path = HERE / "examples", fmu: str | Path | None = None) -> tuple[Path, Path]:
    import tempfile

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="odocompass_examples_") as tmp:
        if fmu is None:
            from .native_fmu import build_native_fmu

            fmu = build_native_fmu(Path(tmp) / "OdoCompassNative.fmu", configs=[])
        cols = example_inputs()
        in_path = out_dir / "OdoCompass_in.csv"
        write_csv(in_path, cols)
        ref = reference(fmu, in_path, 60.0)
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
