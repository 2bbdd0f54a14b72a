"""``odocompass build-fmu --native``: the estimator as an FMI 2.0 co-simulation FMU without Python.

The binary is ``fmu/odocompass_fmi2.c`` and ``odocompass_fmi2_state.c`` (the FMI 2.0 C API,
hand-written, model-independent, types in ``odocompass_fmi2.h``)
compiled with files generated here at build time:

* ``odc_step_<i>.c``: init and step of configuration i, lowered by ``jaxpr_lower`` from the jaxpr
  of ``jaxmodel.run_from`` (parameters as run-time arguments), one file per configuration
  (mode x refine_a x calibration x track);
* ``odocompass_validate.c``: ``odc_validate``, the parameter rules read off
  ``jaxmodel.validate_params`` (``param_rules``);
* ``odocompass_model.h``: value references, types, start values, the parameter vector's layout
  (``PARAMETER_TABLE`` order), the indices the step checks need (looked up by name in the traced
  state/output layout), the configuration table and the log categories.

The model description comes from ``model_description.to_xml``, the same generator as the
pythonfmu FMU's.  The C files are compiled with the system compiler against the FMI 2.0 headers
that ship with fmpy (``fmpy/c-code``), IEEE float64 (no fast-math, no FMA contraction), and shipped
in ``sources/``.  The build replays a synthetic drive through the FMU (fmpy) and refuses a binary
that differs from ``jaxmodel.run`` by more than 1e-12.
"""

from __future__ import annotations

import concurrent.futures
import datetime
import itertools
import json
import math
import os
import shutil
import subprocess
import tempfile
import uuid
import zipfile
from pathlib import Path
from typing import Any, Iterable, Mapping

from . import model_description as md
from . import param_rules

HERE = Path(__file__).resolve().parent
MODEL_IDENTIFIER = "OdoCompassNative"
FMI_SOURCES = (HERE / "odocompass_fmi2.c", HERE / "odocompass_fmi2_state.c", HERE / "odocompass_fmi2.h")
C_FLAGS = ("-std=c99", "-fPIC", "-ffp-contract=off", "-fno-fast-math", "-fvisibility=hidden")
CS_OPTIONS = dict(needsExecutionTool=False, canHandleVariableCommunicationStepSize=True, canInterpolateInputs=False,
                  maxOutputDerivativeOrder=0, canRunAsynchronuously=False, canBeInstantiatedOnlyOncePerProcess=False,
                  canNotUseMemoryManagementFunctions=False, canGetAndSetFMUstate=True, canSerializeFMUstate=True,
                  providesDirectionalDerivative=False)
STRLEN = 64
CHECK_TOLERANCE = 1e-12


def fmi_headers() -> Path:
    import fmpy

    d = Path(fmpy.__file__).resolve().parent / "c-code"
    if not (d / "fmi2Functions.h").is_file():
        raise RuntimeError(f"{d}: the FMI 2.0 headers (fmi2Functions.h) that fmpy ships are missing")
    return d


def all_configs(jm) -> list[dict[str, Any]]:
    """Every configuration ``build-fmu`` offers: the config parameters of the model description."""
    choices = {"mode": list(jm.MODES), "refine_a": [True, False], "calibration": [True, False],
               "track": ["closed_form", "table"]}
    names = list(choices)
    return [dict(zip(names, combo)) for combo in itertools.product(*(choices[n] for n in names))]


def _config_key(cfg: Mapping[str, Any]) -> str:
    return "".join(f"{k}={int(v) if isinstance(v, bool) else v};" for k, v in cfg.items())


def _c_str(s: str) -> str:
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"') + '"'


def _c_double(x: float) -> str:
    if math.isnan(x):
        return "NAN"
    if math.isinf(x):
        return "INFINITY" if x > 0 else "(-INFINITY)"
    return x.hex() if x >= 0 else f"({x.hex()})"


def parameter_layout(jm) -> dict[str, tuple[int, int]]:
    """key -> (offset, size) in the flat parameter vector (Params leaves in PARAMETER_TABLE order)."""
    layout, off = {}, 0
    for spec in jm.PARAMETER_TABLE:
        size = len(spec.default) if isinstance(spec.default, (list, tuple)) else 1
        layout[spec.key] = (off, size)
        off += size
    return layout


