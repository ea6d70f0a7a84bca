"""Passive separation (Stand In-Place, step 0): the separator between the do-nothing floor and an
ideal-mask oracle, scored with the shared per-step scores (``core.audio.scoring``).

For each episode the agent stays at its start pose. Three monaural magnitude estimates of the target:

* ``mixture`` (the floor): |STFT| of the ear mean of the binaural mixture, i.e. doing nothing;
* ``separator``: f^B -> f^M -> f^R with fresh memory on the step-0 mixture: the refined estimate of
  the *dry* target's magnitude (what the paper reports and the controllers use);
* ``separator_binaural``: the ear mean of f^B's separated binaural magnitude, the target *as heard*
  with the distractor masked out, before f^M removes the ears' colouring and the room. The
  deployable variant is scored against the target as heard, which a dry estimate cannot match even
  when perfect (its mixture-phase rebuild lacks the reverberation the reference holds), so this row
  shows what the separator removes in that variant;
* ``oracle`` (ideal mask): the ear-mean mixture's magnitude |X| times the ideal mask |R| / |X|
  capped at 1, i.e. min(|R|, |X|) per bin, where R is what the variant is scored against: for the
  ground-truth-phase scores the dry target clip (at the level the library stores it, which is what
  f^M is trained to output), for the mixture-phase score the target as heard (ear mean of its
  binaural render) at its share of the mixture (/ number of sources). It keeps what the mixture holds
  of the reference's magnitude and removes the rest; it needs the clean target, so it bounds
  masking rather than being reachable.

Each is scored as ``scoring.score_magnitude`` does it for the evaluator and ``scripts/evaluate.py``:
``si_sdr`` (magnitude + the clean target's phase vs the dry target, the paper's variant),
``si_sdr_mixture_phase`` (magnitude + the mixture's phase vs ``scoring.DEPLOYABLE_REFERENCE``, the
target as heard) and ``stft_distance``. :func:`gap_closed` gives the share of the floor-to-oracle gap
the separator closes.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from m2h_ros.core.audio.scoring import StepTruth, deployable_reference, score_magnitude
from m2h_ros.core.audio.stft import StftConfig, from_slices, stft, to_slices
from m2h_ros.core.sounds.library import TARGET_CATEGORIES, SoundLibrary
from m2h_ros.core.world.env import BatchEnv, EnvConfig
from m2h_ros.core.world.episodes import Episode
from m2h_ros.core.results import METRICS, mean_sem
from m2h_ros.errors import ConfigError
from m2h_ros.models.checkpoint import LoadedSeparator

ESTIMATES = ("mixture", "separator", "separator_binaural", "oracle")


def oracle_magnitudes(mixture: np.ndarray, truth: StepTruth, n_sources: np.ndarray, *,
                      config: StftConfig) -> dict[str, np.ndarray]:
    """The ideal-mask estimates min(|R|, |X|) (B, F, T) for each reference R (see the module docs):
    ``"dry"`` (the dry target) and ``"heard"`` (the ear-mean target as heard / number of sources)."""
    x = np.abs(stft(np.asarray(mixture).mean(axis=1), config=config))
    heard_share = deployable_reference(truth) / np.asarray(n_sources, np.float32)[:, None]
    return {"dry": np.minimum(np.abs(stft(truth.target_monaural, config=config)), x),
            "heard": np.minimum(np.abs(stft(heard_share, config=config)), x)}


# The oracle's reference for each metric: the one the metric scores against.
ORACLE_REFERENCE = {"si_sdr": "dry", "stft_distance": "dry", "si_sdr_mixture_phase": "heard"}


def step_zero_batches(env: BatchEnv, episodes: Sequence[Episode], *, desc: str,
                      progress: bool) -> Iterator[tuple[np.ndarray, slice, dict, dict]]:
    """Resets ``env`` on each batch of ``episodes`` in turn: ``(rows, keep, obs, info)``, where ``rows`` are
    the batch's episode indices and ``obs[...][keep]`` their slots (a short last batch is padded with
    its first episode, whose extra slots ``keep`` leaves out)."""
    n_envs = env.n_envs
    for first in tqdm(range(0, len(episodes), n_envs), desc=desc, unit="batch", disable=not progress):
        rows = np.arange(first, min(first + n_envs, len(episodes)))
        slots = np.concatenate([rows, np.full(n_envs - len(rows), rows[0])])
        obs, info = env.reset(episodes=[episodes[i] for i in slots])
        yield rows, slice(0, len(rows)), obs, info


def step_truth(info: dict, keep: slice) -> StepTruth:
    """The ground truth of a reset's kept slots."""
    return StepTruth(target_monaural=info["target_monaural"][keep], target_binaural=info["target_binaural"][keep])


