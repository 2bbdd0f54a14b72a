"""VehicleSensors: a kinematic car with Ackerman steering and its dead-reckoning sensors (FMI 2.0 CS, pythonfmu).

Inputs: the road-wheel steering angle (rad, + = right) and the speed of the rear axle's centre
(m/s, + = forward), held constant over each communication step.  The car moves on the exact arc
of the kinematic bicycle model about the rear axle (dψ/ds = tan δ / B); the sensor axle's
centre travels ``AD`` (rear: s, front: s / cos δ), and the left/right wheel difference ΔD is
the one the seed's wheel model gives for that heading change (US 4,788,645 eq. 8 with T_R, or
eq. 14's Ackerman effective track T_E for front-axle sensors; ``identification.sensors.
differential_distance``), so an estimator given the true parameters integrates the true heading.

Sensors: ``identification/sensors.py`` (bundled unchanged as a private module) adds differential
wheel slip, counts pulses with the true distance per pulse and wraps them at counter_modulus,
and produces the 2-axis compass reading with the earth field's dip, body pitch and roll,
localized magnetic anomalies and transients, mounting rotation, hard-iron offsets and noise.

Outputs: the sensor readings (inputs of the OdoCompass FMU) and the truth: heading, position,
speed, yaw rate, distance.  Built by ``fmu/build.py`` (``build_vehicle``).
"""

from __future__ import annotations

import base64
import importlib.util
import json
import math
import pickle
import sys
import threading
from pathlib import Path

from pythonfmu import Boolean, Fmi2Causality, Fmi2Slave, Fmi2Variability, Integer, Real, String
from pythonfmu.default_experiment import DefaultExperiment
from pythonfmu.enums import Fmi2Initial, Fmi2Status

BUNDLE_DIR = "vehicle_bundle"
_LOAD_LOCK = threading.Lock()
PITCH_PER_ACCEL_DEG = 0.25  # body pitch (nose up) per m/s² of longitudinal acceleration (as identification.simulate)
ROLL_PER_ACCEL_DEG = 0.5    # body roll (outwards) per m/s² of lateral acceleration


def _private_module(name: str, path: Path):
    with _LOAD_LOCK:
        module = sys.modules.get(name)
        if module is None:
            spec = importlib.util.spec_from_file_location(name, path)
            module = importlib.util.module_from_spec(spec)
            sys.modules[name] = module
            try:
                spec.loader.exec_module(module)
            except BaseException:
                sys.modules.pop(name, None)
                raise
        return module


def _wrap(a):
    a = math.fmod(a + math.pi, 2.0 * math.pi)
    if a <= 0.0:
        a += 2.0 * math.pi
    return a - math.pi


