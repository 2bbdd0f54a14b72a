"""Ray for the fleet commands: the cluster, the workers' environment, and running tasks with a
progress bar over vehicles.

* Without ``--address`` a local Ray cluster is started with ``--workers`` CPUs (default: this
  machine's cores) and shut down at the end; with ``--address`` the existing cluster is joined
  (``ray.init(address=...)``; ``auto`` finds a cluster started on this machine with ``ray start``)
  and ``--workers`` caps the tasks in flight.  A session that already called ``ray.init``
  (a test, a notebook) is used as it is and left running.
* One task uses one CPU (``num_cpus=1``), and its XLA runs on one thread
  (``XLA_FLAGS=--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1``, set in the
  job's runtime environment and again by the task before it imports jax): with one task per
  core, XLA's own thread pool would only oversubscribe the cores (measured in docs/fleet.md).
* A worker that dies (killed, out of memory) is retried by Ray (``max_retries``); a task that
  raises is not retried: the task itself already turned each vehicle's problem into an ``error``.
"""

from __future__ import annotations

import logging
import os
import sys
import warnings
from contextlib import contextmanager
from typing import Callable, Iterable

from .errors import OdoCompassError

XLA_ONE_THREAD = "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"
MAX_RETRIES = 3


def worker_setup() -> None:
    """In a task, before jax is imported: one XLA CPU thread, 64-bit JAX, quiet libraries."""
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_cpu_multi_thread_eigen" not in flags:
        os.environ["XLA_FLAGS"] = (flags + " " + XLA_ONE_THREAD).strip()
    os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")
    import jax

    jax.config.update("jax_enable_x64", True)


def _import_ray():
    try:
        import ray
    except ImportError:
        raise OdoCompassError("the fleet commands need Ray: pip install 'ray>=2.9'") from None
    return ray


@contextmanager
def cluster(address: str | None, workers: int | None):
    """Connect to (or start) a Ray cluster; yields the number of tasks to keep in flight."""
    ray = _import_ray()
    started = False
    if not ray.is_initialized():
        env = {"env_vars": {"XLA_FLAGS": XLA_ONE_THREAD, "TF_CPP_MIN_LOG_LEVEL": "2"}}
        kwargs = dict(include_dashboard=False, logging_level=logging.ERROR, log_to_driver=False, runtime_env=env)
        for name in ("ray", "ray._private", "ray.worker"):
            logging.getLogger(name).setLevel(logging.ERROR)
        warnings.filterwarnings("ignore", message=r"os\.fork\(\) was called")  # Ray spawns its processes
        try:
            if address:
                ray.init(address=address, **kwargs)
            else:
                # "local": a new cluster even when `ray start` left one (or its stale address) on this machine
                ray.init(address="local", num_cpus=workers or os.cpu_count() or 1, **kwargs)
        except Exception as exc:  # noqa: BLE001 - connection refused, bad address, no cluster
            where = f"--address {address}" if address else "a local Ray cluster"
            hint = ""
            if address and os.environ.get("RAY_AUTH_MODE") != "token":
                hint = ("; if the cluster uses token authentication (Ray >= 2.59 clusters do by default), set "
                        "RAY_AUTH_MODE=token and its token (RAY_AUTH_TOKEN, or ~/.ray/auth_token) here")
            raise OdoCompassError(f"{where}: cannot start Ray: {' '.join(str(exc).split())[:300]}{hint}") from None
        started = True
    try:
        cpus = int(ray.cluster_resources().get("CPU", 1))
        yield max(1, min(workers, cpus) if workers else cpus)
    finally:
        if started:
            ray.shutdown()


def run_tasks(remote_fn, payloads: list, in_flight: int, weights: Iterable[int], on_result: Callable,
              desc: str, progress: bool, unit: str = "vehicle") -> None:
    """Submit ``remote_fn.remote(p)`` for each payload, at most ``in_flight`` at a time; call
    ``on_result(payload, result_or_exception)`` as each finishes (in completion order); a tqdm
    bar over ``weights`` (vehicles or drives per payload, ``unit``) when ``progress``."""
    ray = _import_ray()
    weights = list(weights)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=sum(weights), desc=desc, unit=unit, file=sys.stderr, dynamic_ncols=True)
    pending: dict = {}
    queue = list(range(len(payloads)))
    try:
        while queue or pending:
            while queue and len(pending) < in_flight:
                i = queue.pop(0)
                pending[remote_fn.remote(payloads[i])] = i
            ready, _ = ray.wait(list(pending), num_returns=1)
            for ref in ready:
                i = pending.pop(ref)
                try:
                    result = ray.get(ref)
                except Exception as exc:  # noqa: BLE001 - a task that failed after its retries
                    result = exc
                on_result(payloads[i], result)
                if bar is not None:
                    bar.update(weights[i])
    finally:
        for ref in pending:
            ray.cancel(ref, force=True)
        if bar is not None:
            bar.close()


def task_error_line(exc: BaseException) -> str:
    """One line for a task that failed (after Ray's retries): its cause, not Ray's wrapping."""
    cause = getattr(exc, "cause", None) or exc
    text = " ".join(str(cause).split()) or type(cause).__name__
    if "Traceback" in text:  # RayTaskError renders the remote traceback; keep its last line
        text = text.rsplit(":", 1)[-1].strip() or type(cause).__name__
    return f"{type(cause).__name__}: {text[:300]}"
