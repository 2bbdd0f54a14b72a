"""The OdoCompass FMU's estimator engine: the bundled ``jaxmodel``, stepped one sample at a time.

This module is bundled into the FMU's ``resources/odocompass_bundle/`` and loaded by the slave
under a private module name, so the FMU always runs its own copy of ``jaxmodel`` even when the
host process has imported another one.  It never changes the host's global JAX configuration:
every JAX call runs inside ``with jax.enable_x64(True):`` (plus local overrides of debug_nans,
debug_infs and rank promotion, which a host may have set globally).

All engines run the same function -- ``jaxmodel.run_from`` over one sample, the parameters and
the state travelling as flat float64 vectors (leaf order of ``jax.tree_util``, as
``jax.flatten_util.ravel_pytree``) -- traced by JAX into a jaxpr:

* ``native``: that jaxpr lowered to C by ``jaxpr_lower`` and compiled at build time (gcc/cc,
  IEEE float64: no fast-math, no FMA contraction); called through ctypes, ~2-5 µs a step.
  Parameters are run-time arguments, so any parameter values work; one library per compiled
  configuration (``manifest.json`` lists them, the build checks each against ``jaxmodel.run``).
* ``python``: the jaxpr lowered to straight-line Python on floats at initialization, with the
  fixed parameters folded in; ~20-50 µs a step; any configuration, no compiler needed.
* ``xla``: the same function jitted and AOT-compiled by XLA and called with numpy arrays;
  ~60-100 µs a step on a 2-core CPU (XLA:CPU runs the step's ~80 fusions as separate kernels).

``auto`` (the FMU's default) takes the first that is available for the configuration, in that
order; ``python`` falls back to ``xla`` when the lowering meets a primitive it does not cover.
"""

from __future__ import annotations

import contextlib
import ctypes
import hashlib
import importlib.util
import platform
import sys
import threading
import time
from pathlib import Path
from typing import Any, Callable

ENGINES = ("auto", "native", "python", "xla")
NATIVE_STEP = "odocompass_step"
NATIVE_INIT = "odocompass_init"


class ConfigurationError(ValueError):
    """Parameters or configuration the estimator refuses (the message names them)."""


def platform_tag() -> str:
    return f"{sys.platform}-{platform.machine()}"


def bundle_digest(bundle_dir: Path) -> str:
    """SHA-256 (16 hex digits) over the bundle's Python sources: names the private modules."""
    h = hashlib.sha256()
    files = sorted(p for p in Path(bundle_dir).rglob("*.py") if "__pycache__" not in p.parts)
    for p in files:
        h.update(p.relative_to(bundle_dir).as_posix().encode())
        h.update(b"\0")
        h.update(p.read_bytes())
    return h.hexdigest()[:16]


def load_private_module(name: str, path: Path, package_dir: Path | None = None):
    """Import ``path`` as module ``name`` (a package when ``package_dir`` is given), once per process."""
    if name in sys.modules:
        return sys.modules[name]
    if package_dir is not None:
        spec = importlib.util.spec_from_file_location(name, path, submodule_search_locations=[str(package_dir)])
    else:
        spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    except BaseException:
        sys.modules.pop(name, None)
        raise
    return module


@contextlib.contextmanager
def local_jax_config(jax):
    """float64 and permissive, for the calls made here only; the host's global config stays as it is."""
    with contextlib.ExitStack() as stack:
        stack.enter_context(jax.enable_x64(True))
        for name, value in (("debug_nans", False), ("debug_infs", False), ("numpy_rank_promotion", "allow")):
            ctx = getattr(jax, name, None)
            if ctx is not None:
                stack.enter_context(ctx(value))
        yield


def config_key(cfg) -> str:
    """Stable text of a jaxmodel.Config (names native libraries)."""
    return "-".join(f"{k}={getattr(cfg, k)}" for k in type(cfg)._fields)


class Stepper:
    """One prepared estimator: ``step(state, sample) -> (state, outputs)``.

    ``state`` is a flat float64 sequence (a list, or the native engine's buffer: index it, or
    ``list()`` it); ``sample`` a list of floats in ``jaxmodel.Inputs`` order; outputs a list in
    ``jaxmodel.Outputs`` order.  ``step`` never modifies the state it is given.
    """

    def __init__(self, kind: str, step: Callable, s0: list[float], prepare_s: float, note: str = ""):
        self.kind = kind
        self.step = step
        self.s0 = s0
        self.prepare_s = prepare_s
        self.note = note


