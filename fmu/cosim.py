"""A co-simulation master for the project's FMUs, written on fmpy's ``FMU2Slave`` (FIELD-NOTES).

* :class:`Slave` wraps one FMU instance: names instead of value references, the FMU's log
  messages captured (status, category, text), fmi2Discard answered as ``False`` instead of
  fmpy's exception.
* :func:`replay` steps a recorded drive (columns in ``jaxmodel.Inputs`` names) through the
  estimator FMU, one sample per ``fmi2DoStep``: sample 0 is set in initialization mode, sample
  k before ``doStep(t[k-1], t[k] - t[k-1])`` (the FMU stamps it ``t + h``).
* :class:`Master` steps any set of connected FMUs, fixed-step Gauss-Seidel; :func:`cosimulate`
  connects the VehicleSensors FMU to the OdoCompass FMU with it: the vehicle steps to ``t + h``
  first, its sensor outputs become the estimator's inputs for the same step, so the estimate at
  ``t + h`` is compared with the truth at ``t + h``.
* :func:`demo_cosimulation` builds both FMUs if needed, runs the co-simulation and the SSP
  variant, writes a plot of estimated against true heading, and returns the time series.

This module imports neither ``jaxmodel`` nor jax: the FMUs bring their own code.
"""

from __future__ import annotations

import math
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

STATUS = ("OK", "WARNING", "DISCARD", "ERROR", "FATAL", "PENDING")
ESTIMATOR_OUTPUTS = ("heading", "wheel_heading", "compass_heading", "x", "y", "speed", "a_current",
                     "heading_reliability")
VEHICLE_TO_ESTIMATOR = (("left_pulses", "left_pulses"), ("right_pulses", "right_pulses"),
                        ("compass_x", "compass_x"), ("compass_y", "compass_y"),
                        ("compass_unreliable_area", "compass_unreliable_area"))


def wrap(a):
    a = np.asarray(a, dtype=np.float64)
    w = np.mod(a + math.pi, 2.0 * math.pi) - math.pi
    return np.where(w == -math.pi, math.pi, w)


