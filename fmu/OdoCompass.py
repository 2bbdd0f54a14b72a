"""OdoCompass: the odocompass heading estimator as an FMI 2.0 co-simulation slave (pythonfmu).

Build it with ``odocompass build-fmu`` (``fmu/build.py``), not with ``pythonfmu build`` alone:
the build bundles a private copy of ``jaxmodel`` and the engine into
``resources/odocompass_bundle/`` and writes ``manifest.json`` there (variables, units,
descriptions and start values, all taken from ``jaxmodel`` -- ``PARAMETER_TABLE``,
``Inputs``, ``Outputs``).

Behaviour (docs/fmu.md has the full story):

* Every ``fmi2DoStep(t, h)`` processes ONE sensor sample: the input values present at the call,
  time-stamped ``t + h`` (the sample taken at the end of the communication interval), through
  ``jaxmodel.run_from`` as JAX traces it -- compiled to C at build time, lowered to Python at
  initialization, or jitted by XLA (parameter ``engine``, see ``engine.py``).  The sample set
  during initialization mode is processed at the start time in ``fmi2ExitInitializationMode``,
  so the outputs are valid right after initialization.
* Bad input (non-finite compass, implausible pulse counters, a zero/negative/non-finite step,
  time not advancing) is logged under a category and answered with fmi2Discard (pythonfmu
  0.7.0's ``doStep`` can return only OK or Discard): the sample is not consumed and the
  estimator state is left exactly as it was.  A counter jump that persists (a counter reset)
  is accepted on the second consecutive sample the way ``jaxmodel`` handles it (distance
  dropped, counters re-synchronised), so a stream never stays stuck.
* Invalid parameters are refused at initialization with a message naming them (category
  ``logBadParameter``, status fmi2Error); the instance then discards every step and its
  outputs are NaN.
* No Python exception ever leaves a callback: pythonfmu turns one into fmi2Fatal and the
  instance is then unusable (a second call can crash the host).
* Full state (estimator state vector, outputs, inputs, parameters; floats as ``float.hex``)
  via ``_get_fmu_state``/``_set_fmu_state``, serializable as JSON.
"""

from __future__ import annotations

import importlib.util
import json
import sys
import threading
import time
import weakref
from pathlib import Path

from pythonfmu import Boolean, Fmi2Causality, Fmi2Slave, Fmi2Variability, Integer, Real, String
from pythonfmu.enums import Fmi2Initial, Fmi2Status

BUNDLE_DIR = "odocompass_bundle"
_LOAD_LOCK = threading.Lock()
_LIVE = weakref.WeakSet()  # instances not yet terminated in this process
_NAN = float("nan")


def _private_module(name: str, path: Path):
    """Import a bundled file under a private module name, once per process."""
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


