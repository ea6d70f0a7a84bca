"""Episode results and the tables and plots made of them: shared by the evaluator node,
``scripts/evaluate.py`` and offline replay scoring, so every tool reports the same numbers the same way.

An :class:`EpisodeTracker` collects one episode as it runs (per-step scores, actions, positions) and
finishes into an :class:`EpisodeResult`. :func:`summarize` gives per-group means with 95% confidence
intervals (Student t over episodes); :func:`write_results` writes Markdown, CSV and JSON tables and the
SI-SDR-vs-step plot.

Navigation (far-target): success = the episode ended with Stop on the target's node; SPL = success x
shortest path / max(path length, shortest path) (Anderson et al. 2018), path length = metres moved.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from m2h_ros.core.plotting import agg_pyplot, save_line_plot
from m2h_ros.core.world.episodes import STOP
from m2h_ros.errors import ConfigError

HELD = -1  # an action slot no command filled in time (free-running mode held the robot), AgentPose.last_action too
METRICS = ("si_sdr", "si_sdr_mixture_phase", "stft_distance")
# Per-episode figures of navigation, paired like the final-step scores (far-target: a policy that walks better).
EPISODE_METRICS = ("success", "spl")
PAIRED_METRICS = METRICS + EPISODE_METRICS
METRIC_LABELS = {"si_sdr": "SI-SDR (dB, GT phase)", "si_sdr_mixture_phase": "SI-SDR (dB, mixture phase)",
                 "stft_distance": "STFT distance", "success": "success (SR, 0 or 1)", "spl": "SPL"}


@dataclass
class EpisodeResult:
    episode_id: str
    controller: str
    task: str
    sound_split: str
    scene_id: str
    target_class: str
    actions: list[int] = field(default_factory=list)  # action answering observation k, k = 0..T-1 (-1: none came, held)
    si_sdr: list[float] = field(default_factory=list)  # per observation k = 0..T
    si_sdr_mixture_phase: list[float] = field(default_factory=list)
    stft_distance: list[float] = field(default_factory=list)
    path_length: float = 0.0  # metres moved
    shortest_path: float = 0.0  # geodesic metres from the start to the target
    success: bool = False  # far-target: stopped on the target's node
    condition: str = ""  # what an experiment varied for this run (e.g. "mic noise 0.1, f^M"); "" otherwise

    @property
    def steps(self) -> int:
        return len(self.actions)

    @property
    def spl(self) -> float:
        if not self.success:
            return 0.0
        return self.shortest_path / max(self.path_length, self.shortest_path, 1e-9)

    def final(self, metric: str) -> float:
        """The last step's ``metric`` (one of METRICS), or the episode's ``success`` / ``spl``."""
        value = getattr(self, metric)
        return float(value) if metric in EPISODE_METRICS else float(value[-1])

    def to_dict(self) -> dict:
        return {**dataclasses.asdict(self), "spl": self.spl}

    @classmethod
    def from_dict(cls, values: dict) -> EpisodeResult:
        names = {f.name for f in dataclasses.fields(cls)}
        return cls(**{k: v for k, v in values.items() if k in names})


class EpisodeTracker:
    """Builds one EpisodeResult step by step: ``observe`` each scored observation in step order,
    ``act`` each action, then ``finish``."""

    def __init__(self, result: EpisodeResult, start_position: np.ndarray) -> None:
        self.result = result
        self.position = np.asarray(start_position, np.float64)[:2]
        self.at_target = False

    def observe(self, step: int, *, si_sdr: float, si_sdr_mixture_phase: float, stft_distance: float,
                position: np.ndarray, at_target: bool) -> None:
        r = self.result
        if step != len(r.si_sdr):
            raise ConfigError(f"episode {r.episode_id}: step {step} scored out of order "
                              f"(expected step {len(r.si_sdr)})")
        r.si_sdr.append(float(si_sdr))
        r.si_sdr_mixture_phase.append(float(si_sdr_mixture_phase))
        r.stft_distance.append(float(stft_distance))
        new = np.asarray(position, np.float64)[:2]
        r.path_length += float(np.linalg.norm(new - self.position))
        self.position, self.at_target = new, bool(at_target)

    def act(self, step: int, action: int) -> None:
        r = self.result
        if step != len(r.actions):
            raise ConfigError(f"episode {r.episode_id}: action for step {step} out of order "
                              f"(expected step {len(r.actions)})")
        r.actions.append(int(action))

    def finish(self) -> EpisodeResult:
        r = self.result
        if len(r.si_sdr) != len(r.actions) + 1:
            raise ConfigError(f"episode {r.episode_id}: {len(r.si_sdr)} scored observations for "
                              f"{len(r.actions)} actions (expected one more observation)")
        r.success = r.task == "far_target" and bool(r.actions) and r.actions[-1] == STOP and self.at_target
        return r


def mean_sem(values: Sequence[float] | np.ndarray) -> tuple[float, float]:
    """Mean and its standard error (sample standard deviation / sqrt(n); 0 for one value, NaN for none):
    how the tools report a paired difference, mean ± standard error over the same episodes."""
    x = np.asarray(values, np.float64)
    if x.size == 0:
        return math.nan, math.nan
    if x.size == 1:
        return float(x[0]), 0.0
    return float(x.mean()), float(x.std(ddof=1) / math.sqrt(x.size))


def mean_ci(values: Sequence[float], *, level: float = 0.95) -> tuple[float, float]:
    """Mean and half-width of its ``level`` confidence interval (Student t; 0 for one value)."""
    # Student's t quantile from scipy.special, which scipy.stats.t.ppf calls: the same number without
    # scipy.stats, whose import (0.5 s of CPU) fell in the middle of a run, when the evaluator first writes.
    from scipy.special import stdtrit

    mean, sem = mean_sem(values)
    if np.size(values) < 2:
        return mean, sem
    return mean, float(stdtrit(np.size(values) - 1, 0.5 + level / 2) * sem)


GROUP_KEYS = ("controller", "task", "sound_split")


def summarize(results: Iterable[EpisodeResult], *, by: Sequence[str] = GROUP_KEYS) -> list[dict]:
    """One row per group: episodes, final-step mean and 95% CI of every metric, SR and SPL."""
    groups: dict[tuple, list[EpisodeResult]] = {}
    for r in results:
        groups.setdefault(tuple(getattr(r, k) for k in by), []).append(r)
    rows = []
    for key, members in groups.items():
        row = dict(zip(by, key))
        row["episodes"] = len(members)
        for metric in METRICS:
            row[metric], row[f"{metric}_ci95"] = mean_ci([m.final(metric) for m in members])
        far = [m for m in members if m.task == "far_target"]
        row["success_rate"] = float(np.mean([m.success for m in far])) if far else None
        row["spl"] = float(np.mean([m.spl for m in far])) if far else None
        rows.append(row)
    return rows


def paired_differences(results: Iterable[EpisodeResult], *, reference: str | Mapping[str, str],
                       metric: str = "si_sdr", by: Sequence[str] = GROUP_KEYS, vary: str = "controller") -> list[dict]:
    """Final-step ``metric`` of each other ``vary`` value minus ``reference``'s on the same episodes,
    mean and 95% CI per group of ``by`` (which holds ``vary``): the paired comparison is much tighter
    than comparing the two means, since episodes vary far more than controllers (or separators) do.
    Default: each controller against ``reference`` per (task, sound split). A mapping pairs each ``vary``
    value it names with its own reference (e.g. a sweep's condition with its "no f^R" twin)."""
    if metric not in PAIRED_METRICS:
        raise ConfigError(f"unknown metric {metric!r}; one of {PAIRED_METRICS}")
    if vary not in by:
        raise ConfigError(f"paired_differences: {vary!r} must be one of the grouping fields {tuple(by)}")
    at = list(by).index(vary)
    finals: dict[tuple, dict[str, float]] = {}
    for r in results:
        finals.setdefault(tuple(getattr(r, k) for k in by), {})[r.episode_id] = r.final(metric)
    rows = []
    for key, values in finals.items():
        against = reference if isinstance(reference, str) else reference.get(key[at])
        base = finals.get((*key[:at], against, *key[at + 1:]))
        if key[at] == against or base is None:
            continue
        shared = sorted(values.keys() & base.keys())
        if not shared:
            continue
        mean, half = mean_ci([values[e] - base[e] for e in shared])
        rows.append({**dict(zip(by, key)), "reference": against, "metric": metric, "episodes": len(shared),
                     "difference": mean, "ci95": half})
    return rows


def forest_order(rows: Sequence[dict]) -> list[str]:
    """The controllers of ``paired_differences`` rows, lowest mean difference (over the rows' splits) first."""
    means: dict[str, list[float]] = {}
    for row in rows:
        means.setdefault(row["controller"], []).append(row["difference"])
    return sorted(means, key=lambda c: (float(np.mean(means[c])), c))


def plot_paired(rows: Sequence[dict], path: str | Path, *, title: str = "") -> Path:
    """Forest plot of ``paired_differences`` rows: one panel per (reference, task), one line per
    controller (the best on top), its mean difference and 95% CI per sound split, zero marked."""
    plt = agg_pyplot()
    if not rows:
        raise ConfigError("no paired differences to plot (does any controller share episodes with the reference?)")
    panels: dict[tuple[str, str], list[dict]] = {}
    for row in rows:
        panels.setdefault((row["reference"], row["task"]), []).append(row)
    splits = list(dict.fromkeys(r["sound_split"] for r in rows))
    orders = {panel: forest_order(mine) for panel, mine in panels.items()}
    tallest = max(len(order) for order in orders.values())
    fig, axes = plt.subplots(1, len(panels), figsize=(5.2 * len(panels), 1.3 + 0.38 * tallest), squeeze=False)
    for ax, ((reference, task), mine) in zip(axes[0], panels.items()):
        order = orders[reference, task]
        for at, split in enumerate(splits):
            # Splits side by side on each controller's line, so their intervals do not hide each other.
            offset = (at - (len(splits) - 1) / 2) * 0.22
            points = [r for r in mine if r["sound_split"] == split]
            ax.errorbar([r["difference"] for r in points], [order.index(r["controller"]) + offset for r in points],
                        xerr=[r["ci95"] for r in points], fmt="o", markersize=4, capsize=2, label=split)
        ax.axvline(0.0, color="black", linewidth=0.8)
        ax.set_yticks(range(len(order)), order, fontsize=8)
        ax.set_xlabel(f"{METRIC_LABELS[mine[0]['metric']]}\nminus {reference}'s")
        ax.set_title(f"{title} {task}".strip(), fontsize=10)
        ax.grid(axis="x", alpha=0.3)
        ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return Path(path)


def paired_table(rows: Sequence[dict], *, by: Sequence[str] = GROUP_KEYS) -> str:
    head = [*by, "episodes", "difference (mean ± 95% CI)"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in rows:
        cells = [str(row[k]) for k in by]
        lines.append(f"| {' | '.join(cells)} | {row['episodes']} | {row['difference']:+.2f} ± {row['ci95']:.2f} |")
    return "\n".join(lines) + "\n"


def paired_section(rows: Sequence[dict], *, reference: str, metric: str = "si_sdr",
                   by: Sequence[str] = GROUP_KEYS) -> str:
    """``paired_differences`` rows under a heading naming the metric and the reference."""
    what = f"Episode {METRIC_LABELS[metric]}" if metric in EPISODE_METRICS else f"Final-step {METRIC_LABELS[metric]}"
    return (f"{what} minus {reference}'s on the same episodes:\n\n"
            f"{paired_table(rows, by=by)}")


def _cell(value) -> str:
    if value is None:
        return "-"
    return f"{value:.3f}" if isinstance(value, float) else str(value)


def markdown_table(rows: Sequence[dict], *, by: Sequence[str] = GROUP_KEYS) -> str:
    """The paper-style table: final-step metrics as mean ± 95% CI, SR and SPL where they apply."""
    head = [*by, "episodes", *(METRIC_LABELS[m] for m in METRICS), "SR", "SPL"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in rows:
        cells = [str(row[k]) for k in by] + [str(row["episodes"])]
        cells += [f"{row[m]:.2f} ± {row[f'{m}_ci95']:.2f}" for m in METRICS]
        cells += [_cell(row["success_rate"]), _cell(row["spl"])]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def write_results(results: Sequence[EpisodeResult], out_dir: str | Path, *, title: str = "Results",
                  meta: dict | None = None, plot: bool = True, command: str | None = None,
                  setup: str | None = None, reference: str | None = None,
                  by: Sequence[str] = GROUP_KEYS) -> dict[str, Path]:
    """Write results.md, results.csv (one row per episode), results.json (episodes + summary + meta)
    and si_sdr_vs_step.png into ``out_dir``; returns the paths by kind. ``command``, the one line that
    reproduces the results, heads the Markdown table, with ``setup`` (the models and data it ran on,
    which the command alone does not pin); with ``reference`` (a controller's name), the
    Markdown also has every other controller's paired SI-SDR (GT phase) difference to it. ``by``: the
    result fields the table groups by (experiments add "condition")."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rows = summarize(results, by=by)
    paths = {"markdown": out / "results.md", "csv": out / "results.csv", "json": out / "results.json"}
    note = ("Final-step scores, mean ± 95% CI over episodes. SI-SDR (GT phase): the estimate rebuilt "
            "with the clean target's phase vs the dry target (the paper's reported variant); SI-SDR "
            "(mixture phase): rebuilt with the mixture's phase (deployable); STFT distance: the original "
            "code's, the estimate with the target's phase vs the target's spectrogram, mean squared "
            "real/imaginary difference.\n")
    how = (f"Command: `{command}`\n\n" if command else "") + (f"Setup: {setup}\n\n" if setup else "")
    paired = paired_differences(results, reference=reference, by=by) if reference else []
    versus = f"\n{paired_section(paired, reference=reference, by=by)}" if paired else ""
    paths["markdown"].write_text(f"# {title}\n\n{how}{note}\n{markdown_table(rows, by=by)}{versus}")
    with paths["csv"].open("w", newline="") as stream:
        writer = csv.writer(stream)
        writer.writerow(["episode_id", *GROUP_KEYS, "condition", "scene_id", "target_class", "steps",
                         *(f"final_{m}" for m in METRICS), "success", "spl", "path_length", "shortest_path"])
        for r in results:
            writer.writerow([r.episode_id, r.controller, r.task, r.sound_split, r.condition, r.scene_id, r.target_class,
                             r.steps, *(f"{r.final(m):.6f}" for m in METRICS), int(r.success),
                             f"{r.spl:.6f}", f"{r.path_length:.3f}", f"{r.shortest_path:.3f}"])
    paths["json"].write_text(json.dumps({"meta": meta or {}, "summary": rows, "paired": paired,
                                         "episodes": [r.to_dict() for r in results]}, indent=1))
    if plot and results:
        paths["plot"] = plot_si_sdr_vs_step(results, out / "si_sdr_vs_step.png", title=title)
    return paths


def read_results(path: str | Path) -> list[EpisodeResult]:
    """The episodes of a results.json written by :func:`write_results`."""
    try:
        document = json.loads(Path(path).read_text())
        return [EpisodeResult.from_dict(e) for e in document["episodes"]]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ConfigError(f"cannot read results file {path}: {exc}") from exc


def read_final_scores(path: str | Path) -> list[EpisodeResult]:
    """The episodes of a results.csv written by :func:`write_results`: final-step scores only (each metric's
    list holds its last value, 6 decimals; no actions). Enough for paired differences against tables
    committed as CSV (the results.json beside them is not kept in git)."""
    try:
        with Path(path).open(newline="") as stream:
            rows = list(csv.DictReader(stream))
        return [EpisodeResult(episode_id=row["episode_id"], controller=row["controller"], task=row["task"],
                              sound_split=row["sound_split"], scene_id=row["scene_id"],
                              target_class=row["target_class"], condition=row["condition"],
                              **{m: [float(row[f"final_{m}"])] for m in METRICS}, success=bool(int(row["success"])),
                              path_length=float(row["path_length"]), shortest_path=float(row["shortest_path"]))
                for row in rows]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ConfigError(f"cannot read results file {path}: {exc}") from exc


def plot_si_sdr_vs_step(results: Sequence[EpisodeResult], path: str | Path, *, title: str = "") -> Path:
    """Mean SI-SDR (GT phase) per step with its 95% CI band, one line per controller and task."""
    plt = agg_pyplot()
    groups: dict[tuple[str, str, str], list[EpisodeResult]] = {}
    for r in results:
        groups.setdefault((r.controller, r.task, r.sound_split), []).append(r)
    fig, ax = plt.subplots(figsize=(7, 4.2))
    # One colour per controller, one line style per task and split, so up to 10 controllers stay apart.
    colours = {c: plt.cm.tab10(i % 10) for i, c in enumerate(dict.fromkeys(k[0] for k in sorted(groups)))}
    styles = {k: ("-", "--", ":", "-.")[i % 4] for i, k in enumerate(dict.fromkeys(k[1:] for k in sorted(groups)))}
    for (controller, task, split), members in sorted(groups.items()):
        length = min(len(m.si_sdr) for m in members)  # Stop can end far-target episodes early
        per_step = np.array([m.si_sdr[:length] for m in members])
        stats_ = [mean_ci(per_step[:, k]) for k in range(length)]
        mean = np.array([s[0] for s in stats_])
        half = np.array([s[1] for s in stats_])
        steps = np.arange(length)
        colour = colours[controller]
        ax.plot(steps, mean, color=colour, linestyle=styles[task, split],
                label=f"{controller} ({task}, {split}, n={len(members)})")
        ax.fill_between(steps, mean - half, mean + half, color=colour, alpha=0.1)
    ax.set_xlabel("step")
    ax.set_ylabel("SI-SDR (dB, GT phase)")
    ax.set_title(title)
    return save_line_plot(fig, ax, path)
