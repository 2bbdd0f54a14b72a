"""Build the project's FMUs with pythonfmu: ``odocompass build-fmu`` (SPEC §5) and the vehicle FMU.

``build_estimator(out, params)`` stages ``fmu/OdoCompass.py`` with a bundle
(``resources/odocompass_bundle/``: a private copy of ``jaxmodel``, ``engine.py``, the lowering
(``jaxpr_lower.py``, ``lowered_code.py``, ``lowering_runtime.py``), ``fmi_support.py`` and
``manifest.json``).  The manifest lists every FMU variable with its unit, description and start
value, taken from ``jaxmodel``: the parameters iterate ``jaxmodel.params.PARAMETER_TABLE``
(``deviation_deg``, a 36-entry table, becomes ``deviation_deg_0`` ... ``deviation_deg_35``, the
entries at raw headings 0, 10, ..., 350 deg; ``sensor_axle`` is a String parameter), the inputs
are ``jaxmodel.Inputs`` (``time_s`` comes from the communication time) and the outputs
``jaxmodel.Outputs``.  Start values are the given parameters (an identified file works
directly).

``build_vehicle(out, params)`` stages ``fmu/VehicleSensors.py`` with ``identification/sensors.py``.

Both builds run pythonfmu's builder in-process, then restore ``sys.path`` and ``sys.modules`` (the
builder imports the slave script under its bare name), and check the result with
``fmpy.validation.validate_fmu``.
"""

from __future__ import annotations

import contextlib
import datetime
import html
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any, Mapping

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
ESTIMATOR_SCRIPT = HERE / "OdoCompass.py"
VEHICLE_SCRIPT = HERE / "VehicleSensors.py"
# the jaxpr lowering: jaxpr_lower.py and the two modules it imports (engine.Engine.modules loads them)
LOWERING = ("jaxpr_lower.py", "lowered_code.py", "lowering_runtime.py")
BUNDLED = ("engine.py", *LOWERING, "fmi_support.py", "model_description.py")

MODEL_OPTIONS = dict(
    needsExecutionTool=True,  # a Python interpreter with jax, numpy (and pythonfmu's runtime)
    canHandleVariableCommunicationStepSize=True,
    canInterpolateInputs=False,
    canBeInstantiatedOnlyOncePerProcess=False,
    canGetAndSetFMUstate=True,
    canSerializeFMUstate=True,
)

# The estimator's variables, units and metadata: one generator for both FMUs (fmu/model_description.py).
from .model_description import CONFIG_META, INPUT_META, OUTPUT_META, OUTPUT_RENAMES  # noqa: E402,F401

VEHICLE_TRUE_KEYS = ("sensor_axle", "P", "B", "T_F", "T_R", "a", "dpp_left", "dpp_right", "counter_modulus",
                     "field_magnitude", "variation_deg", "X0", "Y0", "rotation_deg", "deviation_deg")
VEHICLE_EXTRA = (
    # name, type, unit, start, description
    ("seed", "Integer", None, 0, "random seed of the sensor error models"),
    ("slip", "Boolean", None, True, "differential wheel slip on (identification.sensors.SlipModel)"),
    ("compass_noise_ut", "Real", "uT", 0.35, "white noise per compass axis"),
    ("anomaly_density_per_km2", "Real", "1/km2", 0.0, "localized magnetic anomalies per square km (procedural)"),
    ("transient_rate_per_s", "Real", "1/s", 0.0, "compass transients (passing trucks) per second"),
    ("counter_offset_left", "Integer", None, 0, "left counter reading at the start"),
    ("counter_offset_right", "Integer", None, 0, "right counter reading at the start"),
    ("initial_heading", "Real", "rad", 0.0, "true heading at the start, clockwise from north"),
    ("initial_x", "Real", "m", 0.0, "east position at the start"),
    ("initial_y", "Real", "m", 0.0, "north position at the start"),
)
VEHICLE_OUTPUTS = (
    ("left_pulses", "Integer", None, "left wheel pulse counter (counts)"),
    ("right_pulses", "Integer", None, "right wheel pulse counter (counts)"),
    ("compass_x", "Real", "uT", "compass field component x"),
    ("compass_y", "Real", "uT", "compass field component y"),
    ("compass_unreliable_area", "Boolean", None, "a magnetic anomaly known to the map is near"),
    ("true_heading", "Real", "rad", "true heading, clockwise from true north, wrapped to (-pi, pi]"),
    ("x", "Real", "m", "true position of the rear axle's centre, east"),
    ("y", "Real", "m", "true position of the rear axle's centre, north"),
    ("true_speed", "Real", "m/s", "true speed of the rear axle's centre"),
    ("yaw_rate", "Real", "rad/s", "true yaw rate over the last step"),
    ("distance", "Real", "m", "distance travelled by the rear axle's centre"),
)
VEHICLE_INPUTS = (
    ("steering_angle", "rad", 0.0, "road-wheel steering angle of the kinematic bicycle model, + = right"),
    ("speed", "m/s", 0.0, "speed of the rear axle's centre, + = forward"),
)


