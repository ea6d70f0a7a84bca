"""Bank build time per source node of both RIR engines on the same scene and threads: the project's
(``backend="project"``) and RLRAudioPropagation (``backend="rlr"``, opt-in: scripts/setup.sh --with-rlr),
each with its default settings otherwise, K source nodes spread over the scene, --repeats times, one
process, beside the fixed numpy workload timed in the same run (``m2h_ros.machine.reference_seconds``).

    python scripts/bench/rir_backends.py [--split test] [--index 0] [--sources 2] [--repeats 2] [--threads 1]

Wall and CPU seconds per source node, their spread over the repeats, and the rlr / project ratio.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from m2h_ros.core.world.acoustics import BACKENDS, AcousticsConfig, simulate_source
from m2h_ros.core.world.scene import SCENE_SPLITS, load_split
from m2h_ros.machine import availability_line, load_average, reference_seconds


def per_source(scene, nodes: np.ndarray, config: AcousticsConfig) -> tuple[float, float]:
    """(wall s, CPU s of this process) per source node over ``nodes``."""
    wall, cpu = time.perf_counter(), time.process_time()
    for node in nodes:
        simulate_source(scene, int(node), config)
    return (time.perf_counter() - wall) / len(nodes), (time.process_time() - cpu) / len(nodes)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--split", choices=sorted(SCENE_SPLITS), default="test")
    parser.add_argument("--index", type=int, default=0)
    parser.add_argument("--sources", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--threads", type=int, default=1, help="the rlr engine's threads (the project's uses one)")
    args = parser.parse_args(argv)

    scene = load_split(args.split)[args.index]
    n_nodes = len(scene.grid.positions)
    nodes = np.linspace(0, n_nodes - 1, args.sources).astype(int)
    print(f"scene {scene.scene_id}: {len(scene.rooms)} rooms, {n_nodes} nodes; source nodes {nodes.tolist()}")
    print(availability_line(), flush=True)
    reference = reference_seconds()
    results = {}
    for backend in BACKENDS:
        config = AcousticsConfig(backend=backend, rlr_threads=args.threads)
        simulate_source(scene, int(nodes[0]), config)  # warm-up: the head, the geometry, imports
        runs = np.array([per_source(scene, nodes, config) for _ in range(args.repeats)])
        results[backend] = runs
        print(f"{backend}: {np.median(runs[:, 0]):.2f} s wall per source node (spread "
              f"{runs[:, 0].min():.2f}-{runs[:, 0].max():.2f} over {args.repeats} repeats), "
              f"{np.median(runs[:, 1]):.2f} s CPU; {n_nodes * np.median(runs[:, 0]) / 60:.1f} min for the "
              f"whole bank", flush=True)
    ratio = np.median(results["rlr"][:, 0]) / np.median(results["project"][:, 0])
    print(f"rlr / project per source node: {ratio:.1f}x; reference workload {reference:.3f} s "
          f"(project {np.median(results['project'][:, 0]) / reference:.1f}x it); load {load_average()}")


if __name__ == "__main__":
    main()
