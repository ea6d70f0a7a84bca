"""Experiment 6 of the supplementary material: which quality measure rewards pi^Q best.

Each pi^Q run (``scripts/train_policy.py --kind quality --quality-reward <measure>``, the same seed,
episodes and budget) plays the same near-target test episodes as Stand In-Place; the report gives the
final-step SI-SDR with 95% CI, each run's paired difference to Stand In-Place, its training time
(wall seconds, env steps/s, CPU ms per env step from the run's log) and the training curves.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from m2h_ros import sim_world
from m2h_ros.agents.registry import controller_class
from m2h_ros.core.plotting import agg_pyplot
from m2h_ros.core.results import EpisodeResult
from m2h_ros.core.world.env import EnvConfig
from m2h_ros.core.world.episodes import EpisodeConfig, episodes_for
from m2h_ros.errors import ConfigError
from m2h_ros.experiments.jobs import EvalJob, run_eval_job, run_jobs
from m2h_ros.experiments.training_log import read_training_log
from m2h_ros.paths import repo_relative

REFERENCE = "stand_in_place"
POLICY = "move2hear_quality"  # the registry's pi^Q controller, given each run's policy.pt
# What may differ between the compared runs: the reward, and where they ran.
VARYING = ("quality_reward", "threads", "device", "checkpoint_every")


@dataclass(frozen=True)
class RewardRun:
    """One trained pi^Q: its run directory's settings, log and training time."""

    label: str  # the results' controller name, "pi^Q (<measure>)"
    directory: Path
    config: dict
    metadata: dict  # policy.pt's (command, updates, env steps, wall seconds, machine)
    log: list[dict[str, float]]

    @property
    def policy(self) -> Path:
        return self.directory / "policy.pt"

    def timing(self) -> dict:
        """Wall time, env steps/s over the run, and the per-update medians the log holds."""
        wall, steps = float(self.metadata["wall_seconds"]), int(self.metadata["env_steps"])
        return {"updates": int(self.metadata["updates"]), "env_steps": steps, "wall_seconds": wall,
                "env_steps_per_s": steps / wall,
                "median_update_env_steps_per_s": float(np.median([r["sps"] for r in self.log])),
                "median_cpu_ms_per_env_step": float(np.median([r["cpu_ms_per_step"] for r in self.log])),
                "median_separator_and_reward_share": float(np.median([r["separator_share"] for r in self.log])),
                "command": self.metadata["command"]}


def load_run(directory: Path) -> RewardRun:
    """A finished pi^Q run directory (config.json, policy.pt, log.csv), f^R frozen."""
    from m2h_ros.models.policy import load_policy  # noqa: PLC0415  (torch, only when runs are read)

    directory = Path(directory).resolve()  # the policy path goes to Ray workers, whose folder may differ
    try:
        config = json.loads((directory / "config.json").read_text())
        log = read_training_log(directory)
    except (OSError, ValueError, ConfigError) as exc:
        raise ConfigError(f"{directory} is not a finished training run: {exc}") from exc
    if config.get("kind") != "quality":
        raise ConfigError(f"{directory} trained {config.get('kind')!r}, not pi^Q (quality)")
    metadata = load_policy(directory / "policy.pt", policy_kind="quality").metadata
    if metadata.get("refiner_trained"):
        raise ConfigError(f"{directory} trained f^R beside pi^Q: compare runs with --frozen-refiner, "
                          "so that every controller plays with the same separator")
    if metadata["updates"] != config["updates"]:
        raise ConfigError(f"{directory} stopped at update {metadata['updates']} of {config['updates']}")
    if "quality_reward" not in config:
        raise ConfigError(f"{directory} was trained before --quality-reward existed: retrain it")
    return RewardRun(f"pi^Q ({config['quality_reward']})", directory, config, metadata, log)