def _jax64():
    import jax

    jax.config.update("jax_enable_x64", True)  # the CLI does this too; builds run in applications, not in FMUs


def _params_dict(params) -> dict[str, Any]:
    """JSON-style parameter dict (validated) from None, a path, a mapping or a jaxmodel.Params."""
    _jax64()
    import jaxmodel

    source = "built-in defaults"
    if params is None:
        p = jaxmodel.make_params()
    elif isinstance(params, (str, Path)):
        p, _ = jaxmodel.load_params(params)
        source = str(params)
    elif isinstance(params, Mapping):
        p = jaxmodel.make_params(dict(params))
        source = "given parameters"
    else:
        p = params
        source = "given parameters"
    try:
        jaxmodel.validate_params(p)
    except jaxmodel.ParameterError as exc:
        raise jaxmodel.ParameterError(f"{source}: {exc}") from None
    return jaxmodel.params_to_dict(p)


def estimator_manifest(values: Mapping[str, Any]) -> dict[str, Any]:
    """Variables of the estimator FMU from jaxmodel's tables, ``values`` as start values, min/max from
    the rules of ``jaxmodel.validate_params`` (``fmu.param_rules``)."""
    import jaxmodel

    from . import model_description, param_rules

    return model_description.manifest(values, param_rules.bounds(param_rules.derive(jaxmodel)), jaxmodel)


def vehicle_manifest(values: Mapping[str, Any]) -> dict[str, Any]:
    from jaxmodel.params import PARAMETER_SPECS

    params = []
    for key in VEHICLE_TRUE_KEYS:
        spec = PARAMETER_SPECS[key]
        unit = "uT" if spec.unit == "compass" else (spec.unit or "1")
        if key == "sensor_axle":
            params.append(dict(name=key, type="String", start=values[key], description="true " + spec.description))
        elif isinstance(values[key], (list, tuple)):
            for i, v in enumerate(values[key]):
                params.append(dict(name=f"{key}_{i}", type="Real", unit=unit, start=float(v),
                                   description=f"true value: {spec.description} [entry {i}]"))
        else:
            params.append(dict(name=key, type="Real", unit=unit, start=float(values[key]),
                               description="true value: " + spec.description))
    for name, kind, unit, start, desc in VEHICLE_EXTRA:
        params.append(dict(name=name, type=kind, unit=unit, start=start, description=desc))
    inputs = [dict(name=n, type="Real", unit=u, start=s, description=d) for n, u, s, d in VEHICLE_INPUTS]
    outputs = [dict(name=n, type=t, unit=u, description=d) for n, t, u, d in VEHICLE_OUTPUTS]
    return dict(format="odocompass-vehicle-manifest/1", model="VehicleSensors", inputs=inputs, outputs=outputs,
                parameters=params)


def _copy_package(src: Path, dst: Path) -> None:
    shutil.copytree(src, dst, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))


