"""FMU throughput and correctness: the native FMU in a small C master, both FMUs in fmpy side by side
with a trivial pythonfmu FMU, the time to the first step, and the pythonfmu exit-time soak.

    .venv/bin/python bench/bench_fmu.py [--fmu build/OdoCompass.fmu] [--native-fmu build/OdoCompassNative.fmu]
                                        [--steps 20000] [--repeats 5] [--c-steps 300000] [--soak 500]

One step = what a co-simulation master does per sensor sample: ``setInteger`` (left/right
pulse counters), ``setReal`` (compass x/y), ``doStep``, ``getReal`` (eight outputs).  The trivial
FMU (built here with pythonfmu, same interface, ``do_step`` copies one value) gives the floor of
pythonfmu + fmpy overhead.  All run in this process, interleaved, repeated; the best repetition
of each is reported (the machine is shared).  Engines of the pythonfmu OdoCompass FMU: ``native``
(the jaxmodel step lowered to C at build time), ``python`` and ``xla``; ``OdoCompassNative`` is
the Python-free FMU of ``build-fmu --native``.

* C master (issue 12): a small C program (written and compiled here against fmpy's FMI headers)
  loads OdoCompassNative's binary with dlopen and steps a drive, one sample per ``fmi2DoStep``
  (setInteger, setReal, doStep, getReal of the heading); best of the repetitions; its headings are
  compared with ``jaxmodel.run`` at every sample.
* Soak (issue 12): ``--soak N`` runs N processes that each run four instances of the pythonfmu
  FMU and exit normally; it counts the processes that did not exit 0 (``--soak-no-guard``: the
  same with the slaves' exit guard switched off, to see the fault).

Targets: issue 5: >= 10,000 steps/s, <= 4x the trivial FMU, <= 5 s to the first step; issue 12:
native FMU >= 1e6 steps/s in the C master, >= 2x the pythonfmu FMU in fmpy, equal to jaxmodel within
1e-12 rad at every sample, 0 aborts in 500 normal exits.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

TRIVIAL = textwrap.dedent('''
    from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability, Integer, Real


    class TrivialBench(Fmi2Slave):
        """Same interface shape as OdoCompass's hot path: 2 Integer + 2 Real inputs, 8 Real outputs."""

        def __init__(self, **kwargs):
            super().__init__(**kwargs)
            self.left_pulses = self.right_pulses = 0
            self.compass_x = self.compass_y = 0.0
            self.out = [0.0] * 8
            for n in ("left_pulses", "right_pulses"):
                self.register_variable(Integer(n, causality=Fmi2Causality.input, variability=Fmi2Variability.discrete))
            for n in ("compass_x", "compass_y"):
                self.register_variable(Real(n, causality=Fmi2Causality.input, variability=Fmi2Variability.continuous))
            for i in range(8):
                self.register_variable(Real(f"o{i}", causality=Fmi2Causality.output,
                                            variability=Fmi2Variability.discrete, getter=lambda i=i: self.out[i]))

        def do_step(self, current_time, step_size):
            self.out[0] = self.compass_x + self.left_pulses
            return True
''')

OUTPUTS = ["heading", "wheel_heading", "compass_heading", "x", "y", "speed", "a_current", "heading_reliability"]

FIRST_STEP = textwrap.dedent('''
    import json, sys, time
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave
    path, engine = sys.argv[1], sys.argv[2]
    md = read_model_description(path)
    d = extract(path)
    vr = {v.name: v.valueReference for v in md.modelVariables}

    def start_and_step(name, inputs):
        """Instantiate, initialize (with the inputs when given) and take one step."""
        fmu = FMU2Slave(guid=md.guid, unzipDirectory=d, modelIdentifier=md.coSimulation.modelIdentifier,
                        instanceName=name)
        fmu.instantiate()
        fmu.setupExperiment(startTime=0.0)
        if engine != "default":
            fmu.setString([vr["engine"]], [engine])
        fmu.enterInitializationMode()
        if inputs:
            fmu.setInteger([vr["left_pulses"], vr["right_pulses"]], [100, 100])
            fmu.setReal([vr["compass_x"], vr["compass_y"]], [20.0, 1.0])
        fmu.exitInitializationMode()
        if inputs:
            fmu.setInteger([vr["left_pulses"], vr["right_pulses"]], [150, 149])
        fmu.doStep(0.0, 0.1)
        return fmu

    t0 = time.perf_counter()
    fmu = start_and_step("first", True)
    t1 = time.perf_counter()
    fmu2 = start_and_step("second", False)
    t2 = time.perf_counter()
    print(json.dumps({"first_s": t1 - t0, "second_instance_s": t2 - t1}))