class _NativeLib:
    """A compiled step/init library (ctypes)."""

    def __init__(self, path: Path, n_param: int, n_state: int, n_in: int, n_out: int):
        self.lib = ctypes.CDLL(str(path))
        self.step = getattr(self.lib, NATIVE_STEP)
        self.init = getattr(self.lib, NATIVE_INIT)
        for fn in (self.step, self.init):
            fn.restype = None
        self.n_param, self.n_state, self.n_in, self.n_out = n_param, n_state, n_in, n_out

    def stepper(self, pflat, note: str) -> Stepper:
        dbl = ctypes.c_double
        state_t = dbl * self.n_state
        p = (dbl * self.n_param)(*pflat)
        buf_a, buf_b, xbuf, obuf = state_t(), state_t(), (dbl * self.n_in)(), (dbl * self.n_out)()
        s0 = state_t()
        self.init(p, s0)
        fn = self.step

        def step(s, x):
            if s is buf_a:
                src, dst = buf_a, buf_b
            elif s is buf_b:
                src, dst = buf_b, buf_a
            else:
                buf_a[:] = s
                src, dst = buf_a, buf_b
            xbuf[:] = x
            fn(p, src, xbuf, dst, obuf)
            return dst, obuf[:]

        return Stepper("native", step, list(s0), 0.0, note)