def _documentation(manifest: Mapping[str, Any], title: str, dest: Path) -> None:
    rows = []
    for group in ("inputs", "outputs", "parameters", "config"):
        for v in manifest.get(group, []):
            rows.append(f"<tr><td>{html.escape(v['name'])}</td><td>{group}</td><td>{v.get('type', 'Real')}</td>"
                        f"<td>{html.escape(str(v.get('unit') or ''))}</td><td>{html.escape(v['description'])}</td></tr>")
    dest.mkdir(parents=True, exist_ok=True)
    (dest / "index.html").write_text(
        f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title></head><body>"
        f"<h1>{html.escape(title)}</h1><p>See docs/fmu.md of the odocompass project.</p>"
        "<table border='1'><tr><th>name</th><th>kind</th><th>type</th><th>unit</th><th>description</th></tr>"
        + "".join(rows) + "</table></body></html>\n")


@contextlib.contextmanager
def _isolated_import_state(stage: Path, script_name: str):
    """pythonfmu's builder inserts paths and imports the script under its bare name: undo both."""
    path = list(sys.path)
    before = sys.modules.get(script_name)
    try:
        yield
    finally:
        sys.path[:] = path
        for name, module in list(sys.modules.items()):
            file = getattr(module, "__file__", None) or ""
            if file.startswith(str(stage)):
                sys.modules.pop(name, None)
        if before is None:
            sys.modules.pop(script_name, None)
        else:
            sys.modules[script_name] = before


def _pythonfmu_build(script: Path, bundle: Path, out: Path, doc: Path) -> Path:
    from pythonfmu.builder import FmuBuilder

    out = Path(out).resolve()
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp_out = out.with_name(out.name + ".part.fmu")
    with _isolated_import_state(script.parent, script.stem):
        result = FmuBuilder.build_FMU(script, dest=tmp_out, project_files=[bundle], documentation_folder=doc,
                                      **MODEL_OPTIONS)
    Path(result).replace(out)
    return out


def _validate(path: Path) -> None:
    from fmpy.validation import validate_fmu

    problems = validate_fmu(str(path))
    if problems:
        raise RuntimeError(f"{path}: fmpy validate found problems: " + "; ".join(problems))


NATIVE_CONFIGS = ({"mode": "complementary"}, {"mode": "odometer"}, {"mode": "compass"}, {"mode": "kalman"})
"""Configurations compiled to C (others run the Python lowering); refine_a, calibration, track at defaults."""
C_FLAGS = ("-O2", "-std=c99", "-fPIC", "-shared", "-ffp-contract=off", "-fno-fast-math")


def check_drive(n: int = 1500, seed: int = 7) -> dict[str, Any]:
    """A synthetic drive (numpy only) that exercises the step: turns both ways, stops, reversing,
    speed changes, compass noise and an anomaly, NaN compass samples, a counter fault, counter wrap."""
    import numpy as np

    rng = np.random.default_rng(seed)
    t = np.cumsum(np.full(n, 0.1)) - 0.1
    speed = 12.0 + 8.0 * np.sin(t / 23.0)
    speed[300:340] = 0.0  # a stop (slices beyond n are empty)
    speed[600:650] = -1.5  # reversing
    curv = 0.03 * np.sin(t / 9.0) + 0.08 * (np.abs(((t - 40.0) % 60.0) - 5.0) < 3.0)
    ds = speed * 0.1
    heading = 0.3 + np.cumsum(ds * curv)
    dD = ds * curv * 1.55
    left = np.cumsum(ds + 0.5 * dD) / 0.02
    right = np.cumsum(ds - 0.5 * dD) / 0.02
    left = np.mod(np.floor(left + 61000.0), 65536.0)
    right = np.mod(np.floor(right + 30000.0), 65536.0)
    if n > 900:
        right[900] = right[899] + 7000.0  # a counter glitch
    field = 20.0 + 4.0 * np.exp(-((t - 80.0) / 5.0) ** 2)
    cx = field * np.cos(heading) + rng.normal(0.0, 0.3, n)
    cy = field * np.sin(heading) + rng.normal(0.0, 0.3, n)
    cx[[k for k in (200, 201, 777) if k < n]] = np.nan
    zeros = np.zeros(n)
    return dict(time_s=t, left_pulses=left, right_pulses=right, compass_x=cx, compass_y=cy,
                map_heading=zeros, map_valid=zeros, compass_unreliable_area=zeros, fix_east_m=zeros,
                fix_north_m=zeros, fix_valid=zeros)


