"""Could a native batch engine meet issue 10's throughput bar?  The default step lowered to C, side by side with XLA.

    .venv/bin/python bench/bench_native_batch.py [--drives 64] [--samples 9000] [--lanes 8]

The native FMU's lowering (``fmu/jaxpr_lower.py``: the jaxpr of ``jaxmodel.run_from`` for one sample, scalarised,
folded, common subexpressions shared) is compiled here into a batch loop over drives and samples, two ways:

* scalar: the FMU's own C (``Engine.native_source``), one drive at a time (gcc -O2, IEEE float64);
* lanes: the same program written over ``--lanes`` drives at once, every operation a loop over the lanes that gcc
  vectorises (-O3 -march=native, still without fast-math or FMA contraction: the same results).

Both run on ``bench_run.make_batch`` and are printed beside ``jit(vmap(run))`` of the default and of the seed
filter (the issue-10 bar is the default at >= 0.8x of the seed filter), with the number of operations of each
lowered step and the largest difference from the XLA outputs.  Read the ratios at the default size: on a few
hundred samples XLA's per-call overhead dominates (8 x 300 made the C 1.09x).  An experiment, not an engine of
the package: the lane renderer below reads the lowered ``Program``'s lines, as ``Program.to_c`` does.
"""

from __future__ import annotations

import argparse
import ctypes
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)
import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))
import jaxmodel as jm  # noqa: E402
from bench_run import make_batch, measure  # noqa: E402
from fmu.build import LOWERING  # noqa: E402
from fmu.engine import NATIVE_INIT, NATIVE_STEP, Engine  # noqa: E402

C_FLAGS = ("-std=c99", "-fPIC", "-shared", "-ffp-contract=off", "-fno-fast-math")
_CTYPE = {"float": "double", "int": "long long", "bool": "int"}


def _lanes_c(program, ref_type, lit_c, name: str, lanes: int) -> str:
    """``program`` (a lowered step) as C over ``lanes`` drives: every local an array over the lanes, every
    operation a loop gcc vectorises; inputs and outputs lane-major (lane l's vector at l * size)."""
    shared = set()  # tables of constants: one copy for every lane

    def lit(atom):
        if isinstance(atom, ref_type):
            return atom.name if atom.name in shared else f"{atom.name}[l]"
        return lit_c(atom)

    loop = f"for (int l = 0; l < {lanes}; ++l)"
    args, body = [], []
    for spec in program.inputs:
        if spec is not None:
            i, size, _ = spec
            args.append(f"const double *restrict A{i}")
            body += [f"    double a{i}_{k}[{lanes}]; {loop} a{i}_{k}[l] = A{i}[l * {size} + {k}];" for k in range(size)]
    args += [f"double *restrict R{j}" for j in range(len(program.outs))]
    for line in program.lines:
        t = _CTYPE[line.kind]
        if line.tpl is not None:
            body.append(f"    {t} {line.target}[{lanes}]; {loop} {line.target}[l] = "
                        + line.tpl.c.format(*[lit(a) for a in line.operands]) + ";")
        elif not any(isinstance(a, ref_type) for a in line.operands):
            shared.add(line.target)
            body.append(f"    static const {t} {line.target}[{len(line.operands)}] = {{"
                        + ", ".join(lit_c(a) for a in line.operands) + "};")
        else:
            body.append(f"    {t} {line.target}[{lanes}][{len(line.operands)}]; {loop} {{ "
                        + " ".join(f"{line.target}[l][{k}] = {lit(a)};" for k, a in enumerate(line.operands)) + " }")
    for j, out in enumerate(program.outs):
        flat = out.reshape(-1)
        body += [f"    {loop} R{j}[l * {flat.size} + {k}] = (double)({lit(a)});" for k, a in enumerate(flat)]
    return f"void {name}({', '.join(args)})\n{{\n" + "\n".join(body) + "\n}\n"


def _batch_loop(lanes: int, n_param: int, n_state: int, n_in: int, n_out: int, step: str) -> str:
    """``odc_batch(n_drives, n_samples, P, X, Y)``: X (n_in, n_drives, n_samples), Y (n_drives, n_samples, n_out)."""
    return f"""
void odc_batch(long n_drives, long n_samples, const double *restrict P, const double *restrict X, double *restrict Y)
{{
  for (long d0 = 0; d0 < n_drives; d0 += {lanes}) {{
    double pw[{lanes * n_param}], s0[{lanes * n_state}], s1[{lanes * n_state}], x[{lanes * n_in}], y[{lanes * n_out}];
    for (int l = 0; l < {lanes}; ++l) {{
      for (int k = 0; k < {n_param}; ++k) pw[l * {n_param} + k] = P[k];
      {NATIVE_INIT}(P, s0 + l * {n_state});
    }}
    double *a = s0, *b = s1;
    for (long t = 0; t < n_samples; ++t) {{
      for (int l = 0; l < {lanes}; ++l)
        for (int k = 0; k < {n_in}; ++k) x[l * {n_in} + k] = X[(k * n_drives + d0 + l) * n_samples + t];
      {step}({"pw" if lanes > 1 else "P"}, a, x, b, y);
      for (int l = 0; l < {lanes}; ++l)
        for (int k = 0; k < {n_out}; ++k) Y[((d0 + l) * n_samples + t) * {n_out} + k] = y[l * {n_out} + k];
      double *c = a; a = b; b = c;
    }}
  }}
}}
"""


