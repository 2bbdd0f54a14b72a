"""FMI 2.0 plumbing shared by the project's pythonfmu slaves (bundled into each FMU's resources).

pythonfmu 0.7.0 writes neither units nor ``ModelStructure/InitialUnknowns``, and it writes Real
start values with 16 significant digits (not always the exact float64).  ``decorate`` fixes the
model description a slave's ``to_xml`` returns: ``UnitDefinitions`` (SI base-unit exponents,
display units such as deg for rad), a ``unit`` on every Real variable, ``InitialUnknowns`` for
every output, and round-trip exact start values.  With it ``fmpy validate`` finds no problems.

Self-contained (stdlib only): loaded by the slaves under a private module name.
"""

from __future__ import annotations

import math
from typing import Any, Iterable, Mapping
from xml.etree.ElementTree import Element, SubElement

# unit name -> (base-unit exponents, factor, offset, display units [(name, factor, offset)])
# FMI 2.0: value_in_base_units = factor * value + offset; display = factor * value + offset.
UNITS: dict[str, tuple[dict[str, int], float, float, list[tuple[str, float, float]]]] = {
    "1": ({}, 1.0, 0.0, []),
    "rad": ({"rad": 1}, 1.0, 0.0, [("deg", 180.0 / math.pi, 0.0)]),
    "deg": ({"rad": 1}, math.pi / 180.0, 0.0, []),
    "rad/s": ({"rad": 1, "s": -1}, 1.0, 0.0, [("deg/s", 180.0 / math.pi, 0.0)]),
    "m": ({"m": 1}, 1.0, 0.0, [("km", 0.001, 0.0)]),
    "s": ({"s": 1}, 1.0, 0.0, []),
    "m/s": ({"m": 1, "s": -1}, 1.0, 0.0, [("km/h", 3.6, 0.0)]),
    "s2/m2": ({"m": -2, "s": 2}, 1.0, 0.0, []),
    "rad.m2/s2": ({"rad": 1, "m": 2, "s": -2}, 1.0, 0.0, []),
    "1/rad2": ({"rad": -2}, 1.0, 0.0, []),
    "1/m": ({"m": -1}, 1.0, 0.0, []),
    "uT": ({"kg": 1, "A": -1, "s": -2}, 1e-6, 0.0, []),
    "1/km2": ({"m": -2}, 1e-6, 0.0, []),
    "1/s": ({"s": -1}, 1.0, 0.0, []),
    # "compass": the compass's own unit (any one unit, µT typical; SPEC §1): no SI base given.
}


def exact(x: float) -> str:
    """Shortest text that reads back as the same float64 (XML start values)."""
    x = float(x)
    if math.isnan(x):
        return "NaN"
    if math.isinf(x):
        return "INF" if x > 0 else "-INF"
    return repr(x)


def decorate(root: Element, meta: Mapping[str, Mapping[str, Any]], real_starts: Mapping[str, float]) -> Element:
    """Add units, display units, InitialUnknowns and exact Real starts to a pythonfmu model description.

    ``meta`` maps a variable name to at least ``unit`` (Real variables) and optionally
    ``display_unit``, ``min``, ``max``, ``nominal``; ``real_starts`` maps names to exact start values.
    """
    variables = root.find("ModelVariables")
    used_units: list[str] = []
    outputs: list[int] = []
    for index, sv in enumerate(variables.findall("ScalarVariable"), start=1):
        name = sv.get("name")
        m = meta.get(name, {})
        real = sv.find("Real")
        if real is not None:
            unit = m.get("unit") or "1"
            real.set("unit", unit)
            if unit not in used_units:
                used_units.append(unit)
            if m.get("display_unit"):
                real.set("displayUnit", m["display_unit"])
            for attr in ("min", "max", "nominal"):
                if m.get(attr) is not None:
                    real.set(attr, exact(m[attr]))
            if name in real_starts and real.get("start") is not None:
                real.set("start", exact(real_starts[name]))
        if sv.get("causality") == "output":
            outputs.append(index)

    units = Element("UnitDefinitions")
    for unit in used_units:
        u = SubElement(units, "Unit", name=unit)
        spec = UNITS.get(unit)
        if spec is None:
            continue  # a unit of its own (e.g. "compass"): named, no SI base
        exponents, factor, offset, display = spec
        attrs = {k: str(v) for k, v in exponents.items()}
        if factor != 1.0:
            attrs["factor"] = exact(factor)
        if offset != 0.0:
            attrs["offset"] = exact(offset)
        SubElement(u, "BaseUnit", attrs)
        for dname, dfactor, doffset in display:
            d = {"name": dname}
            if dfactor != 1.0:
                d["factor"] = exact(dfactor)
            if doffset != 0.0:
                d["offset"] = exact(doffset)
            SubElement(u, "DisplayUnit", d)
    # FMI 2.0 order: CoSimulation, UnitDefinitions, TypeDefinitions, LogCategories, DefaultExperiment, ...
    children = list(root)
    position = next((i + 1 for i, c in enumerate(children) if c.tag in ("CoSimulation", "ModelExchange")), 0)
    root.insert(position, units)

    structure = root.find("ModelStructure")
    for tag in ("Outputs", "InitialUnknowns"):
        old = structure.find(tag)
        if old is not None:
            structure.remove(old)
    if outputs:
        out = SubElement(structure, "Outputs")
        for i in outputs:
            SubElement(out, "Unknown", index=str(i))
        init = SubElement(structure, "InitialUnknowns")
        for i in outputs:
            SubElement(init, "Unknown", index=str(i))
    return root


