"""Where `asset-bake` runs its jobs beyond this machine: Ray tasks, one per asset or environment.

The unit of work is the local executor's own `bake.bake_one`, so results, cache keys and
cache bytes are the same whichever executor ran it; only the fan-out differs. Each environment
is one task like each asset (so it is baked once per cluster, never once per worker), and the
content-addressed cache on a shared filesystem makes a job that two nodes run anyway
(a retry, a second `asset-bake` at once) cost time, never correctness.

Requirements on a cluster: every node sees the asset paths and the cache folder at the same
absolute paths (one shared filesystem, mounted alike), and runs the same asset-preview version.
Tasks run in the driver's working directory, so relative paths and result lines read as they
do locally. ASSET_PREVIEW_* variables of the driver travel with the tasks (limits, cache cap).

Ray is optional (`pip install 'asset-preview[ray]'`): nothing here imports it at module level.
"""
from __future__ import annotations

import logging
import os
import socket
import sys
import time
from pathlib import Path
from typing import Any, Callable

from pipeline.bake import bake_one
from pipeline.cache import default_cache_dir

log = logging.getLogger(__name__)

RAY_MISSING = ("--executor ray needs Ray, which is not installed: "
               "pip install 'asset-preview[ray]' (or pip install 'ray[client]>=2.9')")
MAX_RETRIES = 3  # a task whose worker process dies (crash, OOM kill, lost node) runs again
IN_FLIGHT_PER_CPU = 4  # tasks submitted ahead of results: bounded driver memory at 100k assets


class ExecutorUnavailable(RuntimeError):
    """The requested executor cannot run here (Ray missing, cluster unreachable)."""


def require_ray():
    """The `ray` module, or ExecutorUnavailable saying how to install it."""
    try:
        import ray  # optional (the `ray` extra) and heavy: only for --executor ray
    except ImportError as exc:
        raise ExecutorUnavailable(RAY_MISSING) from exc
    return ray


def task_env() -> dict:
    """The runtime_env that carries this process's ASSET_PREVIEW_* settings to Ray workers."""
    env = {k: v for k, v in os.environ.items() if k.startswith("ASSET_PREVIEW_")}
    return {"env_vars": env} if env else {}


_connected_here = False  # this module called ray.init (so it disconnects when done)


def connect(address: str | None = None, num_cpus: int | None = None) -> None:
    """Join the Ray cluster at `address` ("auto", "HOST:PORT", "ray://HOST:PORT"; default
    $RAY_ADDRESS, else a new local one on this machine), unless this process already is
    connected (then that connection is used as it is)."""
    global _connected_here
    ray = require_ray()
    if ray.is_initialized():
        return
    address = address or os.environ.get("RAY_ADDRESS") or None
    # Worker output stays in Ray's session logs: stdout is for result lines only.
    kwargs: dict[str, Any] = {"logging_level": logging.WARNING, "log_to_driver": False}
    if address and address != "auto":
        _probe(address)
    try:
        if address:
            if address.removeprefix("ray://").rpartition(":")[0] in ("127.0.0.1", "localhost"):
                # a loopback cluster: this driver's own servers bind loopback too
                kwargs["_node_ip_address"] = "127.0.0.1"
            ray.init(address=address, **kwargs)
        else:  # a throwaway cluster on this machine, no dashboard
            ray.init(num_cpus=num_cpus, include_dashboard=False, **kwargs)
    except (ConnectionError, RuntimeError, ValueError) as exc:
        raise ExecutorUnavailable(f"cannot connect to the Ray cluster at {address or 'a new local one'}: "
                                  f"{exc}") from exc
    _connected_here = True
    log.info("ray: connected to %s (%s CPUs)", address or "a new local cluster",
             ray.cluster_resources().get("CPU", 0))


def _probe(address: str, timeout: float = 10.0) -> None:
    """Fail fast when nothing listens at HOST:PORT (Ray itself retries for minutes)."""
    host, _, port = address.removeprefix("ray://").rpartition(":")
    try:
        socket.create_connection((host, int(port)), timeout=timeout).close()
    except ValueError:
        raise ExecutorUnavailable(f"not a Ray address: {address!r} (auto, HOST:PORT or ray://HOST:PORT)") from None
    except OSError as exc:
        raise ExecutorUnavailable(f"cannot reach the Ray cluster at {address}: {exc.strerror or exc}") from None


def disconnect() -> None:
    """Leave the cluster if `connect` joined it (a caller's own ray.init is left alone)."""
    global _connected_here
    if _connected_here:
        require_ray().shutdown()
        _connected_here = False