class Slave:
    """One co-simulation FMU instance driven by name (fmpy ``FMU2Slave`` underneath)."""

    def __init__(self, fmu_path: str | Path, instance_name: str = "instance", unzip_dir: str | Path | None = None,
                 logging_on: bool = True, echo: bool = False):
        from fmpy import extract, read_model_description
        from fmpy.fmi2 import FMU2Slave, fmi2CallbackFunctions, fmi2CallbackLoggerTYPE, defaultCallbacks

        self.path = Path(fmu_path)
        self.md = read_model_description(str(self.path))
        self.unzip_dir = Path(unzip_dir) if unzip_dir else Path(extract(str(self.path)))
        self._own_dir = unzip_dir is None
        self.vars = {v.name: v for v in self.md.modelVariables}
        self.vr = {n: v.valueReference for n, v in self.vars.items()}
        self.messages: list[tuple[str, str, str]] = []
        messages = self.messages  # the logger closes over the list, not over self (no reference cycle)

        def logger(component, instance, status, category, message):
            # The message is the FMU's printf format; pythonfmu FMUs pass no arguments and escape '%'.
            # (fmpy's addLoggerProxy, which formats, keeps ONE global target for all callback structs:
            # with several instances it would route messages to -- and call -- the wrong, possibly
            # freed, Python logger, so it is not used here.)
            text = message.decode("utf-8", "replace") if message else ""
            entry = (STATUS[status] if 0 <= status < len(STATUS) else str(status),
                     category.decode("utf-8", "replace") if category else "", text.replace("%%", "%"))
            messages.append(entry)
            if echo:
                print(f"[{entry[0]}] {instance.decode() if instance else ''} {entry[1]}: {entry[2]}")

        self._callbacks = fmi2CallbackFunctions()
        self._callbacks.logger = fmi2CallbackLoggerTYPE(logger)
        self._callbacks.allocateMemory = defaultCallbacks.allocateMemory
        self._callbacks.freeMemory = defaultCallbacks.freeMemory
        self.fmu = FMU2Slave(guid=self.md.guid, unzipDirectory=str(self.unzip_dir),
                             modelIdentifier=self.md.coSimulation.modelIdentifier, instanceName=instance_name)
        self.fmu.instantiate(callbacks=self._callbacks, loggingOn=logging_on)
        self.time = None
        self.last_status = None

    # -- values -----------------------------------------------------------------------------
    def set(self, values: Mapping[str, Any]) -> None:
        groups: dict[str, tuple[list[int], list[Any]]] = {}
        for name, value in values.items():
            v = self.vars[name]
            vrs, vals = groups.setdefault(v.type, ([], []))
            vrs.append(v.valueReference)
            vals.append(value)
        for kind, (vrs, vals) in groups.items():
            if kind == "Real":
                self.fmu.setReal(vrs, [float(x) for x in vals])
            elif kind in ("Integer", "Enumeration"):
                self.fmu.setInteger(vrs, [int(x) for x in vals])
            elif kind == "Boolean":
                self.fmu.setBoolean(vrs, [bool(x) for x in vals])
            elif kind == "String":
                self.fmu.setString(vrs, [str(x) for x in vals])

    def get(self, names: Sequence[str]) -> dict[str, Any]:
        out: dict[str, Any] = {}
        by_type: dict[str, list[str]] = {}
        for n in names:
            by_type.setdefault(self.vars[n].type, []).append(n)
        for kind, ns in by_type.items():
            vrs = [self.vr[n] for n in ns]
            if kind == "Real":
                vals = self.fmu.getReal(vrs)
            elif kind in ("Integer", "Enumeration"):
                vals = self.fmu.getInteger(vrs)
            elif kind == "Boolean":
                vals = [bool(v) for v in self.fmu.getBoolean(vrs)]
            else:
                vals = [v.decode() if isinstance(v, bytes) else v for v in self.fmu.getString(vrs)]
            out.update(zip(ns, vals))
        return out

    # -- life cycle ---------------------------------------------------------------------------
    def initialize(self, start_time: float = 0.0, parameters: Mapping[str, Any] | None = None,
                   inputs: Mapping[str, Any] | None = None, stop_time: float | None = None) -> None:
        self.fmu.setupExperiment(startTime=start_time, stopTime=stop_time)
        if parameters:
            self.set(parameters)
        self.fmu.enterInitializationMode()
        if inputs:
            self.set(inputs)
        self.fmu.exitInitializationMode()
        self.time = start_time

    def step(self, t: float, h: float) -> bool:
        """``fmi2DoStep(t, h)``: True when the step consumed its sample; False for fmi2Discard or when
        the FMU skipped the sample (its ``discarded_samples`` output went up; the OdoCompass FMUs answer
        a skipped sample with fmi2Warning (native) or fmi2OK (pythonfmu) so that masters go on).
        ``last_status`` keeps the answer's name; statuses above fmi2Discard raise."""
        from fmpy.fmi1 import FMICallException

        before = self._discarded_count()
        try:
            status = self.fmu.fmi2DoStep(self.fmu.component, t, h, 1)  # fmpy's doStep drops the status
        except FMICallException as exc:
            self.last_status = STATUS[exc.status] if 0 <= exc.status < len(STATUS) else str(exc.status)
            if exc.status == 2:
                return False
            raise
        self.last_status = STATUS[status] if isinstance(status, int) and 0 <= status < len(STATUS) else "OK"
        self.time = t + h
        return before is None or self._discarded_count() == before

    def _discarded_count(self):
        vr = self.vr.get("discarded_samples")
        return None if vr is None else self.fmu.getInteger([vr])[0]

    def close(self) -> None:
        try:
            self.fmu.terminate()
        finally:
            self.fmu.freeInstance()
            if self._own_dir:
                shutil.rmtree(self.unzip_dir, ignore_errors=True)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


# ----------------------------------------------------------------------------------------------
# Replay of a recorded drive through the estimator FMU
# ----------------------------------------------------------------------------------------------
INPUT_NAMES = ("left_pulses", "right_pulses", "compass_x", "compass_y", "map_heading", "map_valid",
               "compass_unreliable_area", "fix_east_m", "fix_north_m", "fix_valid")


def _sample(columns: Mapping[str, np.ndarray], k: int, names: Sequence[str]) -> dict[str, Any]:
    out = {}
    for n in names:
        v = columns[n][k]
        if n in ("left_pulses", "right_pulses"):
            out[n] = int(v)
        elif n in ("map_valid", "compass_unreliable_area", "fix_valid"):
            out[n] = bool(v > 0.5)
        else:
            out[n] = float(v)
    return out


