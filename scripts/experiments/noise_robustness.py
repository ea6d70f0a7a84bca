#!/usr/bin/env python3
"""Experiment 1 of the supplementary material: separation quality vs microphone noise, with and without f^R.

    python scripts/experiments/noise_robustness.py [--task near_target] [--sound-split heard,unheard]
        [--controllers stand_in_place,move2hear_quality] [--levels 0,0.05,0.1,0.2] [--count 200]
        [--workers 2] [--address ADDR] [--chunk 50] [--seed 0] [--out docs/results/noise_robustness]

Every controller plays the first ``--count`` test episodes of each task x sound split at each
microphone noise level (white noise per ear, std = level x the clean mixture's RMS: 0.05 / 0.1 / 0.2
are SNR 26 / 20 / 14 dB, the levels the separator was trained with), scored on the refined estimate
(f^R) and, in a second play of the same episodes, on f^M's estimate (no f^R). The jobs (chunks of
``--chunk`` episodes) run on Ray; the table does not depend on ``--workers``. Writes results.md /
.csv / .json (final-step SI-SDR and STFT distance, mean ± 95% CI, per controller x condition) and
si_sdr_vs_noise.png into ``--out``. The paper's finding (Supp. Sec. 2): quality falls with noise,
and f^R's memory makes Move2Hear more robust to it.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import shlex
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from m2h_ros.agents.registry import controller_class  # noqa: E402
from m2h_ros.core.results import mean_ci, write_results  # noqa: E402
from m2h_ros.core.sounds.library import SoundLibrary  # noqa: E402
from m2h_ros.core.world.env import EnvConfig  # noqa: E402
from m2h_ros.core.world.episodes import EpisodeConfig, episodes_for  # noqa: E402
from m2h_ros.errors import M2HError  # noqa: E402
from m2h_ros.experiments.jobs import EvalJob, run_eval_job, run_jobs  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
ESTIMATE_LABELS = {"refined": "f^R", "monaural": "no f^R"}


def parse_args(argv):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="near_target", help="near_target, far_target or both comma-separated")
    parser.add_argument("--sound-split", default="heard,unheard")
    parser.add_argument("--controllers", default="stand_in_place,move2hear_quality")
    parser.add_argument("--levels", default="0,0.05,0.1,0.2", help="microphone noise levels (std / mixture RMS)")
    parser.add_argument("--count", type=int, default=200, help="test episodes per task x split")
    parser.add_argument("--chunk", type=int, default=50, help="episodes per job")
    parser.add_argument("--workers", type=int, default=2, help="local Ray CPUs (ignored with --address)")
    parser.add_argument("--address", help="an existing Ray cluster ('auto': this machine's)")
    parser.add_argument("--seed", type=int, default=0, help="seed of stochastic controllers")
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "results" / "noise_robustness")
    parser.add_argument("--no-progress", action="store_true")
    return parser.parse_args(argv)


def condition(level: float, estimate: str) -> str:
    return f"mic noise {level:g}, {ESTIMATE_LABELS[estimate]}"


def plot(rows: list[dict], path: Path, *, title: str) -> Path:
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    panels = sorted({(r["task"], r["sound_split"]) for r in rows})
    fig, axes = plt.subplots(1, len(panels), figsize=(5.2 * len(panels), 4), squeeze=False)
    for ax, (task, split) in zip(axes[0], panels, strict=True):
        lines: dict[tuple[str, str], list[tuple[float, float, float]]] = {}
        for r in rows:
            if (r["task"], r["sound_split"]) == (task, split):
                lines.setdefault((r["controller"], r["estimate"]), []).append((r["level"], r["mean"], r["ci95"]))
        for (controller, estimate), points in sorted(lines.items()):
            x, y, e = zip(*sorted(points), strict=True)
            ax.errorbar(x, y, yerr=e, capsize=3, marker="o", linestyle="-" if estimate == "refined" else "--",
                        label=f"{controller}, {ESTIMATE_LABELS[estimate]}")
        ax.set(title=f"{task}, {split}", xlabel="microphone noise (std / mixture RMS)",
               ylabel="final-step SI-SDR (dB, GT phase)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def main(argv=None) -> int:
    args = parse_args(argv)
    command = shlex.join(["python", "scripts/experiments/noise_robustness.py", *(sys.argv[1:] if argv is None else argv)])
    started = time.perf_counter()
    try:
        tasks, splits = args.task.split(","), args.sound_split.split(",")
        controllers = args.controllers.split(",")
        levels = [float(v) for v in args.levels.split(",")]
        library = SoundLibrary.load()
        jobs, keys = [], []
        for task in tasks:
            for split in splits:
                episodes = episodes_for(EpisodeConfig(task=task, scene_split="test", sound_split=split), library)
                chosen = episodes[:args.count]
                for name in controllers:
                    env = EnvConfig(camera=controller_class(name).uses_camera)
                    for level in levels:
                        for estimate in ESTIMATE_LABELS:
                            for first in range(0, len(chosen), args.chunk):
                                jobs.append(EvalJob(controller=name, episodes=tuple(chosen[first:first + args.chunk]),
                                                    env=dataclasses.replace(env, mic_noise=level),
                                                    estimate=estimate, condition=condition(level, estimate),
                                                    seed=args.seed))
                                keys.append((name, task, split, level, estimate))
        outputs = run_jobs(run_eval_job, jobs, workers=args.workers, address=args.address,
                           progress=not args.no_progress, desc="noise robustness")
    except (M2HError, ValueError) as exc:
        print(f"noise_robustness: error: {exc}", file=sys.stderr)
        return 2
    results = [r for output in outputs for r in output]
    finals: dict[tuple, list[float]] = {}
    for key, output in zip(keys, outputs, strict=True):
        finals.setdefault(key, []).extend(r.final("si_sdr") for r in output)
    rows = [{"controller": k[0], "task": k[1], "sound_split": k[2], "level": k[3], "estimate": k[4],
             **dict(zip(("mean", "ci95"), mean_ci(v)))} for k, v in finals.items()]
    meta = {"command": command, "count_per_split": args.count, "levels": levels, "controller_seed": args.seed,
            "jobs": len(jobs), "workers": args.address or args.workers,
            "wall_seconds": round(time.perf_counter() - started, 1),
            "load_average": [round(x, 2) for x in os.getloadavg()], "curve": rows}
    title = "Noise robustness: final-step SI-SDR vs microphone noise"
    paths = write_results(results, args.out, title=title, meta=meta, command=command, plot=False,
                          by=("controller", "condition", "task", "sound_split"))
    paths["plot"] = plot(rows, args.out / "si_sdr_vs_noise.png", title=title)
    print(paths["markdown"].read_text())
    print(f"{len(results)} episodes in {meta['wall_seconds']} s; " + ", ".join(f"{k}: {v}" for k, v in paths.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