def _compiler() -> str | None:
    cc = os.environ.get("CC")
    if cc and shutil.which(cc):
        return cc
    return shutil.which("cc") or shutil.which("gcc")


def _build_native(bundle: Path, bundle_id: str, values: Mapping[str, Any], configs) -> tuple[list[dict], list[str]]:
    """Lower the bundled jaxmodel step to C per configuration, compile, and check it against jaxmodel.run."""
    import numpy as np

    from fmu.engine import Engine, local_jax_config

    cc = _compiler()
    if cc is None:
        return [], ["no C compiler (cc/gcc, or $CC): the FMU runs the Python lowering"]
    eng = Engine(bundle, bundle_id)
    jax, jm, _ = eng.modules()
    drive = check_drive()
    inputs = np.stack([np.asarray(drive[f], dtype=np.float64) for f in jm.Inputs._fields], axis=1)
    entries, notes = [], []
    (bundle / "native").mkdir(exist_ok=True)
    for i, overrides in enumerate(configs):
        params, cfg = eng.make(dict(values), dict(overrides))
        source, meta = eng.native_source(params, cfg)
        stem = f"native/odocompass_{i}_{cfg.mode}"
        (bundle / f"{stem}.c").write_text(source)
        lib_path = bundle / f"{stem}.so"
        proc = subprocess.run([cc, *C_FLAGS, "-o", str(lib_path), str(bundle / f"{stem}.c"), "-lm"],
                              capture_output=True, text=True)
        if proc.returncode != 0:
            notes.append(f"{cfg.mode}: C compilation failed: {proc.stderr.strip()[:500]}")
            continue
        entry = dict(meta, file=f"{stem}.so")
        # self-check: the compiled step against jaxmodel.run on the check drive
        native = eng._native_lib(cfg, bundle, [entry])
        if isinstance(native, str):
            notes.append(f"{cfg.mode}: {native}")
            continue
        stepper = native.stepper(eng.flat_params(params), "check")
        s = stepper.s0
        outs = []
        for row in inputs.tolist():
            s, o = stepper.step(s, row)
            outs.append(o)
        outs = np.asarray(outs)
        with local_jax_config(jax):
            ref = jm.run(params, jm.Inputs(*[inputs[:, k] for k in range(inputs.shape[1])]), cfg)
            ref = np.stack([np.asarray(getattr(ref, f)) for f in jm.Outputs._fields], axis=1)
        both_nan = np.isnan(outs) & np.isnan(ref)
        err = np.where(both_nan, 0.0, np.abs(outs - ref))
        scale = np.maximum(1.0, np.abs(ref))
        worst = float(np.nanmax(np.where(np.isnan(err), math.inf, err / np.where(both_nan, 1.0, scale))))
        entry["check_max_rel_error"] = worst
        if not worst <= 1e-9:
            notes.append(f"{cfg.mode}: compiled step differs from jaxmodel.run by {worst:.3g}; not used")
            lib_path.unlink()
            continue
        entries.append(entry)
        del native, stepper
    return entries, notes


def _stage_common(stage: Path, bundle_name: str, script: Path) -> Path:
    shutil.copy2(script, stage / script.name)
    bundle = stage / bundle_name
    bundle.mkdir()
    shutil.copy2(HERE / "fmi_support.py", bundle / "fmi_support.py")
    return bundle