def replay(fmu_path: str | Path, columns: Mapping[str, Sequence[float]], parameters: Mapping[str, Any] | None = None,
           outputs: Sequence[str] | None = None, slave: Slave | None = None) -> dict[str, Any]:
    """Step ``columns`` (time_s plus FMU input names) through the estimator FMU, one sample per step.

    Returns {output name: array} plus ``status`` (per sample: 1 stepped, 0 discarded; sample 0 is
    the initialization) and ``messages`` (the FMU's log).
    """
    cols = {k: np.asarray(v) for k, v in columns.items()}
    t = np.asarray(cols["time_s"], dtype=np.float64)
    names = [n for n in INPUT_NAMES if n in cols]
    own = slave is None
    s = slave or Slave(fmu_path, "replay")
    outputs = list(outputs or [v.name for v in s.md.modelVariables
                               if v.causality == "output" and v.type in ("Real", "Boolean")])
    try:
        s.initialize(float(t[0]), parameters, _sample(cols, 0, names))
        res = {n: np.empty(t.shape[0]) for n in outputs}
        status = np.ones(t.shape[0], dtype=np.int8)
        real = [n for n in outputs if s.vars[n].type == "Real"]
        flags = [n for n in outputs if s.vars[n].type == "Boolean"]
        vrs, fvrs = [s.vr[n] for n in real], [s.vr[n] for n in flags]

        def record(k):
            for n, v in zip(real, s.fmu.getReal(vrs) if vrs else []):
                res[n][k] = v
            for n, v in zip(flags, s.fmu.getBoolean(fvrs) if fvrs else []):
                res[n][k] = 1.0 if v else 0.0

        record(0)
        for k in range(1, t.shape[0]):
            s.set(_sample(cols, k, names))
            ok = s.step(float(t[k - 1]), float(t[k] - t[k - 1]))
            status[k] = 1 if ok else 0
            record(k)
        res["status"] = status
        res["messages"] = list(s.messages)
        return res
    finally:
        if own:
            s.close()


# ----------------------------------------------------------------------------------------------
# Vehicle -> estimator co-simulation
# ----------------------------------------------------------------------------------------------
# Knots of the scripted drive: (time s, speed m/s) and (time s, road-wheel steering angle rad, + right).
# Lateral accelerations stay below ~3.5 m/s² and curvatures below what the seed's wheel model covers.
_SPEED_KNOTS = (
    (0, 0), (8, 12), (25, 12), (29, 6), (35, 6), (39, 12), (55, 12), (59, 6), (65, 6), (69, 12),      # town
    (88, 12), (95, 0), (102, 0), (110, 12), (115, 7), (142, 7), (147, 12), (183, 12), (187, 6),
    (195, 6), (200, 12), (240, 12), (255, 22), (330, 22), (345, 32), (470, 32), (480, 15),             # country, motorway
    (505, 15), (515, 3), (548, 3), (552, 0), (556, 0), (560, -1.5), (575, -1.5), (579, 0), (600, 0),   # ramp, parking
)
_STEER_KNOTS = (
    (0, 0), (30, 0), (31, 0.175), (33.6, 0.175), (34.6, 0),             # right turn at 6 m/s
    (60, 0), (61, -0.175), (63.6, -0.175), (64.6, 0),                   # left turn
    (116, 0), (117, 0.08), (118.5, 0.08), (119.5, -0.178), (129.6, -0.178), (130.6, 0.08), (132, 0.08), (133, 0),  # roundabout
    (160, 0), (163, 0.03), (168, 0.03), (171, 0),                       # a bend
    (190, 0), (191, 0.175), (193.6, 0.175), (194.6, 0),                 # right turn
    (205, 0), (208, -0.01), (214, 0.01), (220, 0),                      # weaving
    (482, 0), (485, 0.045), (501, 0.045), (504, 0),                     # exit loop (270°)
    (518, 0), (519, 0.3), (523, 0.3), (524, 0),                         # into the car park
    (561, 0), (562, -0.35), (572, -0.35), (573, 0), (600, 0),           # reversing into a space
)


