"""Where a controller's walk takes the robot relative to the target, from results already written.

Each episode's recorded actions are replayed on its scene's navigation grid (moves are deterministic:
BatchEnv's rule, MoveForward follows ``grid.forward``, turns change the heading, an action that never
came (-1) holds), giving the geodesic distance to the target's node after every step. Summarised per
controller, experiment condition, task and sound split: the mean distance at the start, halfway and at the end, and the share
of episodes that end on the target's node or were on it at some step. It says whether a controller that
hears the target worse than an oracle failed to find it or found it and left; with a reference
controller on the same episodes, :func:`gain_by_reach` gives the final-step SI-SDR gain over it in each
of those three groups.

    python scripts/experiments/reach.py runs/near_test/results.json [--reference stand_in_place] [--out reach.md]
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from m2h_ros.core.plotting import agg_pyplot, save_line_plot
from m2h_ros.core.results import EpisodeResult
from m2h_ros.core.world.episodes import MOVE_FORWARD, TURN_LEFT, TURN_RIGHT, Episode
from m2h_ros.core.world.navgrid import turn_left, turn_right
from m2h_ros.errors import ConfigError


def geodesic_trace(episode: Episode, actions: Sequence[int]) -> np.ndarray:
    """(len(actions) + 1,) geodesic metres from the robot to the target's node before the first action
    and after each one."""
    grid = episode.scene().grid
    node, heading, goal = episode.start_node, episode.start_heading, episode.target_node
    trace = [grid.geodesic[node, goal]]
    for action in actions:
        if action == MOVE_FORWARD:
            node = int(grid.forward[node, heading])
        elif action == TURN_LEFT:
            heading = turn_left(heading)
        elif action == TURN_RIGHT:
            heading = turn_right(heading)
        trace.append(grid.geodesic[node, goal])
    return np.asarray(trace, np.float64)


@dataclass(frozen=True)
class Reach:
    """One controller's walks in one experiment condition, task and sound split."""

    controller: str
    condition: str  # what an experiment varied ("" outside experiments)
    task: str
    sound_split: str
    episodes: int
    start_m: float  # mean geodesic distance to the target's node before the first action
    halfway_m: float  # ... after half the steps of the longest episode (one that stopped earlier: where it stopped)
    final_m: float  # ... after the last action
    ends_on_target: float  # share of episodes whose last pose is on the target's node
    ever_on_target: float  # share that were on it after some action


def _trace(result: EpisodeResult, episodes: Mapping[str, Episode]) -> np.ndarray:
    episode = episodes.get(result.episode_id)
    trace = None if episode is None else geodesic_trace(episode, result.actions)
    # An id names its split, task, sound split and scenario, not every episode setting: check the start.
    if trace is None or episode.scene_id != result.scene_id or abs(trace[0] - result.shortest_path) > 1e-6:
        raise ConfigError(f"episode {result.episode_id!r} of the results is not among the episodes given "
                          f"(results made with other episode settings?)")
    return trace


def _traces(results: Iterable[EpisodeResult], episodes: Mapping[str, Episode]
            ) -> dict[tuple[str, str, str, str], list[np.ndarray]]:
    """Each (controller, condition, task, sound split)'s geodesic traces, sorted by that key."""
    traces: dict[tuple[str, str, str, str], list[np.ndarray]] = {}
    for result in results:
        key = (result.controller, result.condition, result.task, result.sound_split)
        traces.setdefault(key, []).append(_trace(result, episodes))
    return dict(sorted(traces.items()))


def _padded(group: list[np.ndarray]) -> np.ndarray:
    """(episodes, longest + 1): an episode that ended early (Stop) stays where it stopped."""
    length = max(len(t) for t in group)
    return np.array([np.pad(t, (0, length - len(t)), mode="edge") for t in group])


REACH_GROUPS = ("ends on target", "left it", "never on it")


def walk_group(trace: np.ndarray) -> str:
    """Which of :data:`REACH_GROUPS` a walk's geodesic trace falls in (on the target's node after some action)."""
    if trace[-1] == 0:
        return REACH_GROUPS[0]
    return REACH_GROUPS[1] if (trace[1:] == 0).any() else REACH_GROUPS[2]