def run_job(kind: str, source: str, common: dict, then: Callable[[dict, Any], dict] | None = None,
            hint: Any = None) -> dict:
    """One job where it runs (this process, a pool process, a Ray task): the bake, then
    `then(result, hint)` on its result in the same process (asset-bake --thumbnails renders
    there, next to the bake entry it just wrote); neither raises."""
    result = bake_one(kind, source, **common)
    return then(result, hint) if then is not None else result


def _bake_task(kind: str, source: str, cwd: str, common: dict, then=None, hint=None) -> dict:
    """One job in a Ray worker, in the driver's working directory when this node has it."""
    if os.path.isdir(cwd):
        os.chdir(cwd)
    elif not os.path.isabs(source) and kind == "asset":
        return {"kind": kind, "path": source, "status": "failed", "seconds": 0.0,
                "error": f"{source}: relative path, and the driver's working directory {cwd} "
                         f"is not mounted on Ray node {_node()}"}
    return run_job(kind, source, common, then, hint)


def _node() -> str:
    try:
        return require_ray().util.get_node_ip_address()
    except Exception:  # only for a message
        return "?"


def run_ray(jobs: list[tuple[str, str]], common: dict, report, *, address: str | None = None,
            max_retries: int = MAX_RETRIES, then: Callable[[dict, Any], dict] | None = None,
            hint: Callable[[str], Any] | None = None) -> None:
    """Bake `jobs` ((kind, source) pairs) as Ray tasks, passing each result to `report.add`
    as it arrives; `common` holds `bake_one`'s keyword arguments. With `then` (picklable),
    each task also runs `then(result, hint(source))` after its bake, on the same node and in
    the same worker process (see `run_job`); a retried task (its node lost) runs both again
    elsewhere, and the content-addressed cache makes what the first attempt finished a hit.
    Connects (see `connect`) unless connected already, and disconnects when done if it
    connected."""
    ray = require_ray()
    # Ray prints its own notices ("a worker died...", a node lost while disconnecting) to
    # sys.stdout; the report holds the real stdout, so from connecting to disconnecting they go
    # to stderr and stdout stays result lines only.
    stdout, sys.stdout = sys.stdout, sys.stderr
    try:
        connect(address)
    except BaseException:
        sys.stdout = stdout
        raise
    common = dict(common)
    # Absolute, so that a worker that cannot chdir (another mount layout) fails loudly on
    # the path instead of writing a private cache of its own.
    common["cache"] = str(Path(common.get("cache") or default_cache_dir()).absolute())
    options: dict[str, Any] = {"num_cpus": 1, "max_retries": max_retries, "retry_exceptions": False}
    if env := task_env():
        options["runtime_env"] = env
    remote = ray.remote(_bake_task).options(**options)
    cwd = os.getcwd()
    window = max(8, int(IN_FLIGHT_PER_CPU * ray.cluster_resources().get("CPU", 1)))
    shared = ray.put(then) if then is not None else None  # sent once, not with every task
    todo = list(reversed(jobs))
    running: dict = {}
    start = time.perf_counter()
    try:
        while todo or running:
            while todo and len(running) < window:
                kind, source = todo.pop()
                extra = (shared, hint(source) if hint else None) if then is not None else ()
                running[remote.remote(kind, source, cwd, common, *extra)] = (kind, source, time.perf_counter())
            done, _ = ray.wait(list(running), num_returns=1)
            for ref in done:
                kind, source, t0 = running.pop(ref)
                report.add(_result(ray, ref, kind, source, t0, max_retries))
    except KeyboardInterrupt:
        for ref in running:
            ray.cancel(ref, force=True)
        raise
    finally:
        log.info("ray: %d jobs in %.2f s", len(jobs), time.perf_counter() - start)
        try:
            disconnect()
        finally:
            sys.stdout = stdout


def _result(ray, ref, kind: str, source: str, t0: float, max_retries: int) -> dict:
    try:
        return ray.get(ref)
    except ray.exceptions.WorkerCrashedError:
        why = (f"the Ray worker baking it died {max_retries + 1} times "
               "(crash or out of memory); not retried further")
    except ray.exceptions.RayError as exc:  # node lost, task cancelled, object lost
        why = f"Ray could not run the bake ({type(exc).__name__}: {str(exc).splitlines()[0][:200]})"
    return {"kind": kind, "path": source, "status": "failed", "error": f"{source}: {why}",
            "seconds": round(time.perf_counter() - t0, 4)}
