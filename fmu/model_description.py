"""The OdoCompass estimator's FMI 2.0 interface, written once for both FMUs (issue 12).

``manifest(values, rules)`` lists every variable from ``jaxmodel``'s own tables (build time):
inputs from ``jaxmodel.Inputs``, outputs from ``jaxmodel.Outputs``, parameters from
``PARAMETER_TABLE`` with min/max from the validation rules (``fmu/param_rules.py``), and the
configuration switches.  ``variables(manifest)`` puts them in the one canonical order whose
position is the value reference: the pythonfmu slave registers them in that order and the native
FMU's generated tables index them the same way.  ``to_xml(manifest, ...)`` writes the whole
``modelDescription.xml`` for either FMU: units with SI base units (parsed from the unit text),
display units, min/max, exact start values, Boolean flags, output dependencies (none: outputs
change only in ``fmi2DoStep``), InitialUnknowns, log categories and the default experiment.

Stdlib only: the pythonfmu FMU bundles this file and calls ``to_xml`` from its slave's ``to_xml``.
"""

from __future__ import annotations

import math
import re
from typing import Any, Iterable, Mapping
from xml.etree.ElementTree import Element, SubElement

DEFAULT_EXPERIMENT = {"startTime": 0.0, "stopTime": 60.0, "stepSize": 0.1}

# jaxmodel.Inputs fields: (FMI type, unit, start, description).  time_s is the communication time.
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

# jaxmodel.Outputs fields: (unit, display unit, description); FLAG_OUTPUTS are Boolean.
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
    "compass_valid": ("1", None, "true if this sample's compass reading was used"),
    "odometer_valid": ("1", None, "true if this sample's pulse counts were plausible"),
    "curvature": ("1", None, "windowed dD/AD (curvature over the travelled-distance window)"),
    "effective_track": ("m", None, "track T used in eq. (8): T_E of eq. (14) (front) or T_R (rear)"),
    "factor": ("1", None, "filter factor F (FIG. 8E)"),
    "f_delta": ("rad", "deg", "F-DELTA, the filtered compass-minus-wheel heading (FIG. 8G)"),
    "e_c": ("rad", "deg", "compass error bound E_C (FIG. 8C)"),
    "e_w": ("rad", "deg", "wheel error bound E_W (FIG. 8D)"),
    "map_used": ("1", None, "true if the map heading replaced the compass in this sample (FIG. 8F)"),
    "dpp_ratio": ("1", None, "current dpp_right / dpp_left of the left/right calibration (EP 0619873)"),
    "distance": ("m", "km", "distance travelled"),
    "initialized": ("1", None, "true once a valid compass sample has started the heading (before that the heading "
                               "outputs are 0 and meaningless)"),
}
FLAG_OUTPUTS = ("compass_valid", "odometer_valid", "map_used", "initialized")

# FMI names must be unique: the output ``a`` (the current, refined velocity coefficient) would
# collide with the parameter ``a`` (SPEC §3 key: its initial value), so the output is renamed.
OUTPUT_RENAMES = {"a": "a_current"}

PARAMETER_TYPES = {"counter_modulus": "Integer", "sensor_axle": "String"}
STRING_PARAMETER_VALUES = {"sensor_axle": ("front", "rear")}

CONFIG_META = (
    ("mode", "String", "complementary", "estimator mode: complementary (US 4,734,863), odometer, compass or kalman"),
    ("refine_a", "Boolean", True, "online refinement of the velocity coefficient a (US 4,788,645 eq. 9-13)"),
    ("calibration", "Boolean", True, "left/right distance-per-pulse calibration (EP 0619873)"),
    ("track", "String", "closed_form", "effective track model: closed_form (eq. 14) or table (claims 15-16)"),
    ("engine", "String", "auto", "pythonfmu FMU: auto (native if compiled for this configuration, else python), "
                                 "native (C compiled at build time), python (lowered at initialization) or xla; "
                                 "the native FMU always runs its compiled C step"),
    ("discard_bad_samples", "Boolean", True, "true: a bad sample is skipped (estimator state unchanged), counted "
                                             "and logged as a warning; false: it is passed to the estimator, "
                                             "which skips what is unusable (as odocompass estimate does)"),
)
DISCARDED = ("discarded_samples", "number of samples refused so far (skipped, or passed to the estimator with a "
                                  "warning when discard_bad_samples is false)")