class OdoCompass(Fmi2Slave):
    author = "odocompass"
    description = ("Dead-reckoning heading estimator (differential odometer + magnetic compass, "
                   "US 4,788,645 / US 4,734,863): the odocompass jaxmodel step as an FMI 2.0 co-simulation FMU")
    version = "0.1.0"

    # ------------------------------------------------------------------------------------------
    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        res = Path(self.resources) if self.resources else Path(__file__).resolve().parent
        self._bundle = res / BUNDLE_DIR
        self._manifest = json.loads((self._bundle / "manifest.json").read_text())
        bid = self._manifest["bundle_id"]
        self._support = _private_module(f"_odocompass_fmi_support_{bid}", self._bundle / "fmi_support.py")
        self._exit_guard = self._support.guard_pythonfmu_exit(res)
        self._md = _private_module(f"_odocompass_model_description_{bid}", self._bundle / "model_description.py")
        self._engine_module = None
        self._stepper = None
        self._prepared_key = None
        self._phase = "instantiated"  # -> "initialization" -> "stepping"
        self._refused = None  # message when parameters were refused
        self._t_start = 0.0
        self._t_last = -float("inf")
        self._strikes = 0  # consecutive samples refused for implausible counters
        self._discarded = 0
        stopped = self._manifest["stopped_counter"]
        self._stopped = self._support.StoppedCounterWatch(stopped["min_s"], stopped["other_pulses"])
        self._timing: dict[str, float] = {"instantiated": time.perf_counter()}
        with _LOAD_LOCK:
            _LIVE.add(self)

        m = self._manifest
        self._x = [0.0] * len(m["sample_fields"])  # one jaxmodel.Inputs sample; slot 0 is time_s
        self._o = [_NAN] * len(m["outputs"])
        self._o_stale = True  # outputs read before initialization: from the start values, as the native FMU
        self._s = None  # flat estimator state (list of floats) once prepared
        self._params = {}  # JSON-style parameter values (jaxmodel.make_params input)
        self._config = {}
        self._meta = {}
        self._real_in, self._int_in, self._bool_in, self._real_out = {}, {}, {}, {}
        self._real_par, self._string_par, self._bool_par = {}, {}, {}
        self._out_slot = {o.get("field", o["name"]): o["slot"] for o in m["outputs"]}
        f = m["sample_fields"]
        self._i_cx, self._i_cy = f.index("compass_x"), f.index("compass_y")
        self._i_left, self._i_right = f.index("left_pulses"), f.index("right_pulses")
        self._i_map, self._i_map_valid = f.index("map_heading"), f.index("map_valid")
        self._i_fe, self._i_fn, self._i_fix_valid = f.index("fix_east_m"), f.index("fix_north_m"), f.index("fix_valid")

        self._bool_out = {}
        # one canonical order (value reference = position), shared with the native FMU
        for spec in self._md.variables(m):
            name, kind, group = spec["name"], spec["type"], spec["group"]
            if group == "input":
                slot = spec["slot"]
                self._x[slot] = float(spec["start"])
                common = dict(causality=Fmi2Causality.input, description=spec["description"])
                if kind == "Integer":
                    var = Integer(name, variability=Fmi2Variability.discrete, start=int(spec["start"]), **common)
                    self._register(var, self._int_in, slot)
                elif kind == "Boolean":
                    var = Boolean(name, variability=Fmi2Variability.discrete, start=bool(spec["start"]), **common)
                    self._register(var, self._bool_in, slot)
                else:
                    var = Real(name, variability=Fmi2Variability.continuous, start=float(spec["start"]), **common)
                    self._register(var, self._real_in, slot)
            elif group == "output":
                cls, table = (Boolean, self._bool_out) if kind == "Boolean" else (Real, self._real_out)
                var = cls(name, causality=Fmi2Causality.output, variability=Fmi2Variability.discrete,
                          description=spec["description"])
                self._register(var, table, spec["slot"])
            elif group == "discarded":
                var = Integer(name, causality=Fmi2Causality.output, variability=Fmi2Variability.discrete,
                              description=spec["description"])
                self._int_out_vr = self._register(var, None, None)
            elif group == "parameter":
                key, index = spec["key"], spec.get("index")
                if index is None:
                    self._params[key] = spec["start"]
                else:
                    self._params.setdefault(key, [0.0] * spec["size"])[index] = float(spec["start"])
                common = dict(causality=Fmi2Causality.parameter, variability=Fmi2Variability.fixed,
                              initial=Fmi2Initial.exact, description=spec["description"])
                if kind == "String":
                    self._register(String(name, start=str(spec["start"]), **common), self._string_par, key)
                elif kind == "Integer":
                    self._register(Integer(name, start=int(spec["start"]), **common), self._real_par, (key, index))
                else:
                    self._register(Real(name, start=float(spec["start"]), **common), self._real_par, (key, index))
            else:
                self._config[name] = spec["start"]
                common = dict(causality=Fmi2Causality.parameter, variability=Fmi2Variability.fixed,
                              initial=Fmi2Initial.exact, description=spec["description"])
                if kind == "Boolean":
                    self._register(Boolean(name, start=bool(spec["start"]), **common), self._bool_par, name)
                else:
                    self._register(String(name, start=str(spec["start"]), **common), self._string_par,
                                   ("config", name))
            self._meta[name] = spec

    def _register(self, var, table, slot):
        vr = len(self.vars)
        if table is not None:
            table[vr] = slot
        var.getter = lambda vr=vr: self._get_any(vr)
        var.setter = lambda value, vr=vr: self._set_any(vr, value)
        self.register_variable(var)
        return vr

    # ------------------------------------------------------------------------------------------
    def to_xml(self, model_options=dict()):
        """The model description from the generator shared with the native FMU (model_description.py)."""
        from pythonfmu import __version__ as pythonfmu_version

        base = super().to_xml(model_options)  # pythonfmu's CoSimulation options, GUID and date
        cs = dict(base.find("CoSimulation").attrib)
        identifier = cs.pop("modelIdentifier")
        return self._md.to_xml(self._manifest, guid=base.get("guid"), model_identifier=identifier,
                               generation_tool=f"PythonFMU {pythonfmu_version} (odocompass build-fmu)",
                               cs_options=cs, description=type(self).description, author=type(self).author,
                               version=type(self).version, date=base.get("generationDateAndTime"))

    # -- logging --------------------------------------------------------------------------------
    def _log(self, msg, status=Fmi2Status.ok, category="logAll"):
        try:
            # pythonfmu hands the text to the host's logger as its printf format: escape '%'
            self.log(str(msg).replace("%", "%%"), status, category)
        except Exception:  # pragma: no cover - logging must never raise into the host
            pass

    def _log_exception(self, where, exc):
        self._log(f"{where}: unexpected {type(exc).__name__}: {exc}", Fmi2Status.error, "logStatusError")

    # -- value access (never raises) -------------------------------------------------------------
    def _wrong_type(self, vr, kind, call):
        """True (and an error-status message) when ``vr`` is no variable of FMI type ``kind`` (Real, Integer, ...)."""
        var = self.vars.get(vr)
        if var is not None and type(var).__name__ == kind:
            return False
        what = "is no variable of this FMU" if var is None else f"({var.name}) is a {type(var).__name__}"
        self._log(f"{call}: value reference {vr} {what}; refused", Fmi2Status.error, "logStatusError")
        return True

    def _get_any(self, vr):
        if vr in self._real_out:
            if self._o_stale:
                self._refresh_outputs()
            return self._o[self._real_out[vr]]
        if vr in self._bool_out:
            if self._o_stale:
                self._refresh_outputs()
            return self._o[self._bool_out[vr]] == 1.0
        if vr in self._real_in:
            return self._x[self._real_in[vr]]
        if vr in self._int_in:
            return int(self._x[self._int_in[vr]])
        if vr in self._bool_in:
            return self._x[self._bool_in[vr]] > 0.5
        if vr in self._real_par:
            key, index = self._real_par[vr]
            v = self._params[key]
            return float(v if index is None else v[index])
        if vr in self._string_par:
            ref = self._string_par[vr]
            return str(self._config[ref[1]] if isinstance(ref, tuple) else self._params[ref])
        if vr in self._bool_par:
            return bool(self._config[self._bool_par[vr]])
        if vr == self._int_out_vr:
            return self._discarded
        return None

    def _set_any(self, vr, value):
        if vr in self._real_in:
            self._x[self._real_in[vr]] = float(value)
        elif vr in self._int_in:
            self._x[self._int_in[vr]] = float(value)
        elif vr in self._bool_in:
            self._x[self._bool_in[vr]] = 1.0 if value else 0.0
        elif vr in self._real_par or vr in self._string_par or vr in self._bool_par:
            if self._phase == "stepping":
                # an fmi2Error; pythonfmu 0.7.0 answers OK or (for any exception) Fatal, after which it
                # frees the slave object: an error-status message is the most it allows
                self._log(f"parameter {self.vars[vr].name} is fixed after initialization; set refused",
                          Fmi2Status.error, "logBadParameter")
                return
            if vr in self._real_par:
                key, index = self._real_par[vr]
                if index is None:
                    self._params[key] = float(value)
                else:
                    self._params[key][index] = float(value)
            elif vr in self._string_par:
                ref = self._string_par[vr]
                if isinstance(ref, tuple):
                    self._config[ref[1]] = str(value)
                else:
                    self._params[ref] = str(value)
            else:
                self._config[self._bool_par[vr]] = bool(value)
            self._stepper = None
        else:
            name = self.vars[vr].name if vr in self.vars else "unknown"
            self._log(f"variable {vr} ({name}) cannot be set: set refused", Fmi2Status.error, "logBadParameter")
            return
        if self._phase != "stepping":  # outputs before stepping follow the values set
            self._o_stale = True

    def get_real(self, vrs):
        if self._o_stale:
            self._refresh_outputs()
        o, m = self._o, self._real_out
        try:
            return [o[m[vr]] for vr in vrs]
        except KeyError:
            pass
        except Exception as exc:
            self._log_exception("fmi2GetReal", exc)
            return [_NAN] * len(vrs)
        out = []
        for vr in vrs:
            try:
                v = None if self._wrong_type(vr, "Real", "fmi2GetReal") else self._get_any(vr)
                out.append(float(v) if isinstance(v, (int, float)) else _NAN)
            except Exception as exc:
                self._log_exception("fmi2GetReal", exc)
                out.append(_NAN)
        return out

    def set_real(self, vrs, values):
        m, x = self._real_in, self._x
        for vr, value in zip(vrs, values):
            slot = m.get(vr)
            if slot is not None:
                x[slot] = value
            elif not self._wrong_type(vr, "Real", "fmi2SetReal"):
                try:
                    self._set_any(vr, value)
                except Exception as exc:
                    self._log_exception("fmi2SetReal", exc)
        if self._phase != "stepping":  # outputs before stepping follow the values set
            self._o_stale = True

    def set_integer(self, vrs, values):
        m, x = self._int_in, self._x
        for vr, value in zip(vrs, values):
            slot = m.get(vr)
            if slot is not None:
                x[slot] = float(value)
            elif not self._wrong_type(vr, "Integer", "fmi2SetInteger"):
                try:
                    self._set_any(vr, value)
                except Exception as exc:
                    self._log_exception("fmi2SetInteger", exc)
        if self._phase != "stepping":  # outputs before stepping follow the values set
            self._o_stale = True

    def get_integer(self, vrs):
        out = []
        for vr in vrs:
            try:
                v = None if self._wrong_type(vr, "Integer", "fmi2GetInteger") else self._get_any(vr)
                out.append(int(v) if isinstance(v, (int, float, bool)) and v == v else 0)
            except Exception as exc:
                self._log_exception("fmi2GetInteger", exc)
                out.append(0)
        return out

    def set_boolean(self, vrs, values):
        for vr, value in zip(vrs, values):
            try:
                if not self._wrong_type(vr, "Boolean", "fmi2SetBoolean"):
                    self._set_any(vr, value)
            except Exception as exc:
                self._log_exception("fmi2SetBoolean", exc)

    def get_boolean(self, vrs):
        out = []
        for vr in vrs:
            try:
                out.append(not self._wrong_type(vr, "Boolean", "fmi2GetBoolean") and bool(self._get_any(vr)))
            except Exception as exc:
                self._log_exception("fmi2GetBoolean", exc)
                out.append(False)
        return out

    def set_string(self, vrs, values):
        for vr, value in zip(vrs, values):
            try:
                if not self._wrong_type(vr, "String", "fmi2SetString"):
                    self._set_any(vr, value)
            except Exception as exc:
                self._log_exception("fmi2SetString", exc)

    def get_string(self, vrs):
        out = []
        for vr in vrs:
            try:
                v = None if self._wrong_type(vr, "String", "fmi2GetString") else self._get_any(vr)
                out.append("" if v is None else str(v))
            except Exception as exc:
                self._log_exception("fmi2GetString", exc)
                out.append("")
        return out

    # -- engine ---------------------------------------------------------------------------------
    def _engine(self):
        if self._engine_module is None:
            bid = self._manifest["bundle_id"]
            mod = _private_module(f"_odocompass_engine_{bid}", self._bundle / "engine.py")
            self._engine_module = mod
        return self._engine_module.get_engine(self._bundle, self._manifest["bundle_id"])

    def _config_for_engine(self):
        c = self._config
        return {"mode": c.get("mode"), "refine_a": c.get("refine_a"), "calibration": c.get("calibration"),
                "track": c.get("track")}

    def _prepare(self):
        """Stepper for the current parameters (None, with self._refused set, when they are refused)."""
        key = json.dumps([self._params, self._config], sort_keys=True, default=str)
        if self._stepper is not None and key == self._prepared_key:
            return self._stepper
        self._stepper = None
        engine = self._engine()
        t0 = time.perf_counter()
        try:
            stepper = engine.prepare(dict(self._params), self._config_for_engine(), str(self._config.get("engine")),
                                     native_dir=self._bundle, native=self._manifest.get("native", []))
        except self._engine_module.ConfigurationError as exc:
            self._refused = f"parameters refused: {exc}"
            self._log(self._refused, Fmi2Status.error, "logBadParameter")
            return None
        self._refused = None
        self._stepper = stepper
        self._prepared_key = key
        self._timing["prepare_s"] = time.perf_counter() - t0
        names = engine.layout["state"]
        self._i_started = names.index("started")
        self._i_last_left = names.index("last_left")
        self._i_last_right = names.index("last_right")
        self._i_odo_valid = self._out_slot["odometer_valid"]
        self._log(f"engine {stepper.kind} ready in {self._timing['prepare_s']:.3f} s"
                  + (f" ({stepper.note})" if stepper.note else ""), Fmi2Status.ok, "logEngine")
        return stepper

    def _first_sample(self):
        """Outputs of the initial sample (time = start time) from the initial state: (state, outputs)."""
        stepper = self._prepare()
        if stepper is None:
            return None, [_NAN] * len(self._o)
        x = list(self._x)
        x[0] = self._t_start
        return stepper.step(list(stepper.s0), x)

    def _refresh_outputs(self):
        self._o_stale = False
        try:
            _, self._o = self._first_sample()
        except Exception as exc:
            self._log_exception("initial outputs", exc)
            self._o = [_NAN] * len(self._o)

    # -- FMI life cycle ---------------------------------------------------------------------------
    def setup_experiment(self, start_time, stop_time=None, tolerance=None):
        try:
            self._t_start = float(start_time)
        except Exception as exc:
            self._log_exception("fmi2SetupExperiment", exc)

    def enter_initialization_mode(self):
        self._phase = "initialization"
        self._o_stale = True

    def exit_initialization_mode(self):
        try:
            self._o_stale = False
            s, o = self._first_sample()
            self._phase = "stepping"
            self._o = o
            self._s = s
            self._t_last = self._t_start
            self._strikes = 0
            self._stopped.restore(None)
            if s is not None:
                cx, cy = self._x[self._i_cx], self._x[self._i_cy]
                if not (cx - cx == 0.0 and cy - cy == 0.0):
                    self._log(f"initial sample: non-finite compass reading (compass_x={cx!r}, compass_y={cy!r}); "
                              "the estimator skips it", Fmi2Status.warning, "logBadInput")
            self._timing["initialized"] = time.perf_counter()
        except Exception as exc:
            self._phase = "stepping"
            self._refused = f"initialization failed: {type(exc).__name__}: {exc}"
            self._log(self._refused, Fmi2Status.error, "logStatusError")
            self._o = [_NAN] * len(self._o)

    def terminate(self):
        try:
            with _LOAD_LOCK:
                _LIVE.discard(self)
                last = len(_LIVE) == 0
            if last and self._engine_module is not None:
                self._engine_module.release_for_c_host()
        except Exception as exc:
            self._log_exception("fmi2Terminate", exc)

    # -- stepping -------------------------------------------------------------------------------
    def do_step(self, current_time, step_size):
        try:
            return self._do_step(current_time, step_size)
        except Exception as exc:  # never let an exception reach pythonfmu (it would be fmi2Fatal)
            self._log_exception(f"fmi2DoStep at t={current_time!r}", exc)
            return False

    def _do_step(self, t, h):
        if self._s is None:
            if self._refused is None:
                self._refused = "fmi2DoStep before initialization"
            self._log(f"step refused: {self._refused}", Fmi2Status.error, "logBadParameter")
            return False
        if not (0.0 < h < float("inf")):
            return self._refuse(f"communication step size h={h!r} at t={t!r} s: must be positive and finite",
                                t + h, "logBadStep")
        t_sample = t + h
        if not (t_sample > self._t_last) or t_sample != t_sample:
            return self._refuse(f"sample time t+h={t_sample!r} s does not advance past the last sample "
                                f"({self._t_last!r} s)", t_sample, "logBadStep")
        x = self._x
        x[0] = t_sample
        problem = None
        cx, cy = x[self._i_cx], x[self._i_cy]
        if not (cx - cx == 0.0 and cy - cy == 0.0):
            problem = f"non-finite compass reading (compass_x={cx!r}, compass_y={cy!r})"
        elif x[self._i_map_valid] > 0.5 or x[self._i_fix_valid] > 0.5:
            mh, fe, fn = x[self._i_map], x[self._i_fe], x[self._i_fn]
            if (x[self._i_map_valid] > 0.5 and not mh - mh == 0.0) or \
                    (x[self._i_fix_valid] > 0.5 and not fe - fe + fn - fn == 0.0):
                problem = (f"non-finite map heading or position fix flagged valid (map_heading={mh!r}, "
                           f"fix_east_m={fe!r}, fix_north_m={fn!r})")
        discard = bool(self._config.get("discard_bad_samples", True))
        if problem is not None and discard:
            return self._refuse(problem, t_sample)
        s_new, o = self._stepper.step(self._s, x)
        if o[self._i_odo_valid] == 0.0 and self._s[self._i_started] > 0.5:
            # jaxmodel's own plausibility check refused the counters (a jump beyond max_speed)
            counters = self._counter_message(t_sample)
            if self._strikes == 0 and problem is None:
                self._strikes = 1
                if discard:
                    return self._refuse(counters, t_sample)
                problem = counters
            else:
                self._strikes = 0
                self._log(f"{counters}, again: accepted as a counter reset at t={t_sample!r} s (that sample's "
                          "distance dropped, counters re-synchronised)", Fmi2Status.warning, "logBadInput")
        else:
            self._strikes = 0
        if problem is not None:
            self._discarded += 1
            self._log(f"{problem} at t={t_sample!r} s: passed to the estimator, which skips what is unusable "
                      "(discard_bad_samples=false)", Fmi2Status.warning, "logBadInput")
        if self._s[self._i_started] > 0.5:
            for level, text in self._stopped.update(self._t_last, t_sample, self._increments()):
                self._log(text, Fmi2Status.warning if level == "warning" else Fmi2Status.ok, "logBadInput")
        self._s = s_new
        self._o = o
        self._t_last = t_sample
        if "first_step" not in self._timing:
            self._timing["first_step"] = time.perf_counter()
        return True

    def _refuse(self, problem, t_sample, category="logBadInput"):
        """Skip a bad sample: state and outputs unchanged, counted, logged as a warning.  pythonfmu's
        doStep can answer only OK or Discard, and Discard reports "terminated" for good, so a skipped
        sample answers OK (the native FMU answers fmi2Warning): conformant masters go on."""
        self._discarded += 1
        self._log(f"{problem} at t={t_sample!r} s: sample skipped, estimator state unchanged "
                  f"(discarded_samples={self._discarded})", Fmi2Status.warning, category)
        return True

    def _increments(self):
        """(left, right) pulses of the sample in ``_x`` since the state's last counts, wraps decoded (as jaxmodel)."""
        mod = float(self._params.get("counter_modulus", 65536.0))
        out = []
        for slot, i_last in ((self._i_left, self._i_last_left), (self._i_right, self._i_last_right)):
            d = self._x[slot] - self._s[i_last]
            out.append(d - mod * round(d / mod) if d - d == 0.0 else _NAN)
        return out

    def _counter_message(self, t_sample):
        parts = [f"{name} {d:+.0f}" for name, d in zip(("left", "right"), self._increments())]
        return (f"implausible pulse counter jump ({', '.join(parts)} counts in {t_sample - self._t_last:.6g} s, "
                f"beyond max_speed={self._params.get('max_speed')} m/s)")

    # -- FMU state ------------------------------------------------------------------------------
    def _get_fmu_state(self):
        return self._support.format_state(
            bundle_id=self._manifest["bundle_id"], phase=self._phase, params=self._params, config=self._config,
            t_start=self._t_start, t_last=self._t_last, s=self._s, o=self._o, x=self._x, strikes=self._strikes,
            discarded=self._discarded, stopped=self._stopped.to_json(), refused=self._refused)

    def _set_fmu_state(self, state):
        own = self._get_fmu_state()
        try:
            self._apply_state(state)
        except (KeyError, TypeError, ValueError) as exc:  # a damaged or foreign state: the instance keeps its own
            self._apply_state(own)
            self._log(f"fmi2SetFMUstate: refused, the instance is unchanged: {exc}", Fmi2Status.error,
                      "logStatusError")
        except Exception as exc:
            self._log_exception("fmi2SetFMUstate", exc)

    def _apply_state(self, state):
        f = self._support.parse_state(state, param_keys=self._params, n_inputs=len(self._x), n_outputs=len(self._o))
        self._params, self._config, self._phase = f["params"], f["config"], f["phase"]
        self._t_start, self._t_last, self._o, self._x = f["t_start"], f["t_last"], f["o"], f["x"]
        self._strikes, self._discarded, self._refused = f["strikes"], f["discarded"], f["refused"]
        self._stopped.restore(f["stopped"])
        self._o_stale = False
        self._s = None
        if f["s"] is not None and self._prepare() is not None:
            n = len(self._engine().layout["state"])
            if len(f["s"]) != n:
                raise ValueError(f"the state's 's' holds {len(f['s'])} values, this FMU {n}")
            self._s = f["s"]