def demo_profile(t: float) -> tuple[float, float]:
    """A scripted 10-minute drive, (steering angle rad, speed m/s) at time t (repeats every 600 s).

    Town driving with right and left turns at 6 m/s, a stop, a roundabout, a country road with
    bends (22 m/s), a motorway with a long curve and a lane change (32 m/s), an exit loop, and a
    car park with a reversing manoeuvre.
    """
    t = t % 600.0
    steer = float(np.interp(t, [k[0] for k in _STEER_KNOTS], [k[1] for k in _STEER_KNOTS]))
    speed = float(np.interp(t, [k[0] for k in _SPEED_KNOTS], [k[1] for k in _SPEED_KNOTS]))
    if 245.0 < t < 330.0:
        steer += 0.0108 * math.sin(2.0 * math.pi * (t - 245.0) / 40.0)   # country bends, R >= 250 m
    if 360.0 < t < 380.0:
        steer += 0.0054 * min(1.0, (t - 360.0) / 4.0, (380.0 - t) / 4.0)  # motorway curves, R = 500 m, ~45° each
    if 440.0 < t < 460.0:
        steer -= 0.0054 * min(1.0, (t - 440.0) / 4.0, (460.0 - t) / 4.0)
    if 420.0 < t < 426.0:
        steer += 0.003 * (1.0 if t < 423.0 else -1.0)                     # lane change
    return steer, speed


@dataclass
class CosimResult:
    time: np.ndarray
    true_heading: np.ndarray
    heading: np.ndarray
    series: dict[str, np.ndarray] = field(default_factory=dict)
    discarded: int = 0
    messages: list = field(default_factory=list)
    end_time: float = 0.0

    def heading_error_deg(self) -> np.ndarray:
        return np.degrees(wrap(self.heading - self.true_heading))

    def rmse_deg(self, after_s: float = 60.0) -> float:
        m = self.time >= self.time[0] + after_s
        return float(np.sqrt(np.mean(self.heading_error_deg()[m] ** 2)))


class Master:
    """Fixed-step Gauss-Seidel master over named :class:`Slave` components.

    ``connections`` are ``(source, output, target, input)``; ``order`` is the stepping order (default:
    the order of ``components``).  Each step, every component in turn gets its connected inputs from
    the current outputs of its sources -- components earlier in the order are already at ``t + h``,
    later ones still at ``t`` -- plus the external inputs at ``t``, then ``doStep(t, h)``.  A discarded
    step is counted per component and the master goes on (the OdoCompass FMU leaves its state as
    it was; its next step sees the new sample).
    """

    def __init__(self, components: Mapping[str, Slave], connections: Sequence[tuple[str, str, str, str]],
                 order: Sequence[str] | None = None):
        self.components = dict(components)
        self.order = list(order or self.components)
        self.incoming: dict[str, list[tuple[str, str, str]]] = {name: [] for name in self.components}
        for src, out, dst, inp in connections:
            self.incoming[dst].append((src, out, inp))
        self.discarded = {name: 0 for name in self.components}

    def _inputs_of(self, name, external):
        values = {inp: self.components[src].get([out])[out] for src, out, inp in self.incoming[name]}
        values.update(external.get(name, {}))
        return values

    def initialize(self, start_time: float, stop_time: float | None = None,
                   parameters: Mapping[str, Mapping[str, Any]] | None = None,
                   external: Mapping[str, Mapping[str, Any]] | None = None) -> None:
        """Initialize in order; each component's initial inputs come from its (already initialized) sources."""
        for name in self.order:
            self.components[name].initialize(start_time, (parameters or {}).get(name),
                                             self._inputs_of(name, external or {}), stop_time)

    def step(self, t: float, h: float, external: Mapping[str, Mapping[str, Any]] | None = None) -> None:
        for name in self.order:
            c = self.components[name]
            values = self._inputs_of(name, external or {})
            if values:
                c.set(values)
            if not c.step(t, h):
                self.discarded[name] += 1

    def run(self, start_time: float, stop_time: float, step: float,
            external: Callable[[float], Mapping[str, Mapping[str, Any]]] | None = None,
            record: Sequence[tuple[str, str]] = (), parameters: Mapping[str, Mapping[str, Any]] | None = None,
            ) -> dict[str, np.ndarray]:
        """Initialize, step to ``stop_time``; returns ``time`` and ``component.variable`` series."""
        n = int(round((stop_time - start_time) / step))
        times = start_time + step * np.arange(n + 1)
        ext = external or (lambda t: {})
        self.initialize(start_time, stop_time, parameters, ext(start_time))
        rec = {f"{c}.{v}": np.empty(n + 1) for c, v in record}
        by_comp: dict[str, list[str]] = {}
        for c, v in record:
            by_comp.setdefault(c, []).append(v)

        def sample(k):
            for c, names in by_comp.items():
                vals = self.components[c].get(names)
                for v in names:
                    rec[f"{c}.{v}"][k] = vals[v]

        sample(0)
        for k in range(1, n + 1):
            t = float(times[k - 1])
            self.step(t, step, ext(t))
            sample(k)
        rec["time"] = times
        return rec