class Engine:
    """Per bundle and process: the private jaxmodel, its traced step per config, prepared engines."""

    def __init__(self, bundle_dir: str | Path, bundle_id: str):
        self.bundle_dir = Path(bundle_dir)
        self.bundle_id = bundle_id
        self._lock = threading.RLock()
        self._jax = None
        self._jm = None
        self._lower = None
        self._struct = None
        self._traced: dict[Any, Any] = {}
        self._lowered: dict[Any, Any] = {}
        self._xla: dict[Any, Any] = {}
        self._native_libs: dict[str, _NativeLib | str] = {}
        self.layout: dict[str, Any] | None = None

    # -- loading ----------------------------------------------------------------------------
    def modules(self):
        """(jax, private jaxmodel, private jaxpr_lower), imported once."""
        with self._lock:
            if self._jm is None:
                import jax  # the host's jax: one runtime per process

                self._jax = jax
                with local_jax_config(jax):
                    self._jm = load_private_module(f"_odocompass_jaxmodel_{self.bundle_id}",
                                                   self.bundle_dir / "jaxmodel" / "__init__.py",
                                                   package_dir=self.bundle_dir / "jaxmodel")
                # a package over the bundle folder: its relative imports (lowered_code,
                # lowering_runtime) load the bundle's copies, under private names too
                self._lower = load_private_module(f"_odocompass_jaxpr_lower_{self.bundle_id}",
                                                  self.bundle_dir / "jaxpr_lower.py", package_dir=self.bundle_dir)
            return self._jax, self._jm, self._lower

    # -- parameters -------------------------------------------------------------------------
    def make(self, values: dict[str, Any], config: dict[str, Any]):
        """(Params, Config) from JSON-style values; ConfigurationError naming what is wrong."""
        jax, jm, _ = self.modules()
        problems = []
        mode = config.get("mode") or "complementary"
        if mode not in jm.MODES:
            problems.append(f"mode={mode!r} must be one of {', '.join(jm.MODES)}")
        track = config.get("track") or "closed_form"
        if track not in ("closed_form", "table"):
            problems.append(f"track={track!r} must be 'closed_form' or 'table'")
        with local_jax_config(jax):
            try:
                params = jm.make_params(values)
            except jm.ParameterError as exc:
                problems.append(str(exc))
                params = None
            if params is not None:
                try:
                    jm.validate_params(params)
                except jm.ParameterError as exc:
                    problems.append(str(exc))
        if problems:
            raise ConfigurationError("; ".join(problems))
        refine = config.get("refine_a")
        calib = config.get("calibration")
        cfg = jm.Config(mode=mode, refine_a=True if refine is None else bool(refine),
                        calibration=True if calib is None else bool(calib), track=track)
        return params, cfg

    # Flattening and unflattening happen inside the traced functions, so preparing compiles
    # nothing eagerly.
    @staticmethod
    def _unflatten(flat, treedef, shapes):
        leaves, i = [], 0
        for shape in shapes:
            n = 1
            for d in shape:
                n *= d
            leaves.append(flat[i:i + n].reshape(shape))
            i += n
        return treedef.unflatten(leaves)

    @staticmethod
    def _flatten(jax, jnp, tree):
        return jnp.concatenate([jnp.ravel(leaf).astype(jnp.float64) for leaf in jax.tree_util.tree_leaves(tree)])

    def structure(self, params):
        """(param treedef, shapes, state treedef, shapes, state size), cached; sets ``layout``."""
        jax, jm, _ = self.modules()
        with self._lock:
            if self._struct is None:
                with local_jax_config(jax):
                    p_leaves, p_def = jax.tree_util.tree_flatten(params)
                    state = jax.eval_shape(jm.init_state, params)
                    s_leaves, s_def = jax.tree_util.tree_flatten(state)
                    names = []
                    for path, leaf in jax.tree_util.tree_flatten_with_path(state)[0]:
                        base = ".".join(str(getattr(k, "name", getattr(k, "key", k))) for k in path)
                        size = 1
                        for d in leaf.shape:
                            size *= d
                        names.extend([base] if leaf.shape == () else [f"{base}[{i}]" for i in range(size)])
                self.layout = {"state": names, "inputs": list(jm.Inputs._fields), "outputs": list(jm.Outputs._fields),
                               "n_param": sum(int(getattr(l, "size", 1)) for l in p_leaves)}
                self._struct = (p_def, [tuple(getattr(l, "shape", ())) for l in p_leaves], s_def,
                                [tuple(l.shape) for l in s_leaves], len(names))
            return self._struct

    def trace(self, params, cfg):
        """Closed jaxprs of init_state and of one sample through ``jaxmodel.run_from`` (params are inputs)."""
        jax, jm, _ = self.modules()
        key = tuple(cfg)
        with self._lock:
            if key in self._traced:
                return self._traced[key]
            import jax.numpy as jnp

            p_def, p_shapes, s_def, s_shapes, n_state = self.structure(params)
            n_in = len(jm.Inputs._fields)
            n_par = self.layout["n_param"]
            unflatten, flatten = self._unflatten, self._flatten

            def init_flat(pf):
                return flatten(jax, jnp, jm.init_state(unflatten(pf, p_def, p_shapes)))

            def one_sample(pf, sf, x):
                p = unflatten(pf, p_def, p_shapes)
                s = unflatten(sf, s_def, s_shapes)
                sample = jm.Inputs(*[x[i][None] for i in range(n_in)])
                new_state, out = jm.run_from(p, s, sample, cfg)
                return flatten(jax, jnp, new_state), jnp.stack([o[0] for o in out])

            with local_jax_config(jax):
                spec = jax.ShapeDtypeStruct
                closed_init = jax.make_jaxpr(init_flat)(spec((n_par,), jnp.float64))
                closed = jax.make_jaxpr(one_sample)(spec((n_par,), jnp.float64), spec((n_state,), jnp.float64),
                                                    spec((n_in,), jnp.float64))
            self._traced[key] = (closed_init, init_flat, closed, one_sample, n_state)
            return self._traced[key]

    def flat_params(self, params):
        import numpy as np

        jax, _, _ = self.modules()
        return np.concatenate([np.ravel(np.asarray(leaf, dtype=np.float64)) for leaf in jax.tree_util.tree_leaves(params)])

    # -- the native engine --------------------------------------------------------------------
    def native_source(self, params, cfg) -> tuple[str, dict[str, Any]]:
        """C source of init and step for ``cfg`` (parameters as run-time arguments) and its ABI metadata."""
        _, jm, lower = self.modules()
        closed_init, _, closed, _, n_state = self.trace(params, cfg)
        init_prog = lower.lower_program(closed_init, [None])
        step_prog = lower.lower_program(closed, [None, None, None])
        source = lower.C_PRELUDE + init_prog.to_c(NATIVE_INIT) + "\n" + step_prog.to_c(NATIVE_STEP)
        meta = {"config": dict(cfg._asdict()), "key": config_key(cfg), "n_param": self.layout["n_param"],
                "n_state": n_state, "n_in": len(jm.Inputs._fields), "n_out": len(jm.Outputs._fields),
                "state": self.layout["state"], "outputs": self.layout["outputs"], "n_ops": step_prog.n_ops,
                "platform": platform_tag()}
        return source, meta

    def _native_lib(self, cfg, native_dir, native):
        """The loaded library for ``cfg`` from the caller's bundle, or a text saying why there is none."""
        key = config_key(cfg)
        entry = next((e for e in native or () if e.get("key") == key), None)
        if entry is None:
            return f"no native library for {key} in this build"
        path = str((Path(native_dir) / entry["file"]).resolve())
        with self._lock:
            if path in self._native_libs:
                return self._native_libs[path]
            result: _NativeLib | str
            if entry.get("platform") != platform_tag():
                result = f"native library built for {entry.get('platform')}, this is {platform_tag()}"
            elif (entry["state"] != self.layout["state"] or entry["n_param"] != self.layout["n_param"]
                  or entry["outputs"] != self.layout["outputs"]):
                result = "native library does not match the bundled jaxmodel's layout"
            else:
                try:
                    result = _NativeLib(Path(path), entry["n_param"], entry["n_state"], entry["n_in"], entry["n_out"])
                except (OSError, AttributeError) as exc:
                    result = f"native library not loadable: {exc}"
            self._native_libs[path] = result
            return result

    # -- preparing ----------------------------------------------------------------------------
    def prepare(self, values: dict[str, Any], config: dict[str, Any], engine: str = "auto",
                native_dir: str | Path | None = None, native: list[dict] | None = None) -> Stepper:
        """A Stepper for these parameters and configuration (a new one per call: per-instance buffers).

        ``native`` lists the compiled libraries of the caller's build (manifest entries, files
        relative to ``native_dir``).
        """
        engine = engine or "auto"
        if engine not in ENGINES:
            raise ConfigurationError(f"engine={engine!r} must be one of {', '.join(ENGINES)}")
        t0 = time.perf_counter()
        params, cfg = self.make(values, config)
        self.structure(params)
        pflat = self.flat_params(params)
        notes = []
        if engine in ("auto", "native"):
            lib = self._native_lib(cfg, native_dir or self.bundle_dir, native)
            if isinstance(lib, _NativeLib):
                stepper = lib.stepper(pflat, f"C library, {config_key(cfg)}")
                stepper.prepare_s = time.perf_counter() - t0
                return stepper
            notes.append(lib)
        if engine in ("auto", "native", "python"):
            stepper = self._python_stepper(params, cfg, pflat, notes)
            if stepper is not None:
                stepper.prepare_s = time.perf_counter() - t0
                return stepper
        stepper = self._xla_stepper(params, cfg, pflat, notes)
        stepper.prepare_s = time.perf_counter() - t0
        return stepper

    def _python_stepper(self, params, cfg, pflat, notes):
        _, _, lower = self.modules()
        key = (tuple(cfg), pflat.tobytes())
        with self._lock:
            cached = self._lowered.get(key)
            if cached is None:
                closed_init, _, closed, _, _ = self.trace(params, cfg)
                try:
                    s0 = [float(v) for v in lower.lower_jaxpr(closed_init, [pflat], name="odocompass_init").fn()[0]]
                    lowered = lower.lower_jaxpr(closed, [pflat, None, None], name="odocompass_step")
                    cached = (lowered.fn, s0, f"{lowered.n_ops} Python statements")
                except lower.Unsupported as exc:
                    cached = f"lowering to Python not possible ({exc})"
                self._lowered[key] = cached
        if isinstance(cached, str):
            notes.append(cached)
            return None
        fn, s0, note = cached
        return Stepper("python", fn, list(s0), 0.0, "; ".join(notes + [note]))

    def _xla_stepper(self, params, cfg, pflat, notes):
        jax, jm, _ = self.modules()
        import jax.numpy as jnp
        import numpy as np

        closed_init, init_flat, _, one_sample, n_state = self.trace(params, cfg)
        key = tuple(cfg)
        with self._lock, local_jax_config(jax):
            compiled = self._xla.get(key)
            if compiled is None:
                def flat(pf, sf, x):
                    s, o = one_sample(pf, sf, x)
                    return jnp.concatenate([s, o])

                n_in = len(jm.Inputs._fields)
                compiled = (jax.jit(init_flat).lower(pflat).compile(),
                            jax.jit(flat).lower(pflat, np.zeros(n_state), np.zeros(n_in)).compile())
                self._xla[key] = compiled
            init_c, step_c = compiled
            p_dev = jax.device_put(pflat)
            s0 = [float(v) for v in np.asarray(init_c(p_dev))]
        ctx = local_jax_config

        def step(s, x):
            with ctx(jax):
                r = step_c(p_dev, np.asarray(s, dtype=np.float64), np.asarray(x, dtype=np.float64))
            r = np.asarray(r).tolist()
            return r[:n_state], r[n_state:]

        return Stepper("xla", step, s0, 0.0, "; ".join(notes + ["XLA executable"]))