def _compile(source: str, folder: Path, name: str, opt: list[str]) -> tuple[ctypes.CDLL, float]:
    c_file, lib = folder / f"{name}.c", folder / f"{name}.so"
    c_file.write_text(source)
    t0 = time.perf_counter()
    proc = subprocess.run(["gcc", *opt, *C_FLAGS, "-o", str(lib), str(c_file), "-lm"], capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(f"gcc failed on {c_file.name}: {proc.stderr.strip()[:500]}")
    return ctypes.CDLL(str(lib)), time.perf_counter() - t0


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--drives", type=int, default=64)
    ap.add_argument("--samples", type=int, default=9000)
    ap.add_argument("--lanes", type=int, default=8)
    args = ap.parse_args()
    if args.drives % args.lanes:
        raise SystemExit(f"--drives {args.drives} must be a multiple of --lanes {args.lanes}")
    if shutil.which("gcc") is None:
        raise SystemExit("this benchmark needs gcc")
    batch, _, _ = make_batch(args.drives, args.samples)
    params = jm.make_params()
    X = np.ascontiguousarray(np.stack([np.asarray(getattr(batch, f), np.float64) for f in jm.Inputs._fields]))
    n_in, n_out = len(jm.Inputs._fields), len(jm.Outputs._fields)
    ptr = lambda a: a.ctypes.data_as(ctypes.c_void_p)  # noqa: E731
    print(f"{args.drives} drives x {args.samples} samples (bench_run.make_batch), float64; best of 3 runs")
    print(f"{'configuration':10s} {'engine':28s} {'ops/step':>8s} {'build s':>8s} {'run s':>7s} {'max |diff|':>10s}")
    seconds = {}
    with tempfile.TemporaryDirectory(prefix="odc_native_batch_") as tmp:
        tmp = Path(tmp)
        bundle = tmp / "bundle"
        shutil.copytree(ROOT / "jaxmodel", bundle / "jaxmodel", ignore=shutil.ignore_patterns("__pycache__"))
        for name in LOWERING:
            shutil.copy2(ROOT / "fmu" / name, bundle / name)
        eng = Engine(bundle, "bench_native_batch")
        _, _, lower = eng.modules()
        lit_c = sys.modules[lower.Program.__module__]._lit_c
        for label, robust in (("default", True), ("seed", False)):
            config = jm.Config(robust=robust)
            compile_s, best = measure(params, batch, config)
            seconds[(label, "xla")] = best
            reference = jax.jit(jax.vmap(lambda i: jm.run_from(params, jm.init_state(params), i, config)[1]))(batch)
            reference = np.stack([np.asarray(getattr(reference, f)) for f in jm.Outputs._fields], axis=-1)
            print(f"{label:10s} {'XLA jit(vmap(run))':28s} {'':>8s} {compile_s:8.1f} {best:7.3f} {'':>10s}", flush=True)
            p, cfg = eng.make(jm.params_to_dict(params), {})
            cfg = cfg._replace(robust=robust)
            closed_init, _, closed, _, n_state = eng.trace(p, cfg)
            init_prog = lower.lower_program(closed_init, [None])
            step_prog = lower.lower_program(closed, [None, None, None])
            pflat = np.ascontiguousarray(eng.flat_params(p))
            n_param = pflat.size
            engines = (("C, one drive at a time", 1, ["-O2"]),
                       (f"C, {args.lanes} lanes (-march=native)", args.lanes, ["-O3", "-march=native"]))
            for engine, lanes, opt in engines:
                step = NATIVE_STEP if lanes == 1 else "odc_step_lanes"
                source = lower.C_PRELUDE + init_prog.to_c(NATIVE_INIT) + "\n" + (
                    step_prog.to_c(NATIVE_STEP) if lanes == 1 else _lanes_c(step_prog, lower.Ref, lit_c, step, lanes))
                source += _batch_loop(lanes, n_param, n_state, n_in, n_out, step)
                lib, build_s = _compile(source, tmp, f"{label}_{lanes}", opt)
                Y = np.zeros((args.drives, args.samples, n_out))
                runs = []
                for _ in range(3):
                    t0 = time.perf_counter()
                    lib.odc_batch(ctypes.c_long(args.drives), ctypes.c_long(args.samples), ptr(pflat), ptr(X), ptr(Y))
                    runs.append(time.perf_counter() - t0)
                seconds[(label, lanes)] = min(runs)
                diff = float(np.nanmax(np.abs(Y - reference)))
                print(f"{label:10s} {engine:28s} {step_prog.n_ops:8d} {build_s:8.1f} {min(runs):7.3f} {diff:10.1e}",
                      flush=True)
    seed = seconds[("seed", "xla")]
    print("throughput of the default relative to the XLA seed filter (issue 10 bar >= 0.8x): "
          f"XLA {seed / seconds[('default', 'xla')]:.2f}x, C {seed / seconds[('default', 1)]:.2f}x, "
          f"C {args.lanes} lanes {seed / seconds[('default', args.lanes)]:.2f}x")


if __name__ == "__main__":
    main()