def model_header(manifest: Mapping[str, Any], guid: str, layout: Mapping[str, tuple[int, int]],
                 engine_layout: Mapping[str, Any], configs: list[dict[str, Any]]) -> str:
    variables = md.variables(manifest)
    str_slots, bool_slots, strpars, cfg_parts = {}, {}, [], []
    rows = []
    for v in variables:
        group, kind = v["group"], v["type"][0]
        start, sstart, slot = 0.0, "", 0
        if group == "input":
            g, slot, start = "x", v["slot"], float(v["start"])
        elif group == "output":
            g, slot = "o", v["slot"]
        elif group == "discarded":
            g = "d"
        elif group == "parameter":
            g = "p"
            if kind == "S":
                slot = str_slots.setdefault(v["name"], len(str_slots))
                sstart = str(v["start"])
                values = [float(jm_number(v["key"], a)) for a in v["allowed"]]
                strpars.append((v["key"], slot, layout[v["key"]][0], v["allowed"], values))
            else:
                off, _ = layout[v["key"]]
                slot, start = off + (v["index"] or 0), float(v["start"])
        else:
            g = "c"
            if kind == "S":
                slot, sstart = str_slots.setdefault(v["name"], len(str_slots)), str(v["start"])
            else:
                slot, start = bool_slots.setdefault(v["name"], len(bool_slots)), 1.0 if v["start"] else 0.0
        if len(sstart) >= STRLEN:
            raise RuntimeError(f"start value of {v['name']} longer than {STRLEN - 1} characters")
        rows.append(f"    {{{_c_str(v['name'])}, '{kind}', '{g}', {slot}, {_c_double(start)}, {_c_str(sstart)}}}, "
                    f"/* vr {v['vr']} */")
    cfg_names = list(configs[0])
    for name in cfg_names:
        if name in str_slots:
            cfg_parts.append(f"    {{{_c_str(name)}, 'S', {str_slots[name]}}},")
        else:
            cfg_parts.append(f"    {{{_c_str(name)}, 'B', {bool_slots[name]}}},")
    fields = manifest["sample_fields"]
    outs = engine_layout["outputs"]
    state = engine_layout["state"]

    def idx(seq, name, what):
        if name not in seq:
            raise RuntimeError(f"native FMU: {what} {name!r} not found in the traced jaxmodel layout")
        return seq.index(name)

    defines = {
        "ODC_N_PARAM": engine_layout["n_param"], "ODC_N_STATE": len(state), "ODC_N_IN": len(fields),
        "ODC_N_OUT": len(outs), "ODC_N_VARS": len(variables), "ODC_N_STR": max(1, len(str_slots)),
        "ODC_N_BOOL": max(1, len(bool_slots)), "ODC_STRLEN": STRLEN, "ODC_N_CONFIGS": len(configs),
        "ODC_N_STRPARS": len(strpars), "ODC_N_CONFIG_PARTS": len(cfg_parts), "ODC_N_CATEGORIES": len(md.LOG_CATEGORIES),
        "ODC_X_TIME": idx(fields, "time_s", "input"), "ODC_X_LEFT": idx(fields, "left_pulses", "input"),
        "ODC_X_RIGHT": idx(fields, "right_pulses", "input"), "ODC_X_CX": idx(fields, "compass_x", "input"),
        "ODC_X_CY": idx(fields, "compass_y", "input"), "ODC_X_MAP": idx(fields, "map_heading", "input"),
        "ODC_X_MAP_VALID": idx(fields, "map_valid", "input"), "ODC_X_FE": idx(fields, "fix_east_m", "input"),
        "ODC_X_FN": idx(fields, "fix_north_m", "input"), "ODC_X_FIX_VALID": idx(fields, "fix_valid", "input"),
        "ODC_S_STARTED": idx(state, "started", "state value"), "ODC_S_LAST_LEFT": idx(state, "last_left", "state value"),
        "ODC_S_LAST_RIGHT": idx(state, "last_right", "state value"),
        "ODC_O_ODOMETER_VALID": idx(outs, "odometer_valid", "output"),
        "ODC_P_COUNTER_MODULUS": layout["counter_modulus"][0], "ODC_P_MAX_SPEED": layout["max_speed"][0],
        "ODC_STOPPED_MIN_S": repr(manifest["stopped_counter"]["min_s"]),
        "ODC_STOPPED_OTHER_PULSES": repr(manifest["stopped_counter"]["other_pulses"]),
        "ODC_STR_ENGINE": str_slots["engine"], "ODC_BOOL_DISCARD": bool_slots["discard_bad_samples"],
    }
    out = ["/* Generated by odocompass fmu/native_fmu.py from jaxmodel and the model description: do not edit. */",
           "#ifndef ODOCOMPASS_MODEL_H", "#define ODOCOMPASS_MODEL_H", "#include <stddef.h>", "",
           f"#define ODC_GUID {_c_str(guid)}"]
    out += [f"#define {k} {v}" for k, v in defines.items()]
    out += ["", "typedef struct { const char *name; char type; char group; int slot; double start; const char *sstart; } "
                "odc_var;",
            "typedef struct { const char *key; int str_slot; int flat; int n; const char *names[8]; double values[8]; "
            "const char *allowed; } odc_strpar;",
            "typedef struct { const char *name; char type; int slot; } odc_cfgpart;",
            "typedef void (*odc_init_fn)(const double *restrict, double *restrict);",
            "typedef void (*odc_step_fn)(const double *restrict, const double *restrict, const double *restrict, "
            "double *restrict, double *restrict);",
            "typedef struct { const char *key; odc_init_fn init; odc_step_fn step; } odc_config;", "",
            "int odc_validate(const double *p, char *msg, size_t n);"]
    for i in range(len(configs)):
        out.append(f"void odc_init_{i}(const double *restrict A0, double *restrict R0);")
        out.append(f"void odc_step_{i}(const double *restrict A0, const double *restrict A1, const double *restrict A2, "
                   "double *restrict R0, double *restrict R1);")
    out += ["", "static const odc_var ODC_VARS[ODC_N_VARS] = {"] + rows + ["};", ""]
    out.append("static const odc_strpar ODC_STRPARS[ODC_N_STRPARS > 0 ? ODC_N_STRPARS : 1] = {")
    for key, slot, flat, names, values in strpars or [("", 0, 0, [], [])]:
        out.append(f"    {{{_c_str(key)}, {slot}, {flat}, {len(names)}, {{{', '.join(map(_c_str, names)) or '0'}}}, "
                   f"{{{', '.join(map(_c_double, values)) or '0'}}}, {_c_str(', '.join(names))}}},")
    out += ["};", "", "static const odc_cfgpart ODC_CONFIG_PARTS[ODC_N_CONFIG_PARTS] = {"] + cfg_parts + ["};", ""]
    out.append("static const odc_config ODC_CONFIGS[ODC_N_CONFIGS] = {")
    out += [f"    {{{_c_str(_config_key(c))}, odc_init_{i}, odc_step_{i}}}," for i, c in enumerate(configs)]
    choices = "; ".join(f"{k}: {'/'.join(sorted({str(c[k]) for c in configs}))}" for k in cfg_names)
    out += ["};", f"#define ODC_CONFIG_CHOICES {_c_str(choices)}", ""]
    out.append("static const char *const ODC_CATEGORIES[ODC_N_CATEGORIES] = {"
               + ", ".join(_c_str(c) for c in md.LOG_CATEGORIES) + "};")
    out += ["", "#endif", ""]
    return "\n".join(out)