''')


C_MASTER = r"""
/* bench_fmu.py's C master: one sensor sample per fmi2DoStep through an FMI 2.0 CS binary. */
#include <dlfcn.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include "fmi2Functions.h"

static void logger(fmi2ComponentEnvironment e, fmi2String n, fmi2Status s, fmi2String c, fmi2String m, ...)
{
    (void)e; (void)n;
    if (s > fmi2Warning) fprintf(stderr, "[%d] %s: %s\n", (int)s, c, m);
}

#define LOAD(name) name##TYPE *name = (name##TYPE *)dlsym(lib, #name); if (!name) { fprintf(stderr, #name "\n"); return 2; }

int main(int argc, char **argv)
{
    /* lib guid data.bin out.bin repeats vr_left vr_right vr_cx vr_cy vr_heading vr_discarded */
    void *lib = dlopen(argv[1], RTLD_NOW);
    FILE *f;
    long n, k;
    int rep, repeats = atoi(argv[5]);
    double *d, *heading, best = 1e300;
    fmi2ValueReference vi[2] = {atoi(argv[6]), atoi(argv[7])}, vr[2] = {atoi(argv[8]), atoi(argv[9])};
    fmi2ValueReference vh = atoi(argv[10]), vd = atoi(argv[11]);
    fmi2Integer discarded = -1;
    fmi2CallbackFunctions cb = {logger, calloc, free, NULL, NULL};
    if (!lib) { fprintf(stderr, "%s\n", dlerror()); return 2; }
    LOAD(fmi2Instantiate) LOAD(fmi2FreeInstance) LOAD(fmi2SetupExperiment) LOAD(fmi2EnterInitializationMode)
    LOAD(fmi2ExitInitializationMode) LOAD(fmi2SetInteger) LOAD(fmi2SetReal) LOAD(fmi2GetReal) LOAD(fmi2GetInteger)
    LOAD(fmi2DoStep) LOAD(fmi2Terminate)
    f = fopen(argv[3], "rb");
    if (!f || fread(&n, sizeof n, 1, f) != 1) return 3;
    d = malloc(sizeof(double) * 5 * n);
    heading = malloc(sizeof(double) * n);
    if (fread(d, sizeof(double), 5 * n, f) != (size_t)(5 * n)) return 3;
    fclose(f);
    for (rep = 0; rep < repeats; rep++) {
        struct timespec t0, t1;
        fmi2Integer ii[2];
        fmi2Real rr[2];
        double dt;
        fmi2Component c = fmi2Instantiate("cmaster", fmi2CoSimulation, argv[2], "", &cb, fmi2False, fmi2False);
        if (!c) return 4;
        fmi2SetupExperiment(c, fmi2False, 0.0, d[0], fmi2False, 0.0);
        fmi2EnterInitializationMode(c);
        ii[0] = (fmi2Integer)d[1]; ii[1] = (fmi2Integer)d[2]; rr[0] = d[3]; rr[1] = d[4];
        fmi2SetInteger(c, vi, 2, ii);
        fmi2SetReal(c, vr, 2, rr);
        if (fmi2ExitInitializationMode(c) > fmi2Warning) return 5;
        fmi2GetReal(c, &vh, 1, &heading[0]);
        clock_gettime(CLOCK_MONOTONIC, &t0);
        for (k = 1; k < n; k++) {
            const double *x = d + 5 * k;
            ii[0] = (fmi2Integer)x[1]; ii[1] = (fmi2Integer)x[2]; rr[0] = x[3]; rr[1] = x[4];
            fmi2SetInteger(c, vi, 2, ii);
            fmi2SetReal(c, vr, 2, rr);
            if (fmi2DoStep(c, d[5 * (k - 1)], x[0] - d[5 * (k - 1)], fmi2True) > fmi2Warning) return 6;
            fmi2GetReal(c, &vh, 1, &heading[k]);
        }
        clock_gettime(CLOCK_MONOTONIC, &t1);
        dt = (t1.tv_sec - t0.tv_sec) + 1e-9 * (t1.tv_nsec - t0.tv_nsec);
        if (dt < best) best = dt;
        fmi2GetInteger(c, &vd, 1, &discarded);
        fmi2Terminate(c);
        fmi2FreeInstance(c);
    }
    f = fopen(argv[4], "wb");
    fwrite(heading, sizeof(double), n, f);
    fclose(f);
    printf("{\"steps\": %ld, \"best_s\": %.9g, \"steps_per_s\": %.6g, \"discarded\": %d}\n", n - 1, best,
           (n - 1) / best, (int)discarded);
    return 0;
}
"""

SOAK = textwrap.dedent("""
    import sys
    from fmu.cosim import Slave
    for i in range(4):
        s = Slave(sys.argv[1], f"i{i}")
        s.initialize(0.0, None, {"compass_x": 20.0, "compass_y": 1.0, "left_pulses": 0, "right_pulses": 0})
        for k in range(1, 6):
            s.set({"left_pulses": 10 * k, "right_pulses": 10 * k})
            s.step(0.1 * (k - 1), 0.1)
        s.close()
""")


def c_master(native: Path, tmp: Path, n: int, repeats: int) -> dict:
    """Steps/s of the native FMU in the C master, and its heading against jaxmodel.run at every sample."""
    import numpy as np
    from fmpy import extract, read_model_description

    from fmu.native_fmu import fmi_headers

    import jax

    jax.config.update("jax_enable_x64", True)
    import jaxmodel

    md = read_model_description(str(native))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    start = {v.name: v.start for v in md.modelVariables if v.causality == "parameter"}
    left, right, cx, cy = drive(n)
    t = 0.1 * np.arange(n)
    data = np.stack([t, left, right, cx, cy], axis=1).astype(np.float64)
    (tmp / "data.bin").write_bytes(np.int64(n).tobytes() + data.tobytes())
    src = tmp / "cmaster.c"
    src.write_text(C_MASTER)
    exe = tmp / "cmaster"
    subprocess.run(["cc", "-O2", f"-I{fmi_headers()}", "-o", str(exe), str(src), "-ldl"], check=True)
    d = Path(extract(str(native)))
    lib = d / "binaries" / "linux64" / f"{md.coSimulation.modelIdentifier}.so"
    proc = subprocess.run([str(exe), str(lib), md.guid, str(tmp / "data.bin"), str(tmp / "heading.bin"),
                           str(repeats), *(str(vr[k]) for k in ("left_pulses", "right_pulses", "compass_x",
                                                                "compass_y", "heading", "discarded_samples"))],
                          capture_output=True, text=True, check=True)
    res = json.loads(proc.stdout)
    got = np.frombuffer((tmp / "heading.bin").read_bytes(), dtype=np.float64)
    values = {}
    for spec in jaxmodel.PARAMETER_TABLE:  # the FMU's start values are the parameters it was built with
        if isinstance(spec.default, (list, tuple)):
            values[spec.key] = [float(start[f"{spec.key}_{i}"]) for i in range(len(spec.default))]
        else:
            values[spec.key] = start[spec.key] if spec.key == "sensor_axle" else float(start[spec.key])
    inputs = jaxmodel.make_inputs(time_s=t, left_pulses=np.asarray(left, float), right_pulses=np.asarray(right, float),
                                  compass_x=np.asarray(cx), compass_y=np.asarray(cy))
    ref = np.asarray(jaxmodel.run(jaxmodel.make_params(values), inputs).heading)
    err = np.abs(np.mod(got - ref + np.pi, 2 * np.pi) - np.pi)
    res["max_heading_error_rad"] = float(np.max(err))
    return res


def soak(fmu: Path, n: int, guard: bool = True, jobs: int = 2) -> dict:
    """n processes, four instances each, normal exit: how many did not exit 0."""
    import concurrent.futures

    env = dict(os.environ, PYTHONPATH=str(REPO))
    if not guard:
        env["ODOCOMPASS_FMU_EXIT_GUARD"] = "0"

    def one(_):
        p = subprocess.run([sys.executable, "-c", SOAK, str(fmu)], capture_output=True, text=True, env=env,
                           cwd=tempfile.gettempdir(), timeout=600)
        return p.returncode, p.stderr[-300:]

    t0 = time.perf_counter()
    with concurrent.futures.ThreadPoolExecutor(jobs) as pool:
        results = list(pool.map(one, range(n)))
    bad = [(rc, err) for rc, err in results if rc != 0]
    return {"processes": n, "guard": guard, "abnormal_exits": len(bad), "codes": sorted({rc for rc, _ in bad}),
            "sample_stderr": bad[0][1] if bad else "", "seconds": time.perf_counter() - t0}


def build_trivial(dest: Path) -> Path:
    from pythonfmu.builder import FmuBuilder

    src = dest / "src"
    src.mkdir(parents=True, exist_ok=True)
    script = src / "TrivialBench.py"
    script.write_text(TRIVIAL)
    saved = list(sys.path)
    try:
        return Path(FmuBuilder.build_FMU(script, dest=dest))
    finally:
        sys.path[:] = saved
        sys.modules.pop("TrivialBench", None)


def drive(n: int):
    """n sensor samples (ints for counters): the build's check drive without its faults, lap after lap
    with the counters continuing where the previous lap ended."""
    import numpy as np

    from fmu.build import check_drive

    d = check_drive()
    d["right_pulses"][900] = d["right_pulses"][899]  # no counter glitch: a discard would stop fmpy
    m = len(d["time_s"])
    idx = np.arange(n) % m
    laps = np.arange(n) // m
    counts = []
    for name in ("left_pulses", "right_pulses"):
        c = d[name]
        lap_advance = c[-1] - c[0] + (c[-1] - c[-2])
        counts.append((np.mod(c[idx] + laps * lap_advance, 65536.0)).astype(int).tolist())
    cx = np.where(np.isfinite(d["compass_x"]), d["compass_x"], 20.0)[idx].tolist()
    cy = d["compass_y"][idx].tolist()
    return counts[0], counts[1], cx, cy


class Runner:
    def __init__(self, path: Path, outputs, data, engine: str | None = None):
        from fmpy import extract, read_model_description
        from fmpy.fmi2 import FMU2Slave

        md = read_model_description(str(path))
        self.vr = {v.name: v.valueReference for v in md.modelVariables}
        self.fmu = FMU2Slave(guid=md.guid, unzipDirectory=extract(str(path)),
                             modelIdentifier=md.coSimulation.modelIdentifier, instanceName="bench")
        self.fmu.instantiate()
        self.fmu.setupExperiment(startTime=0.0)
        if engine:
            self.fmu.setString([self.vr["engine"]], [engine])
        self.ivr = [self.vr["left_pulses"], self.vr["right_pulses"]]
        self.rvr = [self.vr["compass_x"], self.vr["compass_y"]]
        self.ovr = [self.vr[o] for o in outputs]
        self.fmu.enterInitializationMode()
        left, right, cx, cy = data
        self.fmu.setInteger(self.ivr, [left[0], right[0]])
        self.fmu.setReal(self.rvr, [cx[0], cy[0]])
        self.fmu.exitInitializationMode()
        self.t = 0.0
        self.k = 1

    def run(self, data, n: int) -> float:
        """Seconds per step over n steps (laps of the drive restart the estimator's counters smoothly)."""
        left, right, cx, cy = data
        fmu, ivr, rvr, ovr = self.fmu, self.ivr, self.rvr, self.ovr
        set_i, set_r, step, get_r = fmu.setInteger, fmu.setReal, fmu.doStep, fmu.getReal
        m = len(left)
        t, k = self.t, self.k
        t0 = time.perf_counter()
        for _ in range(n):
            j = k % m
            set_i(ivr, [left[j], right[j]])
            set_r(rvr, [cx[j], cy[j]])
            step(t, 0.1)
            get_r(ovr)
            t += 0.1
            k += 1
        dt = time.perf_counter() - t0
        self.t, self.k = t, k
        return dt / n


def run_lean(runner: "Runner", data, n: int) -> float:
    """Seconds per step through fmpy's bound fmi2* functions with preallocated ctypes arrays (what a
    master written for speed on fmpy does; the same per-call work for every FMU)."""
    from fmpy.fmi2 import fmi2Integer, fmi2Real, fmi2ValueReference

    left, right, cx, cy = data
    fmu = runner.fmu
    c = fmu.component
    ivr = (fmi2ValueReference * 2)(*runner.ivr)
    rvr = (fmi2ValueReference * 2)(*runner.rvr)
    ovr = (fmi2ValueReference * len(runner.ovr))(*runner.ovr)
    ival, rval, oval = (fmi2Integer * 2)(), (fmi2Real * 2)(), (fmi2Real * len(runner.ovr))()
    set_i, set_r, step, get_r = fmu.fmi2SetInteger, fmu.fmi2SetReal, fmu.fmi2DoStep, fmu.fmi2GetReal
    m, no = len(left), len(runner.ovr)
    t, k = runner.t, runner.k
    t0 = time.perf_counter()
    for _ in range(n):
        j = k % m
        ival[0], ival[1] = left[j], right[j]
        rval[0], rval[1] = cx[j], cy[j]
        set_i(c, ivr, 2, ival)
        set_r(c, rvr, 2, rval)
        step(c, t, 0.1, 1)
        get_r(c, ovr, no, oval)
        t += 0.1
        k += 1
    dt = time.perf_counter() - t0
    runner.t, runner.k = t, k
    return dt / n


def first_step(fmu: Path, engine: str) -> dict:
    env = dict(os.environ)
    env.pop("JAX_ENABLE_X64", None)
    proc = subprocess.run([sys.executable, "-c", FIRST_STEP, str(fmu), engine], capture_output=True, text=True,
                          env=env, timeout=600, cwd=tempfile.gettempdir())
    if proc.returncode != 0:
        raise RuntimeError(proc.stderr[-2000:])
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fmu", default=None, help="OdoCompass.fmu to measure (default: build one into a temp dir)")
    ap.add_argument("--native-fmu", default=None, help="OdoCompassNative.fmu (default: build one, default config)")
    ap.add_argument("--steps", type=int, default=20000)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--engines", default="native,python,xla")
    ap.add_argument("--c-steps", type=int, default=300000, help="samples of the C master's drive (0: skip)")
    ap.add_argument("--soak", type=int, default=0, help="processes of the exit soak (issue 12: 500)")
    ap.add_argument("--soak-no-guard", action="store_true", help="soak also with the exit guard off")
    ap.add_argument("--json", default=None, help="also write the figures to this JSON file")
    args = ap.parse_args(argv)

    import platform

    import jax

    jax.config.update("jax_enable_x64", True)
    tmp = Path(tempfile.mkdtemp(prefix="bench_fmu_"))
    if args.fmu:
        fmu = Path(args.fmu)
    else:
        from fmu.build import build_estimator

        t0 = time.perf_counter()
        fmu = build_estimator(tmp / "OdoCompass.fmu")
        print(f"built {fmu} in {time.perf_counter() - t0:.1f} s")
    if args.native_fmu:
        native = Path(args.native_fmu)
    else:
        from fmu.native_fmu import build_native_fmu

        t0 = time.perf_counter()
        native = build_native_fmu(tmp / "OdoCompassNative.fmu", configs=[])
        print(f"built {native} in {time.perf_counter() - t0:.1f} s")
    figures: dict = {}
    if args.c_steps:
        cm = c_master(native, tmp, args.c_steps, args.repeats)
        figures.update({"c_master_steps_per_s": cm["steps_per_s"], "c_master_max_heading_error_rad":
                        cm["max_heading_error_rad"], "c_master_discarded": cm["discarded"]})
        print(f"\nnative FMU in a C master: {cm['steps']} steps, best {cm['best_s']:.3f} s: "
              f"{cm['steps_per_s']:,.0f} steps/s (bar >= 1e6: {'met' if cm['steps_per_s'] >= 1e6 else 'NOT met'}); "
              f"heading vs jaxmodel.run: max {cm['max_heading_error_rad']:.3g} rad at any sample "
              f"(bar <= 1e-12: {'met' if cm['max_heading_error_rad'] <= 1e-12 else 'NOT met'}); "
              f"discarded {cm['discarded']}")

    trivial = build_trivial(tmp)
    data = drive(400 + 2 * args.repeats * args.steps + 10)  # never wraps: every step is a new, plausible sample
    engines = [e for e in args.engines.split(",") if e]
    runners = {"trivial": Runner(trivial, [f"o{i}" for i in range(8)], data),
               "OdoCompassNative": Runner(native, OUTPUTS, data)}
    for e in engines:
        runners[e] = Runner(fmu, OUTPUTS, data, e)
    steps = {name: (args.steps if name not in ("xla",) else max(500, args.steps // 10)) for name in runners}
    for name, r in runners.items():  # warm up
        r.run(data, 200)
    best = {name: float("inf") for name in runners}
    lean = {name: float("inf") for name in ("OdoCompassNative", engines[0])}
    for _ in range(args.repeats):
        for name, r in runners.items():
            best[name] = min(best[name], r.run(data, steps[name]))
        for name in lean:
            lean[name] = min(lean[name], run_lean(runners[name], data, steps[name]))
    for r in runners.values():
        r.fmu.terminate()
        r.fmu.freeInstance()
    cold = {e: first_step(fmu, e) for e in engines}

    print(f"\nOdoCompass FMUs in fmpy, one sensor sample per step (setInteger, setReal, doStep, getReal); "
          f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, best of {args.repeats}")
    print(f"{'FMU / engine':<26}{'us/step':>10}{'steps/s':>12}{'x trivial':>11}{'first step s':>14}")
    triv = best["trivial"]
    print(f"{'trivial pythonfmu':<26}{triv * 1e6:>10.1f}{1 / triv:>12,.0f}{1.0:>11.2f}{'':>14}")
    nat = best["OdoCompassNative"]
    print(f"{'OdoCompassNative (C)':<26}{nat * 1e6:>10.1f}{1 / nat:>12,.0f}{nat / triv:>11.2f}{'':>14}")
    for e in engines:
        print(f"{'OdoCompass ' + e:<26}{best[e] * 1e6:>10.1f}{1 / best[e]:>12,.0f}{best[e] / triv:>11.2f}"
              f"{cold[e]['first_s']:>14.2f}")
    default = engines[0]
    ok = 1 / best[default] >= 10000 and best[default] / triv <= 4.0 and cold[default]["first_s"] <= 5.0
    print(f"\ntargets (default engine '{default}'): >= 10,000 steps/s, <= 4x trivial, <= 5 s to the first step: "
          f"{'met' if ok else 'NOT met'}")
    speedup = best[default] / nat
    lean_speedup = lean[default] / lean["OdoCompassNative"]
    print(f"native FMU vs pythonfmu FMU (engine {default}) in fmpy: {speedup:.2f}x through FMU2Slave's methods "
          f"({nat * 1e6:.1f} vs {best[default] * 1e6:.1f} us/step), {lean_speedup:.2f}x through its bound fmi2* "
          f"functions with preallocated arrays ({lean['OdoCompassNative'] * 1e6:.1f} vs {lean[default] * 1e6:.1f} "
          f"us/step) (bar >= 2x: {'met' if max(speedup, lean_speedup) >= 2.0 else 'NOT met'}"
          f"{'' if min(speedup, lean_speedup) >= 2.0 else ' only with the bound functions'})")
    print("(second instance in the same process, engine prepared already: "
          + ", ".join(f"{e} {cold[e]['second_instance_s'] * 1e3:.0f} ms" for e in engines) + ")")
    figures.update({"trivial_us": triv * 1e6, "native_fmu_us": nat * 1e6, "native_fmu_speedup": speedup,
                    "native_fmu_lean_us": lean["OdoCompassNative"] * 1e6, "pythonfmu_lean_us": lean[default] * 1e6,
                    "native_fmu_lean_speedup": lean_speedup,
                    **{f"{e}_us": best[e] * 1e6 for e in engines},
                    **{f"{e}_ratio": best[e] / triv for e in engines},
                    **{f"{e}_first_step_s": cold[e]["first_s"] for e in engines}})
    if args.soak:
        for guard in ((True, False) if args.soak_no_guard else (True,)):
            r = soak(fmu, args.soak, guard)
            figures[f"soak_{'guard' if guard else 'no_guard'}"] = r
            print(f"exit soak ({'exit guard on' if guard else 'exit guard OFF'}): {r['abnormal_exits']} of "
                  f"{r['processes']} processes (4 instances each) did not exit 0 {r['codes'] or ''} "
                  f"in {r['seconds']:.0f} s" + (f"; e.g. {r['sample_stderr'][-120:]!r}" if r["sample_stderr"] else ""))
    print(json.dumps(figures, default=str))
    if args.json:
        Path(args.json).write_text(json.dumps(figures, indent=1, default=str))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