LOG_CATEGORIES = {
    "logStatusWarning": "Log messages with fmi2Warning status.",
    "logStatusDiscard": "Log messages with fmi2Discard status.",
    "logStatusError": "Log messages with fmi2Error status.",
    "logStatusFatal": "Log messages with fmi2Fatal status.",
    "logAll": "Log all messages.",
    "logBadInput": "Rejected input samples: non-finite compass or position-fix values, implausible pulse counters.",
    "logBadStep": "Rejected communication steps: zero, negative or non-finite step size, time not advancing.",
    "logBadParameter": "Parameters, configuration or variable access refused.",
    "logEngine": "Engine preparation, timing and state save/restore.",
}


# ----------------------------------------------------------------------------------------------
# units: SI base-unit exponents parsed from the unit text ("rad.m2/s2", "1/km2", "deg/min")
# ----------------------------------------------------------------------------------------------
BASE = ("kg", "m", "s", "A", "K", "mol", "cd", "rad")
SYMBOLS: dict[str, tuple[dict[str, int], float]] = {
    "m": ({"m": 1}, 1.0), "s": ({"s": 1}, 1.0), "rad": ({"rad": 1}, 1.0), "kg": ({"kg": 1}, 1.0),
    "A": ({"A": 1}, 1.0), "K": ({"K": 1}, 1.0), "mol": ({"mol": 1}, 1.0), "cd": ({"cd": 1}, 1.0),
    "deg": ({"rad": 1}, math.pi / 180.0), "min": ({"s": 1}, 60.0), "h": ({"s": 1}, 3600.0),
    "km": ({"m": 1}, 1000.0), "T": ({"kg": 1, "A": -1, "s": -2}, 1.0), "uT": ({"kg": 1, "A": -1, "s": -2}, 1e-6),
    # the compass's own unit (SPEC §1: any one unit, µT typical): declared as µT
    "compass": ({"kg": 1, "A": -1, "s": -2}, 1e-6),
}
DISPLAY_UNITS = {"rad": [("deg", 180.0 / math.pi)], "rad/s": [("deg/s", 180.0 / math.pi)],
                 "m/s": [("km/h", 3.6)], "m": [("km", 0.001)]}
_TERM = re.compile(r"^([A-Za-z]+?)(\d+)?$")


def parse_unit(unit: str) -> tuple[dict[str, int], float]:
    """(base-unit exponents, factor) of a unit text; ValueError for an unknown symbol."""
    exps: dict[str, int] = {}
    factor = 1.0
    parts = unit.split("/")
    if len(parts) > 2:
        raise ValueError(f"unit {unit!r}: one '/' at most")
    for sign, part in zip((1, -1), parts):
        for term in part.split("."):
            if term in ("1", ""):
                continue
            m = _TERM.match(term)
            if m is None or m.group(1) not in SYMBOLS:
                raise ValueError(f"unit {unit!r}: unknown symbol {term!r}")
            e = sign * int(m.group(2) or 1)
            base, f = SYMBOLS[m.group(1)]
            factor *= f ** e
            for k, v in base.items():
                exps[k] = exps.get(k, 0) + v * e
    return {k: v for k, v in exps.items() if v}, factor


def exact(x: float) -> str:
    """Shortest text that reads back as the same float64."""
    x = float(x)
    if math.isnan(x):
        return "NaN"
    if math.isinf(x):
        return "INF" if x > 0 else "-INF"
    return repr(x)


