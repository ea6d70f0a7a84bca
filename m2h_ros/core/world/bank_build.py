"""Computing a RIR bank's source nodes: in this process, in local worker processes, or as Ray tasks.

Every way runs ``acoustics.simulate_source`` on the same scene, node and config, and each source's
rows depend on nothing else (its tail's noise is seeded by the node), so a bank is identical bit for
bit whichever way computed it. Workers only compute; this process hands each source's rows to
``store`` as they arrive (``RirBank.store`` writes the file atomically), so the workers of a Ray
cluster need no shared file system, and a build that is killed keeps every source it finished: the
next build computes only the files still missing.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from contextlib import closing
from typing import Any

import numpy as np
from tqdm import tqdm

from m2h_ros.core.world.acoustics import AcousticsConfig, simulate_source
from m2h_ros.errors import ConfigError

#: ``ray_address`` that starts a Ray instance on this machine with ``workers`` CPUs (and stops it after).
LOCAL_RAY = "local"


def compute_sources(scene: Any, config: AcousticsConfig, nodes: Sequence[int],
                    store: Callable[[int, np.ndarray], Any], *, workers: int = 1, ray_address: str | None = None,
                    progress: bool = True, desc: str = "RIR bank") -> None:
    """``store(node, simulate_source(scene, node, config))`` for every node, in the order they finish.

    ``ray_address`` None: ``workers`` local processes (1: this process). Otherwise Ray tasks of one CPU
    each: ``LOCAL_RAY`` starts a local instance of ``workers`` CPUs, any other value is the address of a
    running cluster (``ray.init(address=...)``, "auto" for the one this machine belongs to), whose CPUs
    set the parallelism; a Ray session already open in this process is used as it is. Cluster nodes
    need m2h_ros installed and the head's HRTF; the M2H_* environment variables travel with the tasks.
    """
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ConfigError(f"workers must be an integer >= 1, got {workers!r}")
    nodes = [int(node) for node in nodes]
    if not nodes:  # nothing missing: no pool, no Ray start
        return
    if ray_address is not None:
        results = _on_ray(scene, config, nodes, workers=workers, address=ray_address)
    elif workers > 1 and len(nodes) > 1:
        results = _in_processes(scene, config, nodes, workers=workers)
    else:
        results = ((node, simulate_source(scene, node, config)) for node in nodes)
    with closing(results), tqdm(total=len(nodes), desc=desc, unit="src", disable=not progress) as bar:
        for node, rows in results:
            store(node, rows)
            bar.update()


# The scene and config of a worker process, sent once per worker rather than with every node.
_held: tuple[Any, AcousticsConfig] | None = None


def _hold(scene: Any, config: AcousticsConfig) -> None:
    global _held
    _held = scene, config


def _simulate_held(node: int) -> np.ndarray:
    scene, config = _held
    return simulate_source(scene, node, config)


def _in_processes(scene: Any, config: AcousticsConfig, nodes: list[int], *,
                  workers: int) -> Iterator[tuple[int, np.ndarray]]:
    pool = ProcessPoolExecutor(max_workers=min(workers, len(nodes)), initializer=_hold, initargs=(scene, config))
    try:
        futures = {pool.submit(_simulate_held, node): node for node in nodes}
        for future in as_completed(futures):
            yield futures[future], future.result()
    finally:  # on an error or an interrupt, the queued nodes are dropped rather than computed
        pool.shutdown(wait=True, cancel_futures=True)


def _on_ray(scene: Any, config: AcousticsConfig, nodes: list[int], *, workers: int,
            address: str) -> Iterator[tuple[int, np.ndarray]]:
    import ray  # noqa: PLC0415  (Ray is slow to import and only this path needs it)

    started_here = not ray.is_initialized()
    if started_here:
        env_vars = {k: v for k, v in os.environ.items() if k.startswith("M2H_")}
        env_vars["OMP_WAIT_POLICY"] = "PASSIVE"
        options = {"num_cpus": workers, "include_dashboard": False} if address == LOCAL_RAY else {"address": address}
        ray.init(**options, runtime_env={"env_vars": env_vars}, log_to_driver=False, configure_logging=False)
    pending: dict = {}
    try:
        task = ray.remote(num_cpus=1)(simulate_source)
        scene_ref = ray.put(scene)  # one copy in the object store, not one per task
        pending = {task.remote(scene_ref, node, config): node for node in nodes}
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            for ref in done:
                node = pending.pop(ref)
                yield node, ray.get(ref)
    finally:
        for ref in pending:
            ray.cancel(ref)
        if started_here:
            ray.shutdown()
