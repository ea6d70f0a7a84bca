"""A sweep: controllers x tasks x sound splits x conditions on the test episodes, as Ray jobs, and its
report (the results table grouped by condition, and final-step SI-SDR against the swept value).

The experiment scripts in ``scripts/experiments/`` each say which conditions they sweep; this module
builds the jobs (chunks of episodes), runs them with :func:`~m2h_ros.experiments.jobs.run_jobs`
and writes the report.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from m2h_ros import sim_world
from m2h_ros.agents.registry import controller_class, is_learned
from m2h_ros.core.plotting import agg_pyplot
from m2h_ros.core.results import EpisodeResult, mean_ci, paired_differences, paired_table, write_results
from m2h_ros.core.sounds.library import SoundLibrary
from m2h_ros.core.world.env import EnvConfig
from m2h_ros.core.world.episodes import EpisodeConfig, episodes_for
from m2h_ros.errors import ConfigError
from m2h_ros.experiments.jobs import EvalJob, run_eval_job, run_jobs
from m2h_ros.machine import load_averages

ESTIMATE_LABELS = {"refined": "f^R", "monaural": "no f^R"}
SWEEP_KEYS = ("controller", "condition", "task", "sound_split")


@dataclass(frozen=True)
class Condition:
    """One point of a sweep: what it changes in the episodes, the environment and the scoring."""

    label: str  # the results' ``condition``
    x: float | str  # its place on the plot's x axis
    series: str = ""  # appended to the controller in the legend (e.g. "no f^R")
    episodes: dict = field(default_factory=dict)  # EpisodeConfig overrides
    env: dict = field(default_factory=dict)  # EnvConfig overrides
    controller: dict = field(default_factory=dict)  # learned controllers' options (make_controller)
    estimate: str = "refined"
    separator: str = ""  # separator checkpoint (absolute path: Ray workers); "" the shipped one


@dataclass(frozen=True)
class Sweep:
    controllers: Sequence[str]
    tasks: Sequence[str]
    sound_splits: Sequence[str]
    conditions: Sequence[Condition]
    count: int = 200  # test episodes per task x split x condition
    chunk: int = 50  # episodes per job
    seed: int = 0  # stochastic controllers
    library: str | SoundLibrary = ""  # sim_world.sound_library name, or a library in memory
    controller_checkpoint: str = ""  # the learned controllers' policy file or folder (absolute); "" the shipped ones

    def __post_init__(self) -> None:
        if self.count < 1 or self.chunk < 1:
            raise ConfigError(f"count and chunk must be >= 1, got {self.count} and {self.chunk}")
        for name in self.controllers:
            controller_class(name)  # unknown names fail before any job runs


def sweep_jobs(sweep: Sweep, library: SoundLibrary) -> tuple[list[EvalJob], list[tuple]]:
    """The jobs and, per job, its (controller, task, split, condition index) key."""
    jobs, keys = [], []
    for task in sweep.tasks:
        for split in sweep.sound_splits:
            for index, cond in enumerate(sweep.conditions):
                config = EpisodeConfig(**{"task": task, "scene_split": "test", "sound_split": split, **cond.episodes})
                chosen = episodes_for(config, library)[:sweep.count]
                for name in sweep.controllers:
                    env = EnvConfig(**{"camera": controller_class(name).uses_camera, **cond.env})
                    for first in range(0, len(chosen), sweep.chunk):
                        jobs.append(EvalJob(controller=name, episodes=tuple(chosen[first:first + sweep.chunk]),
                                            env=env, library=sweep.library, estimate=cond.estimate,
                                            separator=cond.separator,
                                            controller_checkpoint=sweep.controller_checkpoint if is_learned(name) else "",
                                            controller_options=tuple(sorted(cond.controller.items())),
                                            condition=cond.label, seed=sweep.seed))
                        keys.append((name, task, split, index))
    return jobs, keys


def run_sweep(sweep: Sweep, *, workers: int = 1, address: str | None = None, progress: bool = True,
              desc: str = "sweep") -> tuple[list[EpisodeResult], list[dict]]:
    """Every job of the sweep; the results and one curve row per (controller, task, split, condition)."""
    library = sim_world.sound_library(sweep.library) if isinstance(sweep.library, str) else sweep.library
    jobs, keys = sweep_jobs(sweep, library)
    outputs = run_jobs(run_eval_job, jobs, workers=workers, address=address, progress=progress, desc=desc)
    finals: dict[tuple, list[float]] = {}
    for key, output in zip(keys, outputs, strict=True):
        finals.setdefault(key, []).extend(r.final("si_sdr") for r in output)
    rows = []
    for (name, task, split, index), values in finals.items():
        cond = sweep.conditions[index]
        mean, half = mean_ci(values)
        rows.append({"controller": name, "task": task, "sound_split": split, "condition": cond.label,
                     "x": cond.x, "series": cond.series, "episodes": len(values), "si_sdr": mean, "ci95": half})
    return [r for output in outputs for r in output], rows


def write_sweep(results: Sequence[EpisodeResult], rows: Sequence[dict], out: Path, *, title: str, xlabel: str,
                command: str, meta: dict, started: float, reference: str | None = None,
                condition_reference: str | Mapping[str, str] | None = None) -> dict[str, Path]:
    """results.md / .csv / .json grouped by condition, and si_sdr_vs_<x>.png; returns the paths.
    ``reference``: a controller every other one is compared with, episode by episode, per condition;
    ``condition_reference``: a condition every other one is compared with, per controller, or each
    condition's own (:func:`estimate_pairs`: with f^R against without) (both as final-step SI-SDR
    differences, GT phase, in the Markdown and in results.json)."""
    versus = (paired_differences(results, reference=condition_reference, by=SWEEP_KEYS, vary="condition")
              if condition_reference else [])
    meta = {**meta, "command": command, "wall_seconds": round(time.perf_counter() - started, 1),
            "load_average": load_averages(), "curve": list(rows),
            **({"paired_conditions": versus} if versus else {})}
    paths = write_results(results, out, title=title, meta=meta, command=command, plot=False, by=SWEEP_KEYS,
                          reference=reference)
    if versus:
        with paths["markdown"].open("a") as stream:
            against = (f"the {condition_reference!r} condition's" if isinstance(condition_reference, str)
                       else f"the same condition's {ESTIMATE_LABELS['monaural']} (f^M's estimate)")
            stream.write(f"\nFinal-step SI-SDR (dB, GT phase) minus {against}, same controller, same episodes:\n\n"
                         f"{paired_table(versus, by=SWEEP_KEYS)}")
    paths["plot"] = plot_curve(rows, out / "si_sdr_vs_condition.png", title=title, xlabel=xlabel)
    return paths


def plot_curve(rows: Sequence[dict], path: Path, *, title: str, xlabel: str) -> Path:
    """Final-step SI-SDR (mean ± 95% CI) against the swept value, one panel per task x split."""
    plt = agg_pyplot()
    panels = sorted({(r["task"], r["sound_split"]) for r in rows})
    fig, axes = plt.subplots(1, len(panels), figsize=(5.2 * len(panels), 4), squeeze=False)
    for ax, panel in zip(axes[0], panels, strict=True):
        lines: dict[tuple[str, str], list[dict]] = {}
        for r in rows:
            if (r["task"], r["sound_split"]) == panel:
                lines.setdefault((r["controller"], r["series"]), []).append(r)
        for (controller, series), points in sorted(lines.items()):
            ax.errorbar([p["x"] for p in points], [p["si_sdr"] for p in points], yerr=[p["ci95"] for p in points],
                        capsize=3, marker="o", linestyle="--" if series else "-",
                        label=f"{controller}, {series}" if series else controller)
        ax.set(title=", ".join(panel), xlabel=xlabel, ylabel="final-step SI-SDR (dB, GT phase)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def with_estimates(conditions: Sequence[Condition]) -> list[Condition]:
    """Each condition twice: scored on f^R's estimate and on f^M's (the "without f^R" ablation)."""
    return [dataclasses.replace(c, label=f"{c.label}, {ESTIMATE_LABELS[e]}", series="" if e == "refined"
                                else ESTIMATE_LABELS[e], estimate=e) for c in conditions for e in ESTIMATE_LABELS]


def estimate_pairs(conditions: Sequence[Condition]) -> dict[str, str]:
    """Each f^R condition of :func:`with_estimates` -> its "no f^R" twin (the same x): the ablation's paired
    comparison, f^R's gain on the same episodes; empty for a sweep without the twins."""
    monaural = {c.x: c.label for c in conditions if c.estimate == "monaural"}
    return {c.label: monaural[c.x] for c in conditions if c.estimate == "refined" and c.x in monaural}
