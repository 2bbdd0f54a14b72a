"""Which XLA:CPU kernels the vmapped scan of one configuration spends its time in (the tool that found
stop 21's slowdown: a sine repeated in 22 kernels, a flag recomputed for every field of a packed state).

    .venv/bin/python bench/profile_kernels.py [--config default|complementary|seed|kalman|odometer] [--drives 64] [--samples 200] [--top 15]

Runs ``jax.profiler`` over one batch (bench_run.make_batch) and prints, per kernel (thunk) of the scan's
body, its median duration per step, with the kernel count per step and the sum.  The profiler adds
~0.3 us to every kernel: compare kernels with each other, and whole configurations with bench_run.py.
The largest kernels name their HLO op (``jit(...)/while/body/...``); ``compiled.as_text()`` shows their
fused computations.
"""

import argparse
import collections
import glob
import gzip
import json
import sys
import tempfile
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)
sys.path.insert(0, str(Path(__file__).resolve().parent))
import jaxmodel as jm  # noqa: E402
from bench_run import batch_headings, make_batch  # noqa: E402

CONFIGS = {"default": dict(), "complementary": dict(refine_a=False, calibration=False),
           "seed": dict(robust=False), "kalman": dict(mode="kalman"), "odometer": dict(mode="odometer")}


def kernel_medians(compiled, batch, steps):
    """Median duration (us) of each kernel that ran once per step, from one profiled run."""
    with tempfile.TemporaryDirectory() as folder:
        with jax.profiler.trace(folder):
            compiled(batch).block_until_ready()
        trace = json.load(gzip.open(glob.glob(f"{folder}/**/*.trace.json.gz", recursive=True)[0]))
    durations = collections.defaultdict(list)
    for event in trace["traceEvents"]:
        name = event.get("name", "")
        if event.get("ph") == "X" and not name.startswith(("$", "end:")) and "Thunk" not in name:
            durations[name].append(event["dur"])
    return {name: sorted(d)[len(d) // 2] for name, d in durations.items() if len(d) >= steps}


def _attribute(text, name):
    """The value of ``name=`` in one line of HLO text (an instruction or a table row), or None."""
    return text.split(f"{name}=")[1].split()[0].rstrip("},") if f"{name}=" in text else None


def _source_lines(text):
    """stack_frame_id -> "file.py:line" of the frame, from the HLO text's FileNames/FileLocations/StackFrames tables."""
    tables, current = collections.defaultdict(dict), None
    for line in text.splitlines():
        if line in ("FileNames", "FunctionNames", "FileLocations", "StackFrames"):
            current = line
        elif not line.strip():
            current = None
        elif current:
            key, _, rest = line.partition(" ")
            tables[current][key] = rest
    files = {k: Path(v.strip('"')).name for k, v in tables["FileNames"].items()}
    where = {}
    for frame, rest in tables["StackFrames"].items():
        loc = tables["FileLocations"].get(_attribute(rest, "file_location_id"), "")
        if loc:
            where[frame] = f"{files.get(_attribute(loc, 'file_name_id'), '?')}:{_attribute(loc, 'line')}"
    return where


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", choices=sorted(CONFIGS), default="default")
    ap.add_argument("--drives", type=int, default=64)
    # The profiler's event buffer is bounded: the default's ~640 kernels per step over 900 steps overflowed it and no
    # kernel reached ``steps`` events, so nothing was printed (stop 60); 200 steps fit.
    ap.add_argument("--samples", type=int, default=200)
    ap.add_argument("--top", type=int, default=15)
    args = ap.parse_args()
    batch, _, _ = make_batch(args.drives, args.samples)
    compiled = jax.jit(batch_headings(jm.make_params(), jm.Config(**CONFIGS[args.config]))).lower(batch).compile()
    compiled(batch).block_until_ready()
    medians = kernel_medians(compiled, batch, args.samples)
    text = compiled.as_text()
    where = _source_lines(text)
    print(f"{args.config}: {len(medians)} kernels per step, sum of medians {sum(medians.values()):.1f} us "
          f"({args.drives} drives, profiled)")
    for name, us in sorted(medians.items(), key=lambda kv: -kv[1])[:args.top]:
        line = next((ln for ln in text.splitlines() if ln.lstrip().startswith(f"%{name} = ")), "")
        op = line.split('op_name="')[1].split('"')[0] if 'op_name="' in line else ""
        print(f"{us:8.2f} us  {name:40s} {where.get(_attribute(line, 'stack_frame_id'), ''):22s} {op[-60:]}")


if __name__ == "__main__":
    main()
