"""Test configuration: float64 and strict rank promotion, as in diffrax."""

import contextlib
import gc
import os
import tempfile
from pathlib import Path

# The suite's time is mostly XLA:CPU compiling the estimator's scan (hundreds of programs: every module clears the
# in-memory caches below, every CLI or FMU subprocess starts empty).  LLVM's backend optimisation off compiles them
# ~25 % faster end to end (tests/test_scenarios.py + test_model.py: 354 -> 265 s); it changes the generated code's
# speed, not the float64 operations XLA asked for.  XLA:CPU's fusion emitters off (the older loop emitters) compile
# the default filter's reverse pass in 10.1 s against 17.2 s (stop 47, one process on an idle machine); its gradient
# agrees to 4e-15 relative.  Inherited by the subprocesses; bench/ keeps the default (the emitters off run a 64-drive
# vmapped batch ~20 % slower: bench_run.py).
os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "")
                           + " --xla_backend_optimization_level=0 --xla_cpu_use_fusion_emitters=false").strip()
from identification import compile_cache  # noqa: E402 (imports no jax)

# One folder for the whole run, shared by the xdist workers: the controller imports this file before it starts
# them, they inherit the variable and use its folder; the controller removes it when it exits (after them).
# Expensive artefacts that every worker would otherwise build alike go there (test_fmu.built_fmus: the FMUs).
SHARED_RUN_DIR_ENV = "ODOCOMPASS_TEST_RUN_DIR"
if not os.path.isdir(os.environ.get(SHARED_RUN_DIR_ENV, "")):
    _SHARED_RUN_DIR = tempfile.TemporaryDirectory(prefix="odocompass-test-run-")
    os.environ[SHARED_RUN_DIR_ENV] = _SHARED_RUN_DIR.name

# One persistent compilation cache for the run, fresh each run, in that folder: the modules (which clear the
# in-memory caches), both workers and the CLI and FMU subprocesses compile many of the same programs; XLA:CPU then
# loads them instead.  A bound on its size turns on JAX's file lock around every read and write
# (jax/_src/lru_cache.py), so a worker never reads a program the other is still writing.
os.environ["JAX_COMPILATION_CACHE_DIR"] = os.path.join(os.environ[SHARED_RUN_DIR_ENV], "jax-cache")
os.environ["JAX_COMPILATION_CACHE_MAX_SIZE"] = str(4 << 30)
os.environ["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"] = str(compile_cache.MIN_COMPILE_S)

import jax  # noqa: E402
import pytest

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_rank_promotion", "raise")

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"
REAL_DATA = SHARED / "data" / "real"


@pytest.fixture(scope="session")
def real_data_dir():
    if not REAL_DATA.is_dir():
        pytest.skip(f"real logs not available: {REAL_DATA} is absent (they live in ../shared, outside the repo)")
    return REAL_DATA


@pytest.fixture(autouse=True, scope="module")
def _free_compiled_programs():
    """Drop every module's compiled XLA programs after it: a whole-suite run in one process crashed
    (SIGSEGV in XLA's compiler) after ~550 tests had accumulated their programs; each file alone,
    and the same files in pairs, pass."""
    yield
    jax.clear_caches()
    gc.collect()


@pytest.fixture
def traced_constants():
    """A context manager that sets module constants for what runs inside it only: ``with traced_constants((module,
    "NAME", value), ...):``.  The estimator reads its module constants when a step is traced, so the compiled programs
    are dropped on entry and on exit, and the constants are restored however the block ends (a failing assertion
    inside it must not leave the rest of the module running programs traced with them)."""

    @contextlib.contextmanager
    def patched(*settings):
        saved = [(module, name, getattr(module, name)) for module, name, _ in settings]
        try:
            for module, name, value in settings:
                setattr(module, name, value)
            jax.clear_caches()
            yield
        finally:
            for module, name, value in reversed(saved):
                setattr(module, name, value)
            jax.clear_caches()

    return patched


HEAVY_FILES_FIRST = ("test_kalman.py", "test_identify_fixes.py", "test_demo.py", "test_fmu.py",
                     "test_identify_recovery.py", "test_identify.py", "test_fleet.py", "test_scenarios.py",
                     "test_stuck_wheel.py", "test_importers.py", "test_hard_iron.py", "test_sample_rate.py",
                     "test_calibration.py", "test_model.py", "test_soft_iron.py", "test_fmu_native.py",
                     "test_fix_alignment.py", "test_robustness.py", "test_warnings.py", "test_compass_fit.py",
                     "test_identify_from_zero.py", "test_shifted_hard_iron.py", "test_readme.py", "test_fmu_cosim.py")
"""Files that take half a minute to ten minutes each, longest first (``--durations=80`` summed per file, stop 92:
test_kalman.py 577 s, test_identify_fixes.py 467 s, test_demo.py 255 s, test_fmu.py 254 s, ... test_stuck_wheel.py
162 s, which had run among the last files, ... test_compass_fit.py 54 s), run first.  xdist's
``--dist loadfile`` hands the files out one at a time as a worker frees up; longest first, the two workers end
together.  In alphabetical order the long files came last and one worker ran them alone while the other sat idle; and
pytest-xdist 3.6 on reorders the files by their number of tests unless ``--no-loadscope-reorder`` (``addopts``), which
put the heaviest files (few tests each: identify recovery 3, the demo 1) last again.  test_fmu.py comes before the two
other FMU files so that the FMUs it builds for the run are there when they ask (``test_fmu.built_fmus``)."""


def pytest_collection_modifyitems(config, items):
    rank = {name: i for i, name in enumerate(HEAVY_FILES_FIRST)}
    # A stable sort: each file's tests keep their order, the other files theirs after the heavy ones.
    items.sort(key=lambda item: rank.get(item.path.name, len(HEAVY_FILES_FIRST)))