# ----------------------------------------------------------------------------------------------
# the manifest (build time, from jaxmodel) and the canonical variable list
# ----------------------------------------------------------------------------------------------
def manifest(values: Mapping[str, Any], bounds: Mapping[str, tuple[float | None, float | None]] | None = None,
             jaxmodel=None) -> dict[str, Any]:
    """Variables of the estimator FMU from jaxmodel's tables, ``values`` as start values, ``bounds``
    (key -> (min, max), from ``param_rules``) as min/max."""
    if jaxmodel is None:
        import jaxmodel
    from jaxmodel.params import PARAMETER_TABLE

    bounds = bounds or {}
    params = []
    for spec in PARAMETER_TABLE:
        value = values[spec.key]
        lo, hi = bounds.get(spec.key, (None, None))
        kind = PARAMETER_TYPES.get(spec.key, "Real")
        common = dict(key=spec.key, min=lo, max=hi)
        if kind == "String":
            params.append(dict(common, name=spec.key, index=None, type="String", unit=None, start=value,
                               allowed=list(STRING_PARAMETER_VALUES.get(spec.key, ())), description=spec.description))
        elif isinstance(value, (list, tuple)):
            for i, v in enumerate(value):
                params.append(dict(common, name=f"{spec.key}_{i}", index=i, size=len(value), type="Real",
                                   unit=spec.unit or "1", start=float(v),
                                   description=f"{spec.description} [entry {i}: raw heading {i * 360 // len(value)} deg]"))
        else:
            start = int(value) if kind == "Integer" else float(value)
            if kind == "Integer" and start != value:
                raise ValueError(f"parameter {spec.key}={value!r} must be an integer in the FMU")
            params.append(dict(common, name=spec.key, index=None, type=kind, unit=None if kind == "Integer" else
                               (spec.unit or "1"), start=start, description=spec.description))
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
        kind = "Boolean" if field in FLAG_OUTPUTS else "Real"
        outputs.append(dict(name=name, field=field, slot=slot, type=kind, unit=unit if kind == "Real" else None,
                            display_unit=display, description=desc))
    config = [dict(name=n, type=t, start=s, description=d) for n, t, s, d in CONFIG_META]
    # what the FMUs report as a wheel sensor that stopped counting (fmi_support.StoppedCounterWatch)
    stopped = dict(min_s=float(jaxmodel.plausibility.STOPPED_MIN_S),
                   other_pulses=float(jaxmodel.plausibility.STOPPED_OTHER_PULSES))
    return dict(format="odocompass-fmu-manifest/2", model="OdoCompass", sample_fields=fields, inputs=inputs,
                outputs=outputs, parameters=params, config=config, stopped_counter=stopped)


def variables(m: Mapping[str, Any]) -> list[dict[str, Any]]:
    """Every FMU variable in value-reference order (vr = position): inputs, outputs,
    discarded_samples, parameters, configuration.  ``group`` says which."""
    out: list[dict[str, Any]] = []

    def add(group, spec, **extra):
        out.append(dict(spec, group=group, vr=len(out), **extra))

    for s in m["inputs"]:
        add("input", s, causality="input", variability="continuous" if s["type"] == "Real" else "discrete")
    for s in m["outputs"]:
        add("output", s, causality="output", variability="discrete")
    add("discarded", dict(name=DISCARDED[0], type="Integer", description=DISCARDED[1]), causality="output",
        variability="discrete")
    for s in m["parameters"]:
        add("parameter", s, causality="parameter", variability="fixed", initial="exact")
    for s in m["config"]:
        add("config", s, causality="parameter", variability="fixed", initial="exact")
    return out


def _start_text(kind: str, start: Any) -> str:
    if kind == "Real":
        return exact(start)
    if kind == "Integer":
        return str(int(start))
    if kind == "Boolean":
        return "true" if start else "false"
    return str(start)