def cosimulate(estimator_fmu: str | Path, vehicle_fmu: str | Path, stop_time: float = 600.0, step: float = 0.1,
               profile: Callable[[float], tuple[float, float]] = demo_profile,
               estimator_parameters: Mapping[str, Any] | None = None,
               vehicle_parameters: Mapping[str, Any] | None = None, start_time: float = 0.0) -> CosimResult:
    """Run VehicleSensors -> OdoCompass (Gauss-Seidel, fixed step) from ``start_time`` to ``stop_time``."""
    with Slave(vehicle_fmu, "vehicle") as veh, Slave(estimator_fmu, "estimator") as est:
        master = Master({"vehicle": veh, "estimator": est},
                        [("vehicle", a, "estimator", b) for a, b in VEHICLE_TO_ESTIMATOR])

        def external(t):
            steer, speed = profile(t)
            return {"vehicle": {"steering_angle": steer, "speed": speed}}

        record = [("vehicle", v) for v in ("true_heading", "x", "y", "true_speed", "steering_angle", "speed")]
        record += [("estimator", v) for v in ESTIMATOR_OUTPUTS]
        rec = master.run(start_time, stop_time, step, external, record,
                         {"vehicle": vehicle_parameters or {}, "estimator": estimator_parameters or {}})
        if master.discarded["vehicle"]:
            raise RuntimeError(f"the vehicle FMU discarded {master.discarded['vehicle']} steps: {veh.messages[-3:]}")
        end = est.time
        messages = [("vehicle", *m) for m in veh.messages] + [("estimator", *m) for m in est.messages]
    series = {"true_heading": rec["vehicle.true_heading"], "true_x": rec["vehicle.x"], "true_y": rec["vehicle.y"],
              "true_speed": rec["vehicle.true_speed"], "steering_angle": rec["vehicle.steering_angle"],
              "speed_command": rec["vehicle.speed"], **{v: rec[f"estimator.{v}"] for v in ESTIMATOR_OUTPUTS}}
    return CosimResult(rec["time"], series["true_heading"], series["heading"], series,
                       master.discarded["estimator"], messages, float(end))


# ----------------------------------------------------------------------------------------------
# The SSP variant (fmpy.ssp.simulate_ssp: fixed-step Jacobi)
# ----------------------------------------------------------------------------------------------
def run_ssp(ssp_path: str | Path, stop_time: float = 600.0, step: float = 0.1,
            profile: Callable[[float], tuple[float, float]] = demo_profile) -> dict[str, np.ndarray]:
    """Simulate the system of ``fmu.ssp.write_ssp`` with fmpy; returns its connector time series."""
    from fmpy.ssp.simulation import simulate_ssp

    from .ssp import parameter_set

    rows = simulate_ssp(str(ssp_path), start_time=0.0, stop_time=stop_time, step_size=step,
                        parameter_set=parameter_set(ssp_path),
                        input={"steering_angle": lambda t: profile(t)[0], "speed": lambda t: profile(t)[1]})
    return {name: np.asarray(rows[name]) for name in rows.dtype.names}