def python_host() -> bool:
    """True when the process is a Python interpreter (fmpy ...), False in a C host that embeds Python
    through pythonfmu (the FMU Compliance Checker, a C master)."""
    import os

    try:
        return Path(os.readlink("/proc/self/exe")).name.startswith(("python", "pypy"))
    except OSError:
        return Path(sys.executable or "").name.startswith("python")


def release_for_c_host() -> None:
    """In a C host, drop JAX's compiled-computation caches once the FMU is done.

    There pythonfmu calls Py_Finalize from the FMU library's destructor, after the C++ statics of
    jaxlib are gone; cached MLIR modules destroyed that late crash the process at exit (seen with
    the FMU Compliance Checker).  In a Python host this is never done: the caches are the host's.
    """
    if python_host():
        return
    import gc

    import jax

    jax.clear_caches()
    gc.collect()


_ENGINES: dict[str, Engine] = {}
_ENGINES_LOCK = threading.Lock()


def get_engine(bundle_dir: str | Path, bundle_id: str) -> Engine:
    """The process-wide Engine of one bundle's sources (FMU instances of builds with equal sources share it)."""
    with _ENGINES_LOCK:
        eng = _ENGINES.get(bundle_id)
        if eng is None:
            eng = _ENGINES[bundle_id] = Engine(bundle_dir, bundle_id)
        return eng