class VehicleSensors(Fmi2Slave):
    author = "odocompass"
    description = ("Kinematic car with Ackerman steering (steering angle and speed in) and its wheel pulse "
                   "counters and magnetic compass (odocompass sensor error models)")
    version = "0.1.0"
    default_experiment = DefaultExperiment(start_time=0.0, step_size=0.1)
    log_categories = {
        "logStatusWarning": "Log messages with fmi2Warning status.",
        "logStatusDiscard": "Log messages with fmi2Discard status.",
        "logStatusError": "Log messages with fmi2Error status.",
        "logStatusFatal": "Log messages with fmi2Fatal status.",
        "logAll": "Log all messages.",
        "logBadInput": "Rejected inputs or steps (non-finite steering or speed, non-positive step).",
    }

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        res = Path(self.resources) if self.resources else Path(__file__).resolve().parent
        self._bundle = res / BUNDLE_DIR
        self._manifest = json.loads((self._bundle / "manifest.json").read_text())
        bid = self._manifest["bundle_id"]
        self._support = _private_module(f"_odocompass_fmi_support_{bid}", self._bundle / "fmi_support.py")
        self._exit_guard = self._support.guard_pythonfmu_exit(res)
        self._sensors_name = f"_odocompass_vehicle_sensors_{bid}"
        self._meta, self._real_starts = {}, {}
        self._p = {}
        self.steering_angle = 0.0
        self.speed = 0.0
        self._out = {"left_pulses": 0, "right_pulses": 0, "compass_x": 0.0, "compass_y": 0.0,
                     "compass_unreliable_area": False, "true_heading": 0.0, "x": 0.0, "y": 0.0,
                     "true_speed": 0.0, "yaw_rate": 0.0, "distance": 0.0}
        self._model = None
        self._kin = None  # kinematic state: x, y, heading (unwrapped), wheel distances, speed, time
        self._lock = None
        self._clamp_logged = False

        for spec in self._manifest["inputs"]:
            name = spec["name"]
            self._add(Real(name, causality=Fmi2Causality.input, variability=Fmi2Variability.continuous,
                           start=float(spec["start"]), description=spec["description"],
                           getter=lambda n=name: getattr(self, n), setter=lambda v, n=name: setattr(self, n, float(v))),
                      spec)
        for spec in self._manifest["outputs"]:
            name, kind = spec["name"], spec["type"]
            cls = {"Real": Real, "Integer": Integer, "Boolean": Boolean}[kind]
            self._add(cls(name, causality=Fmi2Causality.output, variability=Fmi2Variability.discrete,
                          description=spec["description"], getter=lambda n=name: self._out[n]), spec)
        for spec in self._manifest["parameters"]:
            name, kind = spec["name"], spec["type"]
            self._p[name] = spec["start"]
            cls = {"Real": Real, "Integer": Integer, "Boolean": Boolean, "String": String}[kind]
            start = {"Real": float, "Integer": int, "Boolean": bool, "String": str}[kind](spec["start"])
            self._add(cls(name, causality=Fmi2Causality.parameter, variability=Fmi2Variability.fixed,
                          initial=Fmi2Initial.exact, start=start, description=spec["description"],
                          getter=lambda n=name: self._p[n], setter=lambda v, n=name: self._set_param(n, v)), spec)

    def _add(self, var, spec):
        self.register_variable(var, nested=False)
        self._meta[var.name] = spec
        if spec.get("type", "Real") == "Real" and "start" in spec:
            self._real_starts[var.name] = float(spec["start"])

    def _set_param(self, name, value):
        kind = self._meta[name]["type"]
        self._p[name] = {"Real": float, "Integer": int, "Boolean": bool, "String": str}[kind](value)

    def to_xml(self, model_options=dict()):
        return self._support.decorate(super().to_xml(model_options), self._meta, self._real_starts)

    def _log(self, msg, status=Fmi2Status.ok, category="logAll"):
        try:
            # pythonfmu hands the text to the host's logger as its printf format: escape '%'
            self.log(str(msg).replace("%", "%%"), status, category)
        except Exception:  # pragma: no cover
            pass

    # -- getters/setters that never raise ---------------------------------------------------------
    def _safe(self, fn, vrs, default, where):
        out = []
        for vr in vrs:
            try:
                out.append(fn([vr])[0])
            except Exception as exc:
                self._log(f"{where}: {type(exc).__name__}: {exc}", Fmi2Status.error, "logStatusError")
                out.append(default)
        return out

    def get_real(self, vrs):
        try:
            return super().get_real(vrs)
        except Exception:
            return self._safe(super().get_real, vrs, float("nan"), "fmi2GetReal")

    def get_integer(self, vrs):
        try:
            return super().get_integer(vrs)
        except Exception:
            return self._safe(super().get_integer, vrs, 0, "fmi2GetInteger")

    def get_boolean(self, vrs):
        try:
            return super().get_boolean(vrs)
        except Exception:
            return self._safe(super().get_boolean, vrs, False, "fmi2GetBoolean")

    def get_string(self, vrs):
        try:
            return super().get_string(vrs)
        except Exception:
            return self._safe(super().get_string, vrs, "", "fmi2GetString")

    def _set_safe(self, fn, vrs, values, where):
        for vr, v in zip(vrs, values):
            try:
                fn([vr], [v])
            except Exception as exc:
                self._log(f"{where}: {type(exc).__name__}: {exc}", Fmi2Status.error, "logStatusError")

    def set_real(self, vrs, values):
        self._set_safe(super().set_real, vrs, values, "fmi2SetReal")

    def set_integer(self, vrs, values):
        self._set_safe(super().set_integer, vrs, values, "fmi2SetInteger")

    def set_boolean(self, vrs, values):
        self._set_safe(super().set_boolean, vrs, values, "fmi2SetBoolean")

    def set_string(self, vrs, values):
        self._set_safe(super().set_string, vrs, values, "fmi2SetString")

    # -- model --------------------------------------------------------------------------------------
    def _sensors(self):
        return _private_module(self._sensors_name, self._bundle / "sensors.py")

    def _make_model(self):
        sensors = self._sensors()
        p = self._p
        true_params = {k: p[k] for k in ("dpp_left", "dpp_right", "counter_modulus", "field_magnitude",
                                         "variation_deg", "rotation_deg", "X0", "Y0")}
        deviation = [float(p[f"deviation_deg_{i}"]) for i in range(36) if f"deviation_deg_{i}" in p]
        if len(deviation) == 36 and any(deviation):
            true_params["deviation_deg"] = deviation
        slip = None if p["slip"] else sensors.SlipModel(sigma_rel=0.0, white_m=0.0)
        self._model = sensors.SensorModel.from_params(
            true_params, seed=int(p["seed"]), compass_noise_ut=float(p["compass_noise_ut"]), slip=slip,
            anomaly_density_per_km2=float(p["anomaly_density_per_km2"]),
            transient_rate_per_s=float(p["transient_rate_per_s"]),
            counter_offsets=[int(p["counter_offset_left"]), int(p["counter_offset_right"])])
        self._kin = dict(x=float(p["initial_x"]), y=float(p["initial_y"]), heading=float(p["initial_heading"]),
                         dl=0.0, dr=0.0, speed=0.0, distance=0.0, time=0.0)

    def _sense(self, dt, pitch=0.0, roll=0.0):
        k = self._kin
        sample = self._model.step(dt, k["x"], k["y"], k["heading"], k["dl"], k["dr"], pitch, roll)
        o = self._out
        o["left_pulses"], o["right_pulses"] = int(sample.left_pulses), int(sample.right_pulses)
        o["compass_x"], o["compass_y"] = float(sample.compass_x), float(sample.compass_y)
        o["compass_unreliable_area"] = bool(sample.unreliable_area)
        o["true_heading"] = _wrap(k["heading"])
        o["x"], o["y"], o["true_speed"], o["distance"] = k["x"], k["y"], k["speed"], k["distance"]

    def _problems(self):
        p = self._p
        problems = []
        for key in ("B", "T_F", "T_R", "dpp_left", "dpp_right", "counter_modulus"):
            if not float(p[key]) > 0.0:
                problems.append(f"{key}={p[key]} must be positive")
        if not 0.0 <= float(p["P"]) < 1.0:
            problems.append(f"P={p['P']} outside [0, 1)")
        if p["sensor_axle"] not in ("front", "rear"):
            problems.append(f"sensor_axle={p['sensor_axle']!r} must be 'front' or 'rear'")
        return problems

    def exit_initialization_mode(self):
        try:
            problems = self._problems()
            if problems:
                self._refused = "parameters refused: " + "; ".join(problems)
                self._log(self._refused, Fmi2Status.error, "logStatusError")
                return
            self._refused = None
            self._make_model()
            self._sense(0.0)
        except Exception as exc:
            self._refused = f"initialization failed: {type(exc).__name__}: {exc}"
            self._log(self._refused, Fmi2Status.error, "logStatusError")

    def do_step(self, current_time, step_size):
        try:
            return self._do_step(current_time, step_size)
        except Exception as exc:
            self._log(f"fmi2DoStep at t={current_time!r}: {type(exc).__name__}: {exc}", Fmi2Status.error,
                      "logStatusError")
            return False

    def _do_step(self, t, h):
        if self._model is None:
            self._log(getattr(self, "_refused", None) or "not initialized", Fmi2Status.error, "logStatusError")
            return False
        delta, v = float(self.steering_angle), float(self.speed)
        if not (0.0 < h < math.inf) or not (math.isfinite(delta) and math.isfinite(v)):
            self._log(f"step refused at t={t!r}: h={h!r}, steering_angle={delta!r}, speed={v!r}",
                      Fmi2Status.discard, "logBadInput")
            return False
        sensors = self._sensors()
        p, k = self._p, self._kin
        B = float(p["B"])
        delta_max = self._delta_max(sensors)
        if abs(delta) > delta_max:
            if not self._clamp_logged:
                self._log(f"steering_angle {delta!r} rad at t={t!r} beyond the vehicle's lock ({delta_max:.4f} rad, "
                          "where the wheel model's curvature ends); clamped (logged once)", Fmi2Status.warning,
                          "logBadInput")
                self._clamp_logged = True
            delta = math.copysign(delta_max, delta)
        curv = math.tan(delta) / B  # dψ/ds of the rear axle's centre, 1/m
        s = v * h
        d_heading = curv * s
        h0 = k["heading"]
        h1 = h0 + d_heading
        if abs(d_heading) > 1e-12:
            k["x"] += (math.cos(h0) - math.cos(h1)) / curv
            k["y"] += (math.sin(h1) - math.sin(h0)) / curv
        else:
            k["x"] += s * math.sin(h0 + 0.5 * d_heading)
            k["y"] += s * math.cos(h0 + 0.5 * d_heading)
        front = p["sensor_axle"] == "front"
        AD = s / math.cos(delta) if front else s
        dD, _ = sensors.differential_distance(d_heading, AD, h, P=float(p["P"]), B=B, T_F=float(p["T_F"]),
                                              T_R=float(p["T_R"]), a=float(p["a"]), front=front)
        dD = float(dD)
        k["dl"] += AD + 0.5 * dD
        k["dr"] += AD - 0.5 * dD
        accel = (v - k["speed"]) / h
        k["heading"], k["speed"], k["distance"], k["time"] = h1, v, k["distance"] + abs(s), t + h
        pitch = math.radians(PITCH_PER_ACCEL_DEG) * accel
        roll = math.radians(ROLL_PER_ACCEL_DEG) * v * v * curv
        self._sense(h, pitch, roll)
        self._out["yaw_rate"] = d_heading / h
        return True

    def _delta_max(self, sensors):
        """Steering lock: 90 % of the largest ΔD/AD the seed's wheel model (eq. 14) covers, as the simulator."""
        if self._lock is None:
            p = self._p
            B, T_F, T_R, P = float(p["B"]), float(p["T_F"]), float(p["T_R"]), float(p["P"])
            c = 0.9 * sensors.max_curvature(B, T_F)
            kappa = min(c / T_R, c / float(sensors.effective_track(c, P, B, T_F)))
            self._lock = math.atan(kappa * B)
        return self._lock

    # -- state ----------------------------------------------------------------------------------------
    def _get_fmu_state(self):
        blob = pickle.dumps((self._model, dict(self._kin) if self._kin else None, dict(self._out), dict(self._p),
                             self.steering_angle, self.speed))
        return {"format": "odocompass-vehicle-state/1", "pickle": base64.b64encode(blob).decode("ascii")}

    def _set_fmu_state(self, state):
        try:
            self._sensors()  # the pickled classes live in the private sensors module
            model, kin, out, p, self.steering_angle, self.speed = pickle.loads(base64.b64decode(state["pickle"]))
            self._model, self._kin, self._out, self._p = model, kin, out, p
        except Exception as exc:
            self._log(f"fmi2SetFMUstate: {type(exc).__name__}: {exc}", Fmi2Status.error, "logStatusError")