def jm_number(key: str, value: Any) -> float:
    from jaxmodel import params as P

    return float(P._to_number(key, value))


def _compile(cc: str, src: Path, obj: Path, include: list[Path], opt: str) -> None:
    cmd = [cc, opt, *C_FLAGS, *[f"-I{p}" for p in include], "-c", "-o", str(obj), str(src)]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"C compilation of {src.name} failed: {proc.stderr.strip()[:2000]}")


def build_native_fmu(out: str | Path = "build/OdoCompassNative.fmu", params=None,
                     configs: Iterable[Mapping[str, Any]] | None = None, jobs: int | None = None,
                     check: bool = True) -> Path:
    """Build the Python-free FMU; ``configs`` restricts the compiled configurations (default: all)."""
    from .build import LOWERING, _compiler, _documentation, _params_dict, _validate
    from .engine import Engine

    values = _params_dict(params)
    import jaxmodel as jm

    cc = _compiler()
    if cc is None:
        raise RuntimeError("build-fmu --native needs a C compiler (cc/gcc, or $CC)")
    headers = fmi_headers()
    rules = param_rules.derive(jm)
    bounds = param_rules.bounds(rules)
    manifest = md.manifest(values, bounds, jm)
    configs = [dict(c) for c in (configs if configs is not None else all_configs(jm))]
    default = {k: v for k, v in zip(("mode", "refine_a", "calibration", "track"),
                                    ("complementary", True, True, "closed_form"))}
    if default not in configs:
        configs.insert(0, default)
    layout = parameter_layout(jm)
    guid = "{" + str(uuid.uuid4()) + "}"
    out = Path(out).resolve()
    with tempfile.TemporaryDirectory(prefix="odocompass_native_") as tmp:
        tmp = Path(tmp)
        bundle = tmp / "bundle"
        bundle.mkdir()
        shutil.copytree(Path(jm.__file__).resolve().parent, bundle / "jaxmodel",
                        ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
        for name in LOWERING:
            shutil.copy2(HERE / name, bundle / name)
        eng = Engine(bundle, "native_" + uuid.uuid4().hex[:12])
        _, bjm, lower = eng.modules()
        if eng_layout_mismatch(layout, eng, values):
            raise RuntimeError("native FMU: the flat parameter layout does not match jaxmodel.Params")
        fmu_dir = tmp / "fmu"
        src_dir = fmu_dir / "sources"
        src_dir.mkdir(parents=True)
        units = []  # (file, optimisation)
        state_names = None
        for i, overrides in enumerate(configs):
            p, cfg = eng.make(dict(values), dict(overrides))
            closed_init, _, closed, _, _ = eng.trace(p, cfg)
            if state_names is None:
                state_names = list(eng.layout["state"])
            init_prog = lower.lower_program(closed_init, [None])
            step_prog = lower.lower_program(closed, [None, None, None])
            text = (lower.C_PRELUDE + f"/* configuration {_config_key(overrides)} */\n"
                    + init_prog.to_c(f"odc_init_{i}") + "\n" + step_prog.to_c(f"odc_step_{i}"))
            name = f"odc_step_{i}.c"
            (src_dir / name).write_text(text)
            # very long straight-line steps (the table track: ~34,000 operations) take gcc -O2 tens of
            # seconds; they are compiled without optimisation (still IEEE float64, same results)
            units.append((name, "-O2" if step_prog.n_ops < 8000 else "-O0"))
        (src_dir / "odocompass_validate.c").write_text(param_rules.to_c(rules, layout))
        (src_dir / "odocompass_model.h").write_text(model_header(manifest, guid, layout, eng.layout, configs))
        for f in FMI_SOURCES:
            shutil.copy2(f, src_dir / f.name)
        units += [("odocompass_validate.c", "-O2")] + [(f.name, "-O2") for f in FMI_SOURCES if f.suffix == ".c"]

        bin_dir = fmu_dir / "binaries" / "linux64"
        bin_dir.mkdir(parents=True)
        objs = tmp / "obj"
        objs.mkdir()
        with concurrent.futures.ThreadPoolExecutor(max_workers=jobs or min(4, os.cpu_count() or 1)) as pool:
            futures = [pool.submit(_compile, cc, src_dir / n, objs / (n[:-2] + ".o"), [src_dir, headers], opt)
                       for n, opt in sorted(units, key=lambda u: u[1])]  # the slow -O0 ones first
            for f in futures:
                f.result()
        lib = bin_dir / f"{MODEL_IDENTIFIER}.so"
        proc = subprocess.run([cc, "-shared", "-o", str(lib), *sorted(str(o) for o in objs.glob("*.o")), "-lm"],
                              capture_output=True, text=True)
        if proc.returncode != 0:
            raise RuntimeError(f"linking {lib.name} failed: {proc.stderr.strip()[:2000]}")

        sources = sorted(p.name for p in src_dir.glob("*.c"))
        root = md.to_xml(manifest, guid=guid, model_identifier=MODEL_IDENTIFIER,
                         generation_tool="odocompass build-fmu --native (fmu/jaxpr_lower.py, gcc)",
                         cs_options=CS_OPTIONS, source_files=sources,
                         description="Dead-reckoning heading estimator (differential odometer + magnetic compass): "
                                     "the odocompass jaxmodel step lowered to C, no Python at run time",
                         date=datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"))
        (fmu_dir / "modelDescription.xml").write_text(md.to_text(root))
        _documentation(dict(manifest, config=manifest["config"]), "OdoCompassNative FMU", fmu_dir / "documentation")
        (fmu_dir / "documentation" / "build.json").write_text(json.dumps(
            {"configs": [_config_key(c) for c in configs], "rules": {"finite": list(rules.finite),
             "intervals": [r._asdict() for r in rules.intervals], "orders": [o._asdict() for o in rules.orders]},
             "state": state_names, "n_param": eng.layout["n_param"]}, indent=1, default=str) + "\n")
        out.parent.mkdir(parents=True, exist_ok=True)
        part = out.with_name(out.name + ".part")
        with zipfile.ZipFile(part, "w", zipfile.ZIP_DEFLATED) as z:
            for f in sorted(fmu_dir.rglob("*")):
                if f.is_file():
                    z.write(f, f.relative_to(fmu_dir).as_posix())
        if check:
            check_against_jaxmodel(part, fmu_dir, eng, values, [c for c in configs if c.get("track") == "closed_form"
                                                               and c.get("refine_a") and c.get("calibration")])
        part.replace(out)
    _validate(out)
    return out


def eng_layout_mismatch(layout, eng, values) -> bool:
    p, _ = eng.make(dict(values), {})
    eng.structure(p)
    return sum(size for _, size in layout.values()) != eng.layout["n_param"]


def check_against_jaxmodel(fmu_path: Path, unzipped: Path, eng, values, configs) -> float:
    """Replay the build's check drive (faults included, passed to the estimator) through the FMU per
    configuration; refuse a binary whose angles differ from jaxmodel.run by more than 1e-12 rad or
    whose other outputs differ by more than 1e-9 (relative)."""
    import numpy as np

    from .build import check_drive
    from .cosim import Slave, replay, wrap
    from .engine import local_jax_config

    jax, jm, _ = eng.modules()
    drive = check_drive(600)
    units = {f: md.OUTPUT_META.get(f, ("1",))[0] for f in jm.Outputs._fields}
    worst = 0.0
    for cfg_values in configs:
        p, cfg = eng.make(dict(values), dict(cfg_values))
        with local_jax_config(jax):
            ref = jm.run(p, jm.Inputs(*[np.asarray(drive[f], dtype=np.float64) for f in jm.Inputs._fields]), cfg)
        slave = Slave(fmu_path, "check", unzip_dir=unzipped)
        try:
            got = replay(None, drive, {"mode": cfg.mode, "discard_bad_samples": False}, slave=slave)
        finally:
            slave.close()
        for f in jm.Outputs._fields:
            r = np.asarray(getattr(ref, f), dtype=np.float64)
            g = got[md.OUTPUT_RENAMES.get(f, f)]
            both_nan = np.isnan(r) & np.isnan(g)
            if units[f] == "rad":
                err, tol = np.abs(wrap(r - g)), CHECK_TOLERANCE
            else:
                err, tol = np.abs(r - g) / np.maximum(1.0, np.abs(r)), 1e-9
            err = np.where(both_nan, 0.0, err)
            e = float(np.max(np.where(np.isnan(err), np.inf, err)))
            if not e <= tol:
                raise RuntimeError(f"native FMU ({_config_key(cfg_values)}): output {f} differs from jaxmodel.run by "
                                   f"{e:.3g} (> {tol})")
            if units[f] == "rad":
                worst = max(worst, e)
    return worst
