#!/usr/bin/env python3
"""Pipeline throughput: steps per second through the five-process ROS graph vs the same models and
episodes in-process (one slot, camera on, scores computed, the listener output made as separator_node
makes it for separator/audio), measured in one run, and their ratio;
plus the separator node's per-step latency and each node's CPU per step (the CPU time it prints at exit
since its first message, so without its start-up) beside the in-process CPU per step. Test episodes,
shipped separator, banks cached. The recorder runs as run_pipeline.py starts it (derived topics left
to m2h-derive, which runs after the sim's last step and so outside the timed span); nobody else
watches, or with --live-view the live view node runs (in the recorder's process, as run_pipeline.py
starts it) and a Foxglove client (m2h_ros.io.foxglove_watch, in this process, its CPU per step printed)
watches every topic through it, so the live view makes every picture, track and marker; with --live-view
nobody the live view runs and no client connects.

    python scripts/bench/pipeline.py [--episodes 5] [--repeats 2] [--controller random]
                                     [--live-view [everything|nobody]]
"""

from __future__ import annotations

import argparse
import asyncio
import os
import re
import socket
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import torch  # noqa: E402

from m2h_ros import sim_world  # noqa: E402
from m2h_ros.agents.registry import make_controller  # noqa: E402
from m2h_ros.agents.rollout import evaluate_controller  # noqa: E402
from m2h_ros.io.foxglove_watch import Watched, watch  # noqa: E402
from m2h_ros.models.checkpoint import DEFAULT_SEPARATOR_CHECKPOINT, load_separator  # noqa: E402
from m2h_ros.models.listener import DEFAULT_LISTENER_CHECKPOINT, load_listener  # noqa: E402
from m2h_ros.models.runner import SeparatorRunner  # noqa: E402
from m2h_ros.machine import availability_line  # noqa: E402
from m2h_ros.node_configs import PIPELINE_NODES, SimConfig  # noqa: E402
from m2h_ros.paths import REPO_DIR  # noqa: E402

NODES = ("sim_node", *PIPELINE_NODES)


class PlayingRunner(SeparatorRunner):
    """A runner that also makes, each step, what separator_node publishes on separator/audio by default
    (the listener output, both ears): the in-process side does the graph's work, not less."""

    def step(self, audio, class_index, reset, **options):
        separation = super().step(audio, class_index, reset, **options)
        self.listen(audio, class_index, binaural=True)
        return separation


def in_process(config: SimConfig, controller: str) -> tuple[float, float]:
    """Steps per second of evaluate_controller on the sim's episodes (one slot, 1 torch thread, the
    listener output made each step as the separator node does) and its CPU ms per step."""
    torch.set_num_threads(1)
    library = sim_world.sound_library(config.sound_library)
    episodes = sim_world.sim_episodes(config, library)
    runner = PlayingRunner(load_separator(DEFAULT_SEPARATOR_CHECKPOINT), 1,
                           listener=load_listener(DEFAULT_LISTENER_CHECKPOINT))
    started, cpu = time.perf_counter(), time.process_time()
    results = evaluate_controller(make_controller(controller, 1), runner, episodes, library,
                                  env_config=sim_world.env_config(config), progress=False)
    steps = sum(len(r.si_sdr) for r in results)
    return steps / (time.perf_counter() - started), (time.process_time() - cpu) / steps * 1e3


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def through_graph(episodes: int, controller: str, nodes: tuple[str, ...], *, client: bool = False,
                  ) -> tuple[float, str, int, dict[str, float], Watched | None]:
    """Steps per second the sim reports (first publication to last answer), separator latency line,
    steps played, CPU seconds of each node since its first message, and what the client (``client``:
    one watching every topic through the live view) received."""
    port = free_port()
    live_view = ["--live-view", str(port)] if "live_view_node" in nodes else []
    with tempfile.TemporaryDirectory() as tmp, ThreadPoolExecutor(1) as pool:
        run = subprocess.Popen([sys.executable, str(REPO_DIR / "scripts" / "run_pipeline.py"), "--episodes", str(episodes),
                                "--controller", controller, "--out", tmp, *live_view],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        watched = pool.submit(asyncio.run, watch(port, timeout=3600.0, keep=False)) if client else None
        stdout, stderr = run.communicate()
        result = subprocess.CompletedProcess(run.args, run.returncode, stdout, stderr)
        seen = watched.result() if watched is not None else None
        logs = Path(tmp) / "logs"
        # The live view runs in the recorder's process (its CPU is in the recorder's) unless there is no recorder.
        texts = {node: (logs / f"{node}.log").read_text() for node in nodes if (logs / f"{node}.log").exists()}
    if result.returncode:
        raise SystemExit(f"pipeline run failed:\n{result.stdout}\n{result.stderr}\n{texts['sim_node']}")
    done = re.search(r"(\d+) steps in [\d.]+ s \(([\d.]+) steps/s\)", texts["sim_node"])
    latency = re.search(r"latency per step.*", texts["separator_node"])
    cpu = {node: float(re.search(r"([\d.]+) s since its first message", text).group(1)) for node, text in texts.items()}
    return float(done.group(2)), latency.group(0) if latency else "(no latency line)", int(done.group(1)), cpu, seen


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=5)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--controller", default="random")
    parser.add_argument("--live-view", nargs="?", const="everything", choices=("everything", "nobody"),
                        help="run the live view node, with a client watching every topic (everything, the "
                             "default) or none connected (nobody)")
    args = parser.parse_args(argv)
    nodes = (*NODES, "live_view_node") if args.live_view else NODES
    client = args.live_view == "everything"
    target = 1.6 if client else 1.3
    setting = {"everything": " (live view, a client watching every topic)",
               "nobody": " (live view, no client)"}.get(args.live_view, "")
    config = SimConfig(num_episodes=args.episodes)
    print(availability_line(), flush=True)
    in_process(config, args.controller)  # warm: RIR banks of these episodes' sources, camera views
    for repeat in range(args.repeats):
        load = os.getloadavg()[0]
        client_cpu = time.process_time()  # the client is this process's only work while the graph runs
        graph, latency, steps, cpu, seen = through_graph(args.episodes, args.controller, nodes, client=client)
        client_cpu = (time.process_time() - client_cpu) / steps * 1e3
        local, local_cpu = in_process(config, args.controller)
        per_step = {node: cpu[node] / steps * 1e3 for node in cpu}
        print(f"run {repeat + 1}{setting}: graph {graph:.1f} "
              f"steps/s, in-process {local:.1f} steps/s, graph/in-process time ratio {local / graph:.2f} (target <= "
              f"{target}; graph target >= 30 steps/s); separator node {latency}; load average {load:.2f} -> "
              f"{os.getloadavg()[0]:.2f}", flush=True)
        hosted = " + live view" if "live_view_node" in nodes and "live_view_node" not in cpu else ""
        per_node = ", ".join(f"{node.removesuffix('_node')}{hosted if node == 'recorder_node' else ''} {ms:.1f}"
                             for node, ms in per_step.items())
        print(f"  CPU ms per step: {per_node}; "
              f"graph total {sum(per_step.values()):.1f} vs in-process {local_cpu:.1f}", flush=True)
        if seen is not None:
            print(f"  the client received {sum(seen.counts.values())} messages on {len(seen.counts)} of "
                  f"{len(seen.channels)} topics, {seen.received_bytes / 1e6:.0f} MB, on {client_cpu:.1f} CPU ms "
                  "per step of the same cores", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
