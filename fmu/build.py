"""Build the project's FMUs with pythonfmu: ``odocompass build-fmu`` (SPEC §5) and the vehicle FMU.

``build_estimator(out, params)`` stages ``fmu/OdoCompass.py`` with a bundle
(``resources/odocompass_bundle/``: a private copy of ``jaxmodel``, ``engine.py``,
``jaxpr_lower.py``, ``fmi_support.py`` and ``manifest.json``).  The manifest lists every FMU
variable with its unit, description and start value, taken from ``jaxmodel``: the parameters
iterate ``jaxmodel.params.PARAMETER_TABLE`` (``deviation_deg``, a 36-entry table, becomes
``deviation_deg_0`` ... ``deviation_deg_35``, the entries at raw headings 0, 10, ..., 350 deg;
``sensor_axle`` is a String parameter), the inputs are ``jaxmodel.Inputs`` (``time_s`` comes from
the communication time) and the outputs ``jaxmodel.Outputs``.  Start values are the given
parameters (an identified file works directly).

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
BUNDLED = ("engine.py", "jaxpr_lower.py", "fmi_support.py")

MODEL_OPTIONS = dict(
    needsExecutionTool=True,  # a Python interpreter with jax, numpy (and pythonfmu's runtime)
    canHandleVariableCommunicationStepSize=True,
    canInterpolateInputs=False,
    canBeInstantiatedOnlyOncePerProcess=False,
    canGetAndSetFMUstate=True,
    canSerializeFMUstate=True,
)

# FMU metadata of jaxmodel.Inputs fields: (FMI type, unit, start, description).  time_s is the
# communication time, not a variable.
INPUT_META: dict[str, tuple[str, str | None, Any, str]] = {
    "left_pulses": ("Integer", None, 0, "cumulative left wheel pulse counter (counts; wraps at counter_modulus; "
                                        "small decrements are reversing)"),
    "right_pulses": ("Integer", None, 0, "cumulative right wheel pulse counter (counts; wraps at counter_modulus)"),
    "compass_x": ("Real", "compass", 0.0, "compass field component x (compass units, e.g. uT); for an ideal sensor "
                                          "atan2(compass_y, compass_x) is the magnetic heading"),
    "compass_y": ("Real", "compass", 0.0, "compass field component y (compass units, e.g. uT)"),
    "map_heading": ("Real", "rad", 0.0, "street heading from the map, clockwise from true north (either direction "
                                        "of a two-way street)"),
    "map_valid": ("Boolean", None, False, "the vehicle is on a mapped street: map_heading is valid"),
    "compass_unreliable_area": ("Boolean", None, False, "the map flags the area as magnetically unreliable "
                                                        "(the map heading may replace the compass, FIG. 8F)"),
    "fix_east_m": ("Real", "m", 0.0, "position fix, east (Kalman mode)"),
    "fix_north_m": ("Real", "m", 0.0, "position fix, north (Kalman mode)"),
    "fix_valid": ("Boolean", None, False, "a position fix is present in this sample"),
}

# FMU metadata of jaxmodel.Outputs fields: (unit, display unit, description).
OUTPUT_META: dict[str, tuple[str, str | None, str]] = {
    "heading": ("rad", "deg", "estimated heading of the selected mode (EH, FIG. 8H), clockwise from true north, "
                              "wrapped to (-pi, pi]"),
    "wheel_heading": ("rad", "deg", "wheel (odometer) heading H_W, wrapped"),
    "compass_heading": ("rad", "deg", "compass heading H_C (FIG. 8A; the last valid one when this sample's compass "
                                      "is unusable), wrapped"),
    "x": ("m", None, "dead-reckoned position, east"),
    "y": ("m", None, "dead-reckoned position, north"),
    "speed": ("m/s", "km/h", "speed from the wheel distances"),
    "a": ("s2/m2", None, "current velocity coefficient a of eq. (8) (refined online, eq. 9-13)"),
    "heading_reliability": ("1", None, "heading reliability in (0, 1]: 1 / (1 + heading_bound / reliability_scale)"),
    "heading_bound": ("rad", "deg", "bound on the heading error from SDD, E_W and E_C"),
    "compass_valid": ("1", None, "1 if this sample's compass reading was used, else 0"),
    "odometer_valid": ("1", None, "1 if this sample's pulse counts were plausible, else 0"),
    "curvature": ("1", None, "windowed dD/AD (curvature over the travelled-distance window)"),
    "effective_track": ("m", None, "track T used in eq. (8): T_E of eq. (14) (front) or T_R (rear)"),
    "factor": ("1", None, "filter factor F (FIG. 8E)"),
    "f_delta": ("rad", "deg", "F-DELTA, the filtered compass-minus-wheel heading (FIG. 8G)"),
    "e_c": ("rad", "deg", "compass error bound E_C (FIG. 8C)"),
    "e_w": ("rad", "deg", "wheel error bound E_W (FIG. 8D)"),
    "map_used": ("1", None, "1 if the map heading replaced the compass in this sample (FIG. 8F)"),
    "dpp_ratio": ("1", None, "current dpp_right / dpp_left of the left/right calibration (EP 0619873)"),
    "distance": ("m", "km", "distance travelled"),
    "initialized": ("1", None, "1 once a valid compass sample has started the heading (before that the heading "
                               "outputs are 0 and meaningless)"),
}

# FMI names must be unique: the output ``a`` (the current, refined velocity coefficient) would
# collide with the parameter ``a`` (SPEC §3 key: its initial value), so the output is renamed.
OUTPUT_RENAMES = {"a": "a_current"}

CONFIG_META = (
    ("mode", "String", "complementary", "estimator mode: complementary (US 4,734,863), odometer, compass or kalman"),
    ("refine_a", "Boolean", True, "online refinement of the velocity coefficient a (US 4,788,645 eq. 9-13)"),
    ("calibration", "Boolean", True, "left/right distance-per-pulse calibration (EP 0619873)"),
    ("track", "String", "closed_form", "effective track model: closed_form (eq. 14) or table (claims 15-16)"),
    ("engine", "String", "auto", "auto: native if compiled for this configuration, else python; native: the "
                                 "jaxmodel step's jaxpr lowered to C and compiled at build time; python: lowered to "
                                 "Python at initialization; xla: compiled by XLA"),
    ("discard_bad_samples", "Boolean", True, "true: a bad sample is refused with fmi2Discard and not consumed; "
                                             "false: it is logged as a warning and passed to the estimator, "
                                             "which skips what is unusable (as odocompass estimate does)"),
)

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
    """Variables of the estimator FMU from jaxmodel's tables, with ``values`` as start values."""
    import jaxmodel
    from jaxmodel.params import PARAMETER_TABLE

    params = []
    for spec in PARAMETER_TABLE:
        value = values[spec.key]
        if spec.key == "sensor_axle":
            params.append(dict(name=spec.key, key=spec.key, index=None, type="String", unit=None, start=value,
                               description=spec.description))
        elif isinstance(value, (list, tuple)):
            for i, v in enumerate(value):
                params.append(dict(name=f"{spec.key}_{i}", key=spec.key, index=i, size=len(value), type="Real",
                                   unit=spec.unit, start=float(v),
                                   description=f"{spec.description} [entry {i}: raw heading {i * 360 // len(value)} deg]"))
        else:
            params.append(dict(name=spec.key, key=spec.key, index=None, type="Real", unit=spec.unit or "1",
                               start=float(value), description=spec.description))
    fields = list(jaxmodel.Inputs._fields)
    if fields[0] != "time_s":
        raise RuntimeError(f"jaxmodel.Inputs must start with time_s, got {fields}")
    inputs = []
    for slot, name in enumerate(fields):
        if name == "time_s":
            continue
        kind, unit, start, desc = INPUT_META.get(name, ("Real", "1", 0.0, name))
        inputs.append(dict(name=name, slot=slot, type=kind, unit=unit, start=start, description=desc))
    outputs = []
    taken = {p["name"] for p in params} | {i["name"] for i in inputs}
    for slot, field in enumerate(jaxmodel.Outputs._fields):
        unit, display, desc = OUTPUT_META.get(field, ("1", None, field))
        name = OUTPUT_RENAMES.get(field, field)
        if name in taken:
            raise RuntimeError(f"FMU output {name!r} (jaxmodel.Outputs.{field}) collides with a parameter or input")
        outputs.append(dict(name=name, field=field, slot=slot, type="Real", unit=unit, display_unit=display,
                            description=desc))
    config = [dict(name=n, type=t, start=s, description=d) for n, t, s, d in CONFIG_META]
    return dict(format="odocompass-fmu-manifest/1", model="OdoCompass", sample_fields=fields, inputs=inputs,
                outputs=outputs, parameters=params, config=config)


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
    """``odocompass build-fmu [--params P.json] [--out build/OdoCompass.fmu]``."""
    out = build_estimator(args.out, args.params)
    from fmpy import read_model_description

    md = read_model_description(str(out))
    n = {c: sum(v.causality == c for v in md.modelVariables) for c in ("input", "output", "parameter")}
    print(f"wrote {out} ({n['input']} inputs, {n['output']} outputs, {n['parameter']} parameters; "
          f"start values from {args.params or 'the built-in defaults'}; fmpy validate: no problems)")
    return 0