def to_xml(m: Mapping[str, Any], *, guid: str, model_identifier: str, generation_tool: str,
           cs_options: Mapping[str, Any], description: str, author: str = "odocompass", version: str = "0.1.0",
           date: str | None = None, source_files: Iterable[str] = (),
           log_categories: Mapping[str, str] = LOG_CATEGORIES) -> Element:
    """The complete fmiModelDescription element for either FMU."""
    attrib = dict(fmiVersion="2.0", modelName="OdoCompass", guid=guid, description=description, author=author,
                  version=version, generationTool=generation_tool, variableNamingConvention="structured")
    if date:
        attrib["generationDateAndTime"] = date
    root = Element("fmiModelDescription", attrib)
    cs = SubElement(root, "CoSimulation", {"modelIdentifier": model_identifier,
                                           **{k: (str(v).lower() if isinstance(v, bool) else str(v))
                                              for k, v in cs_options.items()}})
    files = list(source_files)
    if files:
        sf = SubElement(cs, "SourceFiles")
        for f in files:
            SubElement(sf, "File", name=f)

    var_list = variables(m)
    used: list[str] = []
    for v in var_list:
        if v["type"] == "Real":
            u = v.get("unit") or "1"
            if u not in used:
                used.append(u)
    units = SubElement(root, "UnitDefinitions")
    for u in used:
        exps, factor = parse_unit(u)
        ue = SubElement(units, "Unit", name=u)
        battr = {k: str(exps[k]) for k in BASE if k in exps}
        if factor != 1.0:
            battr["factor"] = exact(factor)
        SubElement(ue, "BaseUnit", battr)
        for dname, dfactor in DISPLAY_UNITS.get(u, []):
            SubElement(ue, "DisplayUnit", name=dname, factor=exact(dfactor))
    cats = SubElement(root, "LogCategories")
    for name, desc in log_categories.items():
        SubElement(cats, "Category", name=name, description=desc)
    SubElement(root, "DefaultExperiment", {k: exact(v) for k, v in DEFAULT_EXPERIMENT.items()})

    mv = SubElement(root, "ModelVariables")
    outputs = []
    for v in var_list:
        sv_attr = dict(name=v["name"], valueReference=str(v["vr"]), description=v["description"],
                       causality=v["causality"], variability=v["variability"])
        if v.get("initial"):
            sv_attr["initial"] = v["initial"]
        sv = SubElement(mv, "ScalarVariable", sv_attr)
        t_attr: dict[str, str] = {}
        kind = v["type"]
        if kind == "Real":
            t_attr["unit"] = v.get("unit") or "1"
            if v.get("display_unit"):
                t_attr["displayUnit"] = v["display_unit"]
        if kind in ("Real", "Integer"):
            for a in ("min", "max"):
                if v.get(a) is None:
                    continue
                if kind == "Real":
                    t_attr[a] = exact(v[a])
                else:  # fmi2Integer is 32-bit: a bound beyond it bounds nothing
                    b = math.ceil(v[a]) if a == "min" else math.floor(v[a])
                    if -2 ** 31 <= b <= 2 ** 31 - 1:
                        t_attr[a] = str(b)
        if v["causality"] in ("input", "parameter"):
            t_attr["start"] = _start_text(kind, v["start"])
        SubElement(sv, kind, t_attr)
        if v["causality"] == "output":
            outputs.append(v["vr"] + 1)
    ms = SubElement(root, "ModelStructure")
    out_el = SubElement(ms, "Outputs")
    for i in outputs:  # outputs change only in fmi2DoStep: no direct feedthrough from any input
        SubElement(out_el, "Unknown", index=str(i), dependencies="")
    init_el = SubElement(ms, "InitialUnknowns")
    for i in outputs:  # computed in fmi2ExitInitializationMode from the inputs and parameters
        SubElement(init_el, "Unknown", index=str(i))
    return root


def to_text(root: Element) -> str:
    from xml.dom import minidom
    from xml.etree.ElementTree import tostring

    return minidom.parseString(tostring(root, encoding="unicode")).toprettyxml(indent="  ", encoding="UTF-8").decode()