def float_to_text(x: float) -> str:
    """Exact, JSON-safe text of a float64 (``float.hex``; NaN and infinities spelled out)."""
    x = float(x)
    if x != x:
        return "nan"
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    return x.hex()


def text_to_float(s: str) -> float:
    if s in ("nan", "inf", "-inf"):
        return float(s)
    return float.fromhex(s)


def floats_to_text(values: Iterable[float]) -> list[str]:
    return [float_to_text(v) for v in values]


def text_to_floats(values: Iterable[str]) -> list[float]:
    return [text_to_float(v) for v in values]


STATE_FORMAT = "odocompass-fmu-state/1"
STATE_PHASES = ("instantiated", "initialization", "stepping")


def format_state(*, bundle_id: str, phase: str, params: Mapping[str, Any], config: Mapping[str, Any], t_start: float,
                 t_last: float, s, o, x, strikes: int, discarded: int, stopped, refused) -> dict:
    """A pythonfmu FMU state as JSON-ready fields, floats as ``float.hex`` (exact); ``parse_state`` reads it back."""
    text = {k: (floats_to_text(v) if isinstance(v, list) else float_to_text(v) if isinstance(v, float) else v)
            for k, v in params.items()}
    return {"format": STATE_FORMAT, "bundle_id": bundle_id, "phase": phase, "params": text, "config": dict(config),
            "t_start": float_to_text(t_start), "t_last": float_to_text(t_last),
            "s": None if s is None else floats_to_text(s), "o": floats_to_text(o), "x": floats_to_text(x),
            "strikes": strikes, "discarded": discarded, "stopped": stopped, "refused": refused}


def parse_state(state, *, param_keys, n_inputs: int, n_outputs: int) -> dict:
    """The fields of a pythonfmu FMU state (the slave's ``_get_fmu_state`` dict), every one checked before any is
    used: a ValueError says what is wrong, and a damaged or foreign state never half-replaces an instance's (a short
    input vector once made the next fmi2SetInteger fatal; a missing parameter silently took its default)."""
    if not isinstance(state, dict) or state.get("format") != STATE_FORMAT:
        found = state.get("format") if isinstance(state, dict) else type(state).__name__
        raise ValueError(f"not an OdoCompass FMU state: format {found!r}")
    raw = state.get("params")
    if not isinstance(raw, dict) or set(raw) != set(param_keys):
        missing = sorted(set(param_keys) - set(raw or {}))
        extra = sorted(set(raw or {}) - set(param_keys))
        raise ValueError(f"the state's parameters differ from this FMU's (missing {missing}, unknown {extra})")
    params = {k: (text_to_floats(v) if isinstance(v, list) else
                  v if k == "sensor_axle" or not isinstance(v, str) else text_to_float(v)) for k, v in raw.items()}
    out = dict(params=params, config=dict(state["config"]), phase=state["phase"],
               t_start=text_to_float(state["t_start"]), t_last=text_to_float(state["t_last"]),
               o=text_to_floats(state["o"]), x=text_to_floats(state["x"]), strikes=int(state["strikes"]),
               discarded=int(state["discarded"]), stopped=state.get("stopped"), refused=state.get("refused"),
               s=None if state["s"] is None else text_to_floats(state["s"]))
    for name, n in (("x", n_inputs), ("o", n_outputs)):  # the estimator state's size: once its engine is ready
        if len(out[name]) != n:
            raise ValueError(f"the state's {name!r} holds {len(out[name])} values, this FMU {n}")
    if out["phase"] not in STATE_PHASES or out["strikes"] < 0 or out["discarded"] < 0:
        raise ValueError(f"the state's phase {out['phase']!r} or counts ({out['strikes']}, {out['discarded']}) "
                         f"are no state of this FMU")
    return out