# ----------------------------------------------------------------------------------------------
# For `odocompass demo`
# ----------------------------------------------------------------------------------------------
def plot_headings(result: CosimResult, path: str | Path, title: str = "OdoCompass FMU in a vehicle co-simulation",
                  ssp: Mapping[str, np.ndarray] | None = None) -> Path:
    from identification.plots import pyplot, save_figure

    plt = pyplot()

    fig, axes = plt.subplots(2, 1, figsize=(10, 7), sharex=True, gridspec_kw={"height_ratios": [2, 1]})
    t = result.time
    truth = np.unwrap(result.true_heading)  # continuous, so a heading through south draws no 360° jumps
    axes[0].plot(t, np.degrees(truth), "k-", lw=1.6, label="true heading (vehicle FMU)")
    axes[0].plot(t, np.degrees(truth + wrap(result.heading - result.true_heading)), "C0-", lw=1.0,
                 label="estimated heading (OdoCompass FMU)")
    axes[0].plot(t, np.degrees(truth + wrap(result.series["compass_heading"] - result.true_heading)), "C1.", ms=1.0,
                 alpha=0.4, label="compass heading")
    axes[0].set_ylabel("heading (deg, clockwise from north, unwrapped)")
    axes[0].legend(loc="upper right", fontsize=8)
    axes[0].set_title(title)
    axes[1].plot(t, result.heading_error_deg(), "C0-", lw=0.8, label="estimate - truth (master in fmu/cosim.py)")
    if ssp is not None and "estimator.heading" in ssp:
        ts = ssp["time"]
        # Jacobi: the estimator sees the vehicle's previous-step outputs, one step of lag
        err = np.degrees(wrap(ssp["estimator.heading"][1:] - ssp["vehicle.true_heading"][:-1]))
        axes[1].plot(ts[1:], err, "C2-", lw=0.6, alpha=0.7, label="estimate - truth (SSP, fmpy simulate_ssp)")
    axes[1].set_ylabel("error (deg)")
    axes[1].set_xlabel("time (s)")
    axes[1].legend(loc="upper right", fontsize=8)
    lim = max(2.0, float(np.nanpercentile(np.abs(result.heading_error_deg()), 99.5)) * 1.3)
    axes[1].set_ylim(-lim, lim)
    axes[1].grid(alpha=0.3)
    return save_figure(fig, path)


def demo_cosimulation(out_dir: str | Path, estimator_fmu: str | Path | None = None,
                      vehicle_fmu: str | Path | None = None, params=None, stop_time: float = 600.0,
                      step: float = 0.1, with_ssp: bool = True, vehicle_parameters: Mapping[str, Any] | None = None,
                      fmu_dir: str | Path | None = None, true_params=None) -> dict[str, Any]:
    """Co-simulate VehicleSensors -> OdoCompass, plot estimated vs true heading into ``out_dir``.

    Builds the FMUs into ``fmu_dir`` (default: ``out_dir``) when paths are not given: the estimator
    with ``params`` as start values (e.g. an identified parameter file), the vehicle with
    ``true_params`` (default: ``params``) as its true parameters.  ``vehicle_parameters`` override
    the vehicle FMU's other parameters (seed, anomaly density, ...).  Returns a dict with the time
    series (``time``, ``true_heading``, ``heading``, ``series``), ``rmse_deg`` after the first
    minute, ``end_time``, ``discarded``, the plot path (``fmu_cosim_heading.png``) and, with
    ``with_ssp``, ``ssp_path``, ``ssp_end_time`` and ``ssp_rmse_deg``.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    fmu_dir = Path(fmu_dir) if fmu_dir else out_dir
    if estimator_fmu is None or vehicle_fmu is None:
        from . import build

        if estimator_fmu is None:
            estimator_fmu = build.build_estimator(fmu_dir / "OdoCompass.fmu", params)
        if vehicle_fmu is None:
            vehicle_fmu = build.build_vehicle(fmu_dir / "VehicleSensors.fmu", params if true_params is None else true_params)
    vp = {"anomaly_density_per_km2": 3.0, "transient_rate_per_s": 1.0 / 90.0, "seed": 1}
    vp.update(vehicle_parameters or {})
    result = cosimulate(estimator_fmu, vehicle_fmu, stop_time, step, vehicle_parameters=vp)
    summary: dict[str, Any] = {
        "time": result.time, "true_heading": result.true_heading, "heading": result.heading,
        "series": result.series, "rmse_deg": result.rmse_deg(), "end_time": result.end_time,
        "discarded": result.discarded, "estimator_fmu": str(estimator_fmu), "vehicle_fmu": str(vehicle_fmu),
    }
    ssp_rows = None
    if with_ssp:
        from .ssp import write_ssp

        ssp_path = write_ssp(out_dir / "VehicleOdoCompass.ssp", vehicle_fmu, estimator_fmu, stop_time=stop_time,
                             step=step, vehicle_parameters=vp)
        ssp_rows = run_ssp(ssp_path, stop_time, step)
        err = np.degrees(wrap(ssp_rows["estimator.heading"][1:] - ssp_rows["vehicle.true_heading"][:-1]))
        m = ssp_rows["time"][1:] >= 60.0
        summary.update(ssp_path=str(ssp_path), ssp_end_time=float(ssp_rows["time"][-1] + step),
                       ssp_rmse_deg=float(np.sqrt(np.mean(err[m] ** 2))))
    summary["plot"] = str(plot_headings(result, out_dir / "fmu_cosim_heading.png", ssp=ssp_rows))
    return summary
