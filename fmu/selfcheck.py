"""Behavioural checks of a built OdoCompass FMU through fmpy: ``python -m fmu.selfcheck FMU [--engine E]``.

Each check steps the FMU with the drive of ``fmu.build.check_drive`` (or a given one) and returns
a JSON-ready dict; ``main`` prints them and exits non-zero if one fails.  The tests run this in a
subprocess that never imports ``jaxmodel``, so the FMU must work from its own bundle.

* ``save_restore``: getFMUstate mid-drive, run on, setFMUstate, repeat the inputs: outputs
  bit-identical; the serialized state restored into a second, freshly initialized instance gives
  the same bits; a state is plain JSON with floats as ``float.hex``.
* ``reset``: fmi2Reset then a new initialization reproduces a fresh instance bit for bit.
* ``two_instances``: two instances stepped interleaved with different drives each equal their solo runs.
* ``bad_inputs``: NaN/inf compass, a counter jumping backwards and forwards, a zero, negative and
  NaN step, time not advancing: each skipped (counted in ``discarded_samples``) with a categorised
  warning, answered so that the run goes on (fmi2Warning native, fmi2OK pythonfmu; never Discard,
  which ends a run), and the run then continues exactly as if the bad sample had never been sent
  (state unharmed); a persistent counter jump (a reset) is accepted on the second sample; with
  ``discard_bad_samples=false`` a NaN compass is stepped with a warning.
* ``bad_parameters``: invalid parameters are refused at initialization with a message naming
  them: fmi2Error from exitInitializationMode (native); pythonfmu cannot answer fmi2Error, so
  there the message has error status, every step answers fmi2Discard and outputs are NaN.
* ``access``: setting a fixed parameter after initialization or an unknown value reference is
  refused: fmi2Error (native), an error-status message (pythonfmu).
* ``stopped_counter``: a wheel counter that stops for 2 s while the other counts on is reported once
  (a logBadInput warning naming it) and its end once; a drive without the fault reports nothing.

Works on both FMUs (``build-fmu`` and ``build-fmu --native``).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from .cosim import INPUT_NAMES, Slave, _sample

OUTS = ("heading", "wheel_heading", "compass_heading", "x", "y", "speed", "a_current", "heading_reliability",
        "heading_bound", "dpp_ratio", "distance")


def _drive(n: int | None = None, clean: bool = True) -> dict[str, np.ndarray]:
    from .build import check_drive

    d = check_drive()
    if clean:  # no NaN compass, no counter glitch
        d["compass_x"] = np.where(np.isfinite(d["compass_x"]), d["compass_x"], 20.0)
        d["right_pulses"] = d["right_pulses"].copy()
        d["right_pulses"][900] = d["right_pulses"][899]  # check_drive() has 1500 samples
    if n is not None:
        d = {k: v[:n] for k, v in d.items()}
    return d


class _Run:
    """One instance stepping a drive sample by sample."""

    def __init__(self, fmu: str, name: str, drive: Mapping[str, np.ndarray], params: Mapping[str, Any] | None = None):
        self.s = Slave(fmu, name)
        self.d = drive
        self.names = [n for n in INPUT_NAMES if n in drive]
        self.vrs = [self.s.vr[o] for o in OUTS]
        self.params = params
        self.k = 0

    def init(self):
        self.s.initialize(float(self.d["time_s"][0]), self.params, _sample(self.d, 0, self.names))
        self.k = 0
        return self.s.fmu.getReal(self.vrs)

    def step(self, k: int | None = None, override: Mapping[str, Any] | None = None, t=None, h=None):
        k = self.k + 1 if k is None else k
        sample = _sample(self.d, k, self.names)
        if override:
            sample.update(override)
        self.s.set(sample)
        t = float(self.d["time_s"][k - 1]) if t is None else t
        h = float(self.d["time_s"][k] - self.d["time_s"][k - 1]) if h is None else h
        ok = self.s.step(t, h)
        if ok:
            self.k = k
        return ok, self.s.fmu.getReal(self.vrs)

    def run_to(self, k_end: int) -> list[list[float]]:
        out = []
        while self.k < k_end:
            ok, o = self.step()
            if not ok:
                raise RuntimeError(f"unexpected discard at sample {self.k + 1}: {self.s.messages[-2:]}")
            out.append(o)
        return out

    def close(self):
        self.s.close()


def _same_bits(a, b) -> bool:
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    return a.shape == b.shape and a.tobytes() == b.tobytes()


def _state_vector(slave: Slave, blob: bytes) -> list:
    """The estimator state inside a serialized FMU state: the pythonfmu FMU's JSON (floats as
    float.hex), or the native FMU's plain struct (layout of odocompass_fmi2.c's odc_saved)."""
    try:
        return json.loads(blob.decode("utf-8"))["s"]
    except (UnicodeDecodeError, ValueError):
        pass
    info = json.loads((Path(slave.unzip_dir) / "documentation" / "build.json").read_text())
    n_param, n_state = info["n_param"], len(info["state"])
    cur = int(np.frombuffer(blob, dtype=np.int32, count=1, offset=80)[0])
    s = np.frombuffer(blob, dtype=np.float64, count=n_state, offset=112 + 8 * n_param + 8 * n_state * cur)
    return [float(x).hex() for x in s]


def _json_state(blob: bytes):
    """True for a JSON state with every estimator float as float.hex (pythonfmu FMU), None for a
    binary one (native FMU)."""
    try:
        decoded = json.loads(blob.decode("utf-8"))
    except (UnicodeDecodeError, ValueError):
        return None
    return isinstance(decoded, dict) and all(
        isinstance(x, str) and (x.startswith(("0x", "-0x")) or x in ("nan", "inf", "-inf")) for x in decoded["s"])


def check_save_restore(fmu: str, params=None) -> dict[str, Any]:
    d = _drive(700)
    r = _Run(fmu, "a", d, params)
    r.init()
    r.run_to(300)
    state = r.s.fmu.getFMUstate()
    blob = r.s.fmu.serializeFMUstate(state)
    first = r.run_to(650)
    r.s.fmu.setFMUstate(state)
    r.k = 300
    again = r.run_to(650)
    r.s.fmu.freeFMUstate(state)
    # into a second instance, initialized with another first sample
    d2 = dict(d)
    q = _Run(fmu, "b", d2, params)
    q.init()
    q.run_to(5)
    st2 = q.s.fmu.deSerializeFMUstate(blob)
    q.s.fmu.setFMUstate(st2)
    q.s.fmu.freeFMUstate(st2)
    q.k = 300
    other = q.run_to(650)
    vec = _state_vector(r.s, bytes(blob))
    r.close()
    q.close()
    return {
        "restored_bit_identical": _same_bits(first, again),
        "deserialized_bit_identical": _same_bits(first, other),
        "state_bytes": len(blob),
        "state_size": len(vec),
        "state_is_json_with_hex_floats": _json_state(bytes(blob)),
    }


def check_reset(fmu: str, params=None) -> dict[str, Any]:
    d = _drive(300)
    r = _Run(fmu, "a", d, params)
    first0 = r.init()
    first = r.run_to(250)
    r.s.fmu.reset()
    second0 = r.init()
    second = r.run_to(250)
    r.close()
    return {"reset_bit_identical": _same_bits(first, second) and _same_bits(first0, second0)}


def check_two_instances(fmu: str, params=None) -> dict[str, Any]:
    d1 = _drive(400)
    d2 = _drive(400)
    rot = 0.7  # a different drive: the compass turned by 0.7 rad, the counters offset
    d2["compass_x"], d2["compass_y"] = (d1["compass_x"] * math.cos(rot) - d1["compass_y"] * math.sin(rot),
                                        d1["compass_x"] * math.sin(rot) + d1["compass_y"] * math.cos(rot))
    d2["left_pulses"] = np.mod(d1["left_pulses"] + 1234, 65536)
    solo = []
    for d in (d1, d2):
        r = _Run(fmu, "solo", d, params)
        r.init()
        solo.append(r.run_to(399))
        r.close()
    a, b = _Run(fmu, "A", d1, params), _Run(fmu, "B", d2, params)
    a.init()
    b.init()
    oa, ob = [], []
    for _ in range(399):
        oa.append(a.step()[1])
        ob.append(b.step()[1])
    a.close()
    b.close()
    return {"A_equals_solo": _same_bits(oa, solo[0]), "B_equals_solo": _same_bits(ob, solo[1]),
            "A_differs_from_B": not _same_bits(oa, ob)}


BAD_CASES = {
    "compass_nan": dict(override={"compass_x": float("nan")}),
    "compass_inf": dict(override={"compass_y": float("inf")}),
    "counter_backwards": dict(override_fn=lambda s: {"left_pulses": int(s["left_pulses"]) - 3000}),
    "counter_jump": dict(override_fn=lambda s: {"right_pulses": int(s["right_pulses"]) + 20000}),
    "step_zero": dict(h=0.0),
    "step_negative": dict(h=-0.1),
    "step_nan": dict(h=float("nan")),
    "time_backwards": dict(t_shift=-5.0),
}


def check_bad_inputs(fmu: str, params=None) -> dict[str, Any]:
    d = _drive(260)
    ref = _Run(fmu, "ref", d, params)
    ref.init()
    expected = ref.run_to(250)
    ref.close()
    results: dict[str, Any] = {}
    j = 120  # the bad sample replaces sample j+1 once, then the good samples continue
    for case, spec in BAD_CASES.items():
        r = _Run(fmu, case, d, params)
        r.init()
        before = r.run_to(j)
        state = r.s.fmu.getFMUstate()
        blob_before = r.s.fmu.serializeFMUstate(state)
        r.s.fmu.freeFMUstate(state)
        n_msgs = len(r.s.messages)
        sample = _sample(d, j + 1, r.names)
        override = dict(spec.get("override", {}))
        if "override_fn" in spec:
            override.update(spec["override_fn"](sample))
        t = float(d["time_s"][j]) + spec.get("t_shift", 0.0)
        n_before = r.s.get(["discarded_samples"])["discarded_samples"]
        ok, out_after_bad = r.step(j + 1, override, t=t, h=spec.get("h"))
        status = r.s.last_status
        counted = r.s.get(["discarded_samples"])["discarded_samples"] == n_before + 1
        state = r.s.fmu.getFMUstate()
        blob_after = r.s.fmu.serializeFMUstate(state)
        r.s.fmu.freeFMUstate(state)
        msgs = r.s.messages[n_msgs:]
        unchanged = _state_vector(r.s, bytes(blob_before)) == _state_vector(r.s, bytes(blob_after))
        rest = r.run_to(250)
        r.close()
        results[case] = {
            "skipped": not ok,
            "status": status,
            "counted": counted,
            "messages": [list(m) for m in msgs],
            "categorised": any(m[1] in ("logBadInput", "logBadStep") and m[0] == "WARNING" for m in msgs),
            "state_unchanged": unchanged,
            "outputs_held": _same_bits(out_after_bad, before[-1]),
            "continues_as_if_never_sent": _same_bits(before + rest, expected),
        }
    # a persistent jump (counter reset): discarded once, accepted on the second sample
    r = _Run(fmu, "reset_jump", d, params)
    r.init()
    r.run_to(j)
    statuses = []
    for k in range(j + 1, j + 6):
        s = _sample(d, k, r.names)
        ok, _ = r.step(k, {"left_pulses": (int(s["left_pulses"]) + 30000) % 65536,
                           "right_pulses": (int(s["right_pulses"]) + 30000) % 65536})
        statuses.append("STEPPED" if ok else "SKIPPED")
    results["counter_reset"] = {"statuses": statuses,
                                "messages": [list(m) for m in r.s.messages if m[0] != "OK"]}
    r.close()
    # discard_bad_samples = false: a NaN compass is passed to the estimator (it skips the compass)
    p2 = dict(params or {})
    p2["discard_bad_samples"] = False
    r = _Run(fmu, "lenient", d, p2)
    r.init()
    r.run_to(j)
    n_msgs = len(r.s.messages)
    st = r.s.fmu.getFMUstate()
    before = _state_vector(r.s, bytes(r.s.fmu.serializeFMUstate(st)))
    r.step(j + 1, {"compass_x": float("nan")})
    r.s.fmu.freeFMUstate(st)
    st = r.s.fmu.getFMUstate()
    after = _state_vector(r.s, bytes(r.s.fmu.serializeFMUstate(st)))
    r.s.fmu.freeFMUstate(st)
    results["lenient_compass_nan"] = {"stepped": before != after and r.s.last_status in ("OK", "WARNING"),
                                      "messages": [list(m) for m in r.s.messages[n_msgs:]],
                                      "discarded_samples": r.s.get(["discarded_samples"])["discarded_samples"]}
    r.close()
    return results


def check_stopped_counter(fmu: str, params=None) -> dict[str, Any]:
    """The left counter stopped for 2 s at 16 m/s while the right counts on (its pulses lost): every sample is
    stepped, one warning names the left counter once the stop lasts STOPPED_MIN_S, one information its end, and the
    same drive without the fault logs neither."""
    d = _drive(200)
    j, n = 120, 20
    runs = {}
    for case in ("clean", "stopped"):
        drive = dict(d)
        if case == "stopped":
            inc = np.diff(d["left_pulses"])
            inc = (inc + 32768.0) % 65536.0 - 32768.0
            inc[j - 1:j - 1 + n] = 0.0  # samples j .. j+n-1 count nothing
            drive["left_pulses"] = (d["left_pulses"][0] + np.concatenate([[0.0], np.cumsum(inc)])) % 65536.0
        r = _Run(fmu, case, drive, params)
        r.init()
        r.run_to(len(d["time_s"]) - 1)
        runs[case] = [list(m) for m in r.s.messages if "stopped" in m[2]]
        r.close()
    stopped = runs["stopped"]
    return {"messages": stopped + runs["clean"],
            "warned_once": [m[0] for m in stopped if "left_pulses stopped counting" in m[2]] == ["WARNING"],
            "end_reported": [m[0] for m in stopped if "left_pulses no longer stopped" in m[2]] == ["OK"],
            "clean_quiet": not runs["clean"] and not any("right_pulses stopped" in m[2] for m in stopped)}


BAD_PARAMETERS = {"P": 1.2, "T_F": -1.0, "B": 0.0, "sensor_axle": "middle", "mode": "bogus"}


def check_bad_parameters(fmu: str) -> dict[str, Any]:
    from fmpy.fmi1 import FMICallException

    out: dict[str, Any] = {}
    for key, value in BAD_PARAMETERS.items():
        s = Slave(fmu, f"bad_{key}")
        d = _drive(5)
        names = [n for n in INPUT_NAMES if n in d]
        init_error = None
        try:
            s.initialize(0.0, {key: value}, _sample(d, 0, names))
        except FMICallException as exc:
            init_error = exc.status
        stepped, outputs_nan = None, None
        if init_error is None:
            outputs_nan = all(math.isnan(v) for v in s.get(["heading", "x"]).values())
            s.set(_sample(d, 1, names))
            stepped = s.step(0.0, 0.1)
        msgs = [list(m) for m in s.messages if m[0] != "OK"]
        s.close()
        out[key] = {"init_error": init_error, "stepped": stepped, "outputs_nan": outputs_nan, "messages": msgs,
                    "named": any(key in m[2] and m[1] == "logBadParameter" and m[0] == "ERROR" for m in msgs)}
    return out


def check_access(fmu: str, params=None) -> dict[str, Any]:
    """A fixed parameter set after initialization, an unknown value reference: refused as errors."""
    from fmpy.fmi1 import FMICallException

    s = Slave(fmu, "access")
    d = _drive(3)
    s.initialize(0.0, params, _sample(d, 0, [n for n in INPUT_NAMES if n in d]))
    out = {}
    for case, call in (("fixed_parameter", lambda: s.fmu.setReal([s.vr["B"]], [3.0])),
                       ("unknown_variable", lambda: s.fmu.setReal([10 ** 6], [1.0]))):
        n = len(s.messages)
        try:
            call()
            status = "OK"
        except FMICallException as exc:
            status = "ERROR" if exc.status == 3 else str(exc.status)
        out[case] = {"status": status, "messages": [list(m) for m in s.messages[n:]],
                     "error_logged": any(m[0] == "ERROR" for m in s.messages[n:])}
    out["B_unchanged"] = s.get(["B"])["B"] != 3.0
    s.close()
    return out


def check_all(fmu: str, engine: str | None = None) -> dict[str, Any]:
    params = {"engine": engine} if engine else None
    res = {"save_restore": check_save_restore(fmu, params), "reset": check_reset(fmu, params),
           "two_instances": check_two_instances(fmu, params), "bad_inputs": check_bad_inputs(fmu, params),
           "bad_parameters": check_bad_parameters(fmu), "access": check_access(fmu, params),
           "stopped_counter": check_stopped_counter(fmu, params)}
    s = Slave(fmu, "engine")
    d = _drive(3)
    s.initialize(0.0, params, _sample(d, 0, [n for n in INPUT_NAMES if n in d]))
    res["engine_log"] = [list(m) for m in s.messages if m[1] == "logEngine"]
    s.close()
    return res


def failures(res: Mapping[str, Any]) -> list[str]:
    bad = []
    for key in ("restored_bit_identical", "deserialized_bit_identical"):
        if not res["save_restore"][key]:
            bad.append(f"save_restore.{key}")
    if not res["reset"]["reset_bit_identical"]:
        bad.append("reset")
    for key, v in res["two_instances"].items():
        if not v:
            bad.append(f"two_instances.{key}")
    for case in BAD_CASES:
        r = res["bad_inputs"][case]
        for key in ("skipped", "counted", "categorised", "state_unchanged", "outputs_held",
                    "continues_as_if_never_sent"):
            if not r[key]:
                bad.append(f"bad_inputs.{case}.{key}")
        if r["status"] not in ("OK", "WARNING"):
            bad.append(f"bad_inputs.{case}.status={r['status']}")
    if res["bad_inputs"]["counter_reset"]["statuses"] != ["SKIPPED", "STEPPED", "STEPPED", "STEPPED", "STEPPED"]:
        bad.append("bad_inputs.counter_reset")
    if not res["bad_inputs"]["lenient_compass_nan"]["stepped"]:
        bad.append("bad_inputs.lenient_compass_nan")
    for key, r in res["bad_parameters"].items():
        refused = r["init_error"] == 3 or (r["init_error"] is None and not r["stepped"] and r["outputs_nan"])
        if not refused or not r["named"]:
            bad.append(f"bad_parameters.{key}")
    for case in ("fixed_parameter", "unknown_variable"):
        if not res["access"][case]["error_logged"]:
            bad.append(f"access.{case}")
    if not res["access"]["B_unchanged"]:
        bad.append("access.B_unchanged")
    for key in ("warned_once", "end_reported", "clean_quiet"):
        if not res["stopped_counter"][key]:
            bad.append(f"stopped_counter.{key}")
    return bad


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m fmu.selfcheck", description=__doc__.splitlines()[0])
    ap.add_argument("fmu")
    ap.add_argument("--engine", choices=("auto", "native", "python", "xla"), default=None)
    ap.add_argument("--json", action="store_true", help="print the full results as JSON")
    args = ap.parse_args(argv)
    res = check_all(str(Path(args.fmu)), args.engine)
    bad = failures(res)
    if args.json:
        print(json.dumps({"results": res, "failures": bad}, default=str))
    else:
        for line in res["engine_log"]:
            print("engine:", line[2])
        print("failures:", ", ".join(bad) if bad else "none")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