def build_estimator(out: str | Path = "build/OdoCompass.fmu", params=None, native_configs=NATIVE_CONFIGS,
                    report: dict | None = None) -> Path:
    """Build the OdoCompass estimator FMU with ``params`` (None, path, mapping or Params) as start values.

    ``native_configs``: configurations to compile to C (empty: none); ``report`` (a dict) receives
    the native libraries built and notes on those that were not.
    """
    values = _params_dict(params)
    import jaxmodel

    with tempfile.TemporaryDirectory(prefix="odocompass_fmu_") as tmp:
        stage = Path(tmp)
        bundle = _stage_common(stage, "odocompass_bundle", ESTIMATOR_SCRIPT)
        for name in BUNDLED:
            shutil.copy2(HERE / name, bundle / name)
        _copy_package(Path(jaxmodel.__file__).resolve().parent, bundle / "jaxmodel")
        from fmu.engine import bundle_digest

        manifest = estimator_manifest(values)
        manifest["bundle_id"] = bundle_digest(bundle)
        manifest["native"], notes = _build_native(bundle, manifest["bundle_id"], values, native_configs)
        manifest["native_notes"] = notes
        if report is not None:
            report.update(native=manifest["native"], notes=notes)
        manifest["built"] = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
        (bundle / "manifest.json").write_text(json.dumps(manifest, indent=1, allow_nan=False) + "\n")
        _documentation(manifest, "OdoCompass FMU", stage / "documentation")
        path = _pythonfmu_build(stage / ESTIMATOR_SCRIPT.name, bundle, Path(out), stage / "documentation")
    _validate(path)
    return path


def build_vehicle(out: str | Path = "build/VehicleSensors.fmu", params=None) -> Path:
    """Build the VehicleSensors FMU; ``params`` (estimator keys) are the TRUE vehicle parameters."""
    values = _params_dict(params)
    sensors = REPO / "identification" / "sensors.py"
    if not sensors.is_file():
        raise RuntimeError(f"{sensors} is missing: the vehicle FMU bundles the sensor models")
    with tempfile.TemporaryDirectory(prefix="odocompass_vehicle_") as tmp:
        stage = Path(tmp)
        bundle = _stage_common(stage, "vehicle_bundle", VEHICLE_SCRIPT)
        shutil.copy2(sensors, bundle / "sensors.py")
        from fmu.engine import bundle_digest

        manifest = vehicle_manifest(values)
        manifest["bundle_id"] = bundle_digest(bundle)
        (bundle / "manifest.json").write_text(json.dumps(manifest, indent=1, allow_nan=False) + "\n")
        _documentation(manifest, "VehicleSensors FMU", stage / "documentation")
        path = _pythonfmu_build(stage / VEHICLE_SCRIPT.name, bundle, Path(out), stage / "documentation")
    _validate(path)
    return path


def main(args) -> int:
    """``odocompass build-fmu [--params P.json] [--out build/OdoCompass.fmu] [--native]``.

    The output is checked before the build (a .fmu name, never the parameter file, a writable
    folder) and written atomically: built under a temporary name beside it, renamed on success."""
    import os

    from identification.diagnostics import checked_params
    from identification.outputs import atomic, check_output_file

    native = getattr(args, "native", False)
    out = Path("build/OdoCompassNative.fmu" if native and args.out == "build/OdoCompass.fmu" else args.out)
    check_output_file(out, inputs=[("the parameter file", args.params)], suffixes=(".fmu",))
    checked_params(args.params)  # its errors name the file, before the build
    with atomic(out) as tmp:
        try:
            if native:
                from .native_fmu import build_native_fmu

                built = build_native_fmu(tmp, args.params)
            else:
                built = build_estimator(tmp, args.params)
            if Path(built).resolve() != tmp.resolve():
                os.replace(built, tmp)
        finally:
            part = tmp.with_name(tmp.name + ".part.fmu")  # pythonfmu's own partial file, if a build failed
            if part.exists():
                part.unlink()
    from fmpy import read_model_description

    md = read_model_description(str(out))
    n = {c: sum(v.causality == c for v in md.modelVariables) for c in ("input", "output", "parameter")}
    from identification.console import info  # stderr, silenced by -q like every command's information lines

    info(f"wrote {out} ({n['input']} inputs, {n['output']} outputs, {n['parameter']} parameters; "
         f"start values from {args.params or 'the built-in defaults'}; fmpy validate: no problems)")
    return 0