def check_comparable(runs: Sequence[RewardRun]) -> None:
    """The runs differ in their reward only (and where they ran): same seed, episodes, budget. Runs that
    continue earlier ones (a second stage, ``--init-policy``) may each start from their own reward's
    earlier run, if those are comparable in turn."""
    if len({r.label for r in runs}) != len(runs):
        raise ConfigError(f"two runs share a reward: {[r.label for r in runs]}")
    starts = [r.config.get("init_policy") or "" for r in runs]
    own_starts = len(set(starts)) > 1
    first = runs[0].config
    for run in runs[1:]:
        changed = sorted(k for k in set(first) | set(run.config) if k not in VARYING
                         and not (own_starts and k == "init_policy") and first.get(k) != run.config.get(k))
        if changed:
            raise ConfigError(f"{run.directory} differs from {runs[0].directory} in {', '.join(changed)}")
    if own_starts:
        if not all(starts):
            raise ConfigError("some runs start from a policy (--init-policy) and some from scratch")
        earlier = [load_run(Path(start).parent) for start in starts]
        for run, stage in zip(runs, earlier, strict=True):
            if stage.label != run.label:
                raise ConfigError(f"{run.directory} continues {stage.directory}, which trained {stage.label}")
        check_comparable(earlier)


def reward_jobs(runs: Sequence[RewardRun], *, sound_splits: Sequence[str], count: int, chunk: int,
                seed: int) -> list[EvalJob]:
    """Stand In-Place and every run's pi^Q on the first ``count`` near-target test episodes of each split."""
    separator = runs[0].config["separator"]  # "" the shipped one (the runs share it: check_comparable)
    library = sim_world.sound_library("")
    players = [(REFERENCE, "", REFERENCE), *((POLICY, str(r.policy), r.label) for r in runs)]
    jobs = []
    for split in sound_splits:
        chosen = episodes_for(EpisodeConfig(task="near_target", scene_split="test", sound_split=split), library)[:count]
        for name, checkpoint, label in players:
            env = EnvConfig(camera=controller_class(name).uses_camera)
            for first in range(0, len(chosen), chunk):
                jobs.append(EvalJob(controller=name, episodes=tuple(chosen[first:first + chunk]), env=env,
                                    separator=separator, controller_checkpoint=checkpoint, condition=label, seed=seed))
    return jobs


def run_reward_jobs(jobs: Sequence[EvalJob], *, workers: int, address: str | None = None,
                    progress: bool = True) -> list[EpisodeResult]:
    """Every job; each result named by its player (the condition), so the runs' pi^Q stay apart."""
    outputs = run_jobs(run_eval_job, jobs, workers=workers, address=address, progress=progress, desc="reward")
    return [dataclasses.replace(r, controller=r.condition) for output in outputs for r in output]


def plot_training(runs: Sequence[RewardRun], path: Path) -> Path:
    """Final NMSE (the measure every run logs), value loss (in each reward's units) and entropy vs env steps."""
    plt = agg_pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(15, 4))
    for run in runs:
        steps = [r["env_steps"] for r in run.log]
        for ax, key in zip(axes, ("final_nmse_window", "value_loss", "entropy"), strict=True):
            ax.plot(steps, [r[key] for r in run.log], label=run.label)
    titles = ("final NMSE, last 50 episodes (lower is better)", "value loss (the reward's units squared)",
              "policy entropy")
    for ax, title in zip(axes, titles, strict=True):
        ax.set(title=title, xlabel="environment steps")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    axes[1].set_yscale("log")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def timing_table(runs: Sequence[RewardRun]) -> str:
    head = ["run", "updates", "env steps", "wall (s)", "env steps/s", "median steps/s per update",
            "median CPU ms / env step", "separator + reward share"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for run in runs:
        t = run.timing()
        lines.append(f"| {run.label} | {t['updates']} | {t['env_steps']} | {t['wall_seconds']:.0f} | "
                     f"{t['env_steps_per_s']:.1f} | {t['median_update_env_steps_per_s']:.1f} | "
                     f"{t['median_cpu_ms_per_env_step']:.2f} | {100 * t['median_separator_and_reward_share']:.0f}% |")
    return "\n".join(lines) + "\n"


def describe_runs(runs: Sequence[RewardRun]) -> list[dict]:
    """What results.json records of each run: where it is, its command and its training time."""
    return [{"label": r.label, "directory": repo_relative(r.directory), "quality_reward": r.config["quality_reward"],
             "seed": r.config["seed"], **r.timing(), "machine": r.metadata.get("machine")} for r in runs]