def evaluate_passive(loaded: LoadedSeparator, episodes: Sequence[Episode], library: SoundLibrary, *,
                     env_config: EnvConfig | None = None, n_envs: int = 16, rir_cache_dir: Path | None = None,
                     progress: bool = True) -> dict[str, dict[str, np.ndarray]]:
    """Per-episode scores ``{estimate: {metric: (E,)}}`` at step 0 (metrics: ``results.METRICS``)."""
    env_config = env_config or EnvConfig(camera=False)
    if env_config.stft != loaded.stft:
        raise ConfigError(f"the environment's STFT {env_config.stft} differs from the separator's {loaded.stft}")
    # The environment numbers target classes by TARGET_CATEGORIES; the checkpoint by its class list.
    class_map = np.array([loaded.class_index(name) for name in TARGET_CATEGORIES])
    episodes = list(episodes)
    n_envs = min(n_envs, len(episodes))
    scores = {e: {m: np.empty(len(episodes)) for m in METRICS} for e in ESTIMATES}
    env = BatchEnv(episodes, library, n_envs=n_envs, config=env_config, rir_cache_dir=rir_cache_dir,
                   autoreset=False)
    loaded.separator.eval()
    try:
        for rows, keep, obs, info in step_zero_batches(env, episodes, desc="passive eval", progress=progress):
            mixture = obs["audio"][keep]
            truth = step_truth(info, keep)
            n_sources = np.array([len(episodes[i].source_nodes) for i in rows])
            spec = stft(mixture, config=loaded.stft)
            sliced = torch.from_numpy(np.ascontiguousarray(to_slices(np.abs(spec), n_slices=loaded.stft.n_freq_slices)))
            with torch.no_grad():
                step = loaded.separator(sliced, torch.from_numpy(class_map[obs["target_class"][keep]]))
            magnitudes = {"mixture": np.abs(spec.mean(axis=1)),
                          "separator": from_slices(step.refined.numpy(), n_slices=loaded.stft.n_freq_slices)[:, 0],
                          "separator_binaural": from_slices(step.binaural.numpy(),
                                                            n_slices=loaded.stft.n_freq_slices).mean(axis=1)}
            for estimate, magnitude in magnitudes.items():
                scored = score_magnitude(magnitude, mixture, truth, config=loaded.stft)
                for metric in METRICS:
                    scores[estimate][metric][rows] = getattr(scored, metric)
            oracle = {name: score_magnitude(magnitude, mixture, truth, config=loaded.stft) for name, magnitude
                      in oracle_magnitudes(mixture, truth, n_sources, config=loaded.stft).items()}
            for metric in METRICS:
                scores["oracle"][metric][rows] = getattr(oracle[ORACLE_REFERENCE[metric]], metric)
    finally:
        env.close()
    return scores


def summarize(scores: dict[str, dict[str, np.ndarray]]) -> dict[str, dict[str, float]]:
    """Mean, standard error and count of every metric of every estimate."""
    out = {}
    for estimate, metrics in scores.items():
        out[estimate] = {"episodes": int(len(next(iter(metrics.values()))))}
        for name, values in metrics.items():
            out[estimate][name], out[estimate][f"{name}_sem"] = mean_sem(values)
    return out


def gap_closed(summary: dict[str, dict[str, float]], metric: str, estimate: str = "separator") -> float:
    """(estimate - floor) / (oracle - floor) of a metric's means: the share of the gap it closes."""
    floor, oracle = summary["mixture"][metric], summary["oracle"][metric]
    return float((summary[estimate][metric] - floor) / (oracle - floor))