def reach_table(results: Iterable[EpisodeResult], episodes: Mapping[str, Episode]) -> list[Reach]:
    """:class:`Reach` rows, sorted by controller, condition, task and split; ``episodes`` by episode id."""
    rows = []
    for (controller, condition, task, split), group in _traces(results, episodes).items():
        padded, groups = _padded(group), [walk_group(t) for t in group]
        rows.append(Reach(controller, condition, task, split, len(group), start_m=float(padded[:, 0].mean()),
                          halfway_m=float(padded[:, (padded.shape[1] - 1) // 2].mean()),
                          final_m=float(np.mean([t[-1] for t in group])),
                          ends_on_target=groups.count(REACH_GROUPS[0]) / len(groups),
                          ever_on_target=1 - groups.count(REACH_GROUPS[2]) / len(groups)))
    return rows


def plot_reach(results: Iterable[EpisodeResult], episodes: Mapping[str, Episode], path: str | Path) -> Path:
    """Mean geodesic distance to the target's node vs step, one line per controller, condition, task and split
    (an episode that ended early, by Stop, stays where it stopped)."""
    plt = agg_pyplot()
    fig, ax = plt.subplots(figsize=(7, 4.2))
    for (controller, condition, task, split), group in _traces(results, episodes).items():
        padded = _padded(group)
        label = ", ".join(x for x in (controller, condition, task, split) if x)
        ax.plot(np.arange(padded.shape[1]), padded.mean(0), label=f"{label} (n={len(group)})")
    ax.set(xlabel="step", ylabel="geodesic distance to the target's node (m)", ylim=(0, None))
    return save_line_plot(fig, ax, path)


def gain_by_reach(results: Sequence[EpisodeResult], episodes: Mapping[str, Episode], *, reference: str
                  ) -> list[tuple[str, str, str, str, str, int, float]]:
    """(controller, condition, task, sound split, group, episodes, mean final-step SI-SDR minus ``reference``'s
    on the same episode and condition) for each controller but the reference and each of :data:`REACH_GROUPS`
    it has episodes in. A reference played without a condition (``scripts/evaluate.py``) serves every condition
    of a sweep on the same episodes."""
    final = {(r.episode_id, r.condition): r.si_sdr[-1] for r in results if r.controller == reference}
    if not final:
        raise ConfigError(f"no episodes of the reference {reference!r} in the results")
    gains: dict[tuple[str, str, str, str, str], list[float]] = {}
    for result in results:
        if result.controller == reference:
            continue
        key = (result.episode_id, result.condition)
        if key not in final:  # a reference played without a condition
            key = (result.episode_id, "")
        if key not in final:
            raise ConfigError(f"{result.controller} played {result.episode_id!r}, {reference} did not")
        group = walk_group(_trace(result, episodes))
        gains.setdefault((result.controller, result.condition, result.task, result.sound_split, group), []).append(
            result.si_sdr[-1] - final[key])
    order = {g: i for i, g in enumerate(REACH_GROUPS)}
    return [(*key, len(values), float(np.mean(values)))
            for key, values in sorted(gains.items(), key=lambda kv: (*kv[0][:4], order[kv[0][4]]))]


def gain_markdown(rows: Sequence[tuple[str, str, str, str, str, int, float]], *, reference: str) -> str:
    lines = [f"| controller | condition | task | sound_split | walk | episodes | final SI-SDR minus {reference}'s (dB) |",
             "|---|---|---|---|---|---|---|"]
    lines += [f"| {c} | {k} | {t} | {s} | {g} | {n} | {gain:+.2f} |" for c, k, t, s, g, n, gain in rows]
    return "\n".join(lines)


def reach_markdown(rows: Sequence[Reach]) -> str:
    lines = ["| controller | condition | task | sound_split | episodes | start (m) | halfway (m) | final (m) "
             "| ends on target | ever on target |", "|---|---|---|---|---|---|---|---|---|---|"]
    lines += [f"| {r.controller} | {r.condition} | {r.task} | {r.sound_split} | {r.episodes} | {r.start_m:.2f} | {r.halfway_m:.2f} "
              f"| {r.final_m:.2f} | {r.ends_on_target:.3f} | {r.ever_on_target:.3f} |" for r in rows]
    return "\n".join(lines)