# ----------------------------------------------------------------------------------------------
# a wheel sensor that stopped counting
# ----------------------------------------------------------------------------------------------
class StoppedCounterWatch:
    """Reports a wheel pulse counter that stopped counting while the other counted on (a sensor fault), from the
    samples an FMU steps.  The estimator substitutes such samples where it can tell them from a turn and says
    nothing; ``estimate`` warns of it from the log, and an FMU's host learns it from this.

    A run starts at the last sample before the first increment of 0 on one side with at least ``other_pulses``
    on the other; once it lasts ``min_s`` it is reported once (a warning), and its end once (an information).
    The thresholds are the manifest's ``stopped_counter`` (jaxmodel.plausibility.STOPPED_MIN_S,
    STOPPED_OTHER_PULSES); odocompass_fmi2.c's ``watch_counters`` is the native FMU's twin."""

    SIDES = ("left", "right")

    def __init__(self, min_s: float, other_pulses: float):
        self.min_s, self.other_pulses = float(min_s), float(other_pulses)
        self.since: list[float | None] = [None, None]  # time (s) of the sample before each side's run
        self.reported = [False, False]

    def update(self, t_previous: float, t: float, increments) -> list[tuple[str, str]]:
        """One stepped sample at ``t`` (s) after one at ``t_previous``, with the (left, right) counter increments
        (pulses, wraps decoded; NaN if unknown).  Returns the messages to log as (level, text), level "warning"
        or "ok"."""
        out = []
        for i, side in enumerate(self.SIDES):
            other = self.SIDES[1 - i]
            if increments[i] == 0.0 and abs(increments[1 - i]) >= self.other_pulses:
                if self.since[i] is None:
                    self.since[i] = t_previous
                if not self.reported[i] and t - self.since[i] >= self.min_s:
                    self.reported[i] = True
                    out.append(("warning", f"{side}_pulses stopped counting while {other}_pulses counted on, since "
                                           f"t={self.since[i]!r} s: a wheel sensor fault; the estimator replaces its "
                                           "samples by the other wheel's travel where it can tell them from a turn"))
                continue
            if self.reported[i]:
                out.append(("ok", f"{side}_pulses no longer stopped at t={t!r} s (stopped since t={self.since[i]!r} "
                                  f"s, {t_previous - self.since[i]:.6g} s)"))
            self.since[i], self.reported[i] = None, False
        return out

    def to_json(self) -> dict[str, Any]:
        """The watch's state for an FMU state (times as float.hex)."""
        return {"since": [None if v is None else float_to_text(v) for v in self.since], "reported": list(self.reported)}

    def restore(self, data: Mapping[str, Any] | None) -> None:
        """The state of ``to_json`` (None: nothing running, as in a state saved before the watch existed)."""
        data = data or {}
        self.since = [None if v is None else text_to_float(v) for v in data.get("since", [None, None])]
        self.reported = [bool(v) for v in data.get("reported", [False, False])]


# ----------------------------------------------------------------------------------------------
# pythonfmu 0.7.0's exit-time abort (issue 12)
# ----------------------------------------------------------------------------------------------
_EXIT_GUARDED: set[str] = set()
_EXIT_HANDLES: list = []


def guard_pythonfmu_exit(resources) -> str:
    """Make pythonfmu 0.7.0's exit-time abort impossible in a Python host.

    The wrapper library keeps a global ``std::shared_ptr<PyState>``; at process exit the C++ runtime
    destroys it, then the library's unload hook (``__attribute__((destructor))``) assigns ``nullptr``
    to the destroyed pointer and decrements a reference count in freed memory: "corrupted
    double-linked list" in ~1 % of exits, an invalid read under valgrind every time.  Calling the
    library's exported ``finalizePythonInterpreter()`` from an ``atexit`` hook empties the pointer
    while everything is alive (in a Python host pythonfmu never initialized Python, so this only
    joins a finished thread); what runs at exit then finds it empty.  The library is held open
    (``RTLD_NOLOAD``: the copy already loaded, one more reference) so that the hook can call it even
    after the host unloaded the FMU.  In a C host (Python embedded by pythonfmu, whose atexit hooks run
    inside that very finalization) nothing is done.  Returns what was done, for the log.
    """
    import atexit
    import ctypes
    import os
    from pathlib import Path

    try:
        exe = Path(os.readlink("/proc/self/exe")).name
    except OSError:
        import sys

        exe = Path(sys.executable or "").name
    if not exe.startswith(("python", "pypy")):
        return "C host: exit guard not installed"
    if os.environ.get("ODOCOMPASS_FMU_EXIT_GUARD") == "0":  # for measuring the fault (bench/bench_fmu.py)
        return "exit guard disabled by ODOCOMPASS_FMU_EXIT_GUARD=0"
    binaries = Path(resources).resolve().parent / "binaries"
    libs = sorted(binaries.glob("*/*.so")) + sorted(binaries.glob("*/*.dylib"))
    done = []
    for lib in libs:
        key = str(lib)
        if key in _EXIT_GUARDED:
            continue
        try:
            handle = ctypes.CDLL(key, mode=getattr(os, "RTLD_NOLOAD", 4) | getattr(os, "RTLD_NOW", 2))
            fn = handle.finalizePythonInterpreter
        except (OSError, AttributeError):
            continue
        fn.restype = None
        fn.argtypes = []
        _EXIT_GUARDED.add(key)
        _EXIT_HANDLES.append(handle)
        atexit.register(fn)
        done.append(lib.name)
    return "exit guard: " + (", ".join(done) if done else "already installed")
