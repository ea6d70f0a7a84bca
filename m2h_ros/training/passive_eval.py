"""Passive separation baseline (Stand In-Place, step 0): the separator vs doing nothing.

For each episode the agent stays at its start pose; the separator (f^B -> f^M -> f^R with fresh
memory) turns the step-0 binaural mixture into the target's monaural magnitude, rebuilt two ways:

* ``separator_gt_phase``: predicted magnitude + the clean target's phase (the paper's reported
  variant; an oracle, for comparability only);
* ``separator_mixture_phase``: predicted magnitude + the phase of the mixture's channel mean (what a
  deployed robot can do);
* ``mixture``: the do-nothing floor, the channel mean of the binaural mixture taken as the estimate;
* ``mixture_gt_phase``: the floor of the oracle-phase variant, the magnitude of that channel mean
  with the clean target's phase (what the separator's magnitude adds over doing nothing).

References (``REFERENCES``): the ground-truth-phase variants are scored against the target's dry
monaural clip, exactly as the paper. The dry clip starts at t = 0 while the microphones hear it after
the direct path's propagation delay, so against the dry clip every mixture-phase estimate is mostly
misalignment (about -23 dB even for the target as heard); as usual for reverberant separation, the
mixture-phase variants are scored against the *delay-aligned* dry clip instead: delayed by the
environment's ``info["target_delay"]`` (direct-path delay at the head centre), rounded to whole
samples, zeros in front. Reverberation still counts as error there.

Metrics: SI-SDR (dB) and STFT distance (Frobenius norm of the difference of the complex spectrograms
of the waveforms).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from tqdm import tqdm

from m2h_ros.core.audio.metrics import delayed, si_sdr, stft_distance
from m2h_ros.core.audio.stft import rebuild_ground_truth_phase, stft
from m2h_ros.core.sounds.library import TARGET_CATEGORIES, SoundLibrary
from m2h_ros.core.world.env import BatchEnv, EnvConfig
from m2h_ros.core.world.episodes import Episode
from m2h_ros.errors import ConfigError
from m2h_ros.models.checkpoint import LoadedSeparator
from m2h_ros.models.separator import separate_clip

VARIANTS = ("separator_gt_phase", "separator_mixture_phase", "mixture_gt_phase", "mixture")
DRY, DELAY_ALIGNED = "dry target", "delay-aligned dry target"
REFERENCES = {"separator_gt_phase": DRY, "separator_mixture_phase": DELAY_ALIGNED,
              "mixture_gt_phase": DRY, "mixture": DELAY_ALIGNED}


def evaluate_passive(loaded: LoadedSeparator, episodes: Sequence[Episode], library: SoundLibrary, *,
                     env_config: EnvConfig | None = None, n_envs: int = 16, rir_cache_dir: Path | None = None,
                     progress: bool = True) -> dict[str, dict[str, np.ndarray]]:
    """Per-episode scores ``{variant: {"si_sdr": (E,), "stft_distance": (E,)}}`` at step 0."""
    env_config = env_config or EnvConfig(camera=False)
    if env_config.stft != loaded.stft:
        raise ConfigError(f"the environment's STFT {env_config.stft} differs from the separator's {loaded.stft}")
    # The environment numbers target classes by TARGET_CATEGORIES; the checkpoint by its class list.
    class_map = np.array([loaded.class_index(name) for name in TARGET_CATEGORIES])
    episodes = list(episodes)
    n_envs = min(n_envs, len(episodes))
    scores = {v: {"si_sdr": np.empty(len(episodes)), "stft_distance": np.empty(len(episodes))} for v in VARIANTS}
    env = BatchEnv(episodes, library, n_envs=n_envs, config=env_config, rir_cache_dir=rir_cache_dir,
                   autoreset=False)
    loaded.separator.eval()
    try:
        for first in tqdm(range(0, len(episodes), n_envs), desc="passive eval", unit="batch", disable=not progress):
            rows = np.arange(first, min(first + n_envs, len(episodes)))
            slots = np.concatenate([rows, np.full(n_envs - len(rows), rows[0])])  # pad a short last batch
            obs, info = env.reset(episodes=[episodes[i] for i in slots])
            keep = slice(0, len(rows))
            mixture, target = obs["audio"][keep], info["target_monaural"][keep]
            result = separate_clip(loaded.separator, mixture, class_map[obs["target_class"][keep]],
                                   config=loaded.stft)
            estimates = {"separator_gt_phase": rebuild_ground_truth_phase(result.magnitude, target, config=loaded.stft),
                         "separator_mixture_phase": result.waveform,
                         "mixture_gt_phase": rebuild_ground_truth_phase(
                             np.abs(stft(mixture.mean(axis=1), config=loaded.stft)), target, config=loaded.stft),
                         "mixture": mixture.mean(axis=1)}
            references = {DRY: target, DELAY_ALIGNED: delayed(target, np.rint(info["target_delay"][keep]).astype(int))}
            reference_specs = {name: stft(ref, config=loaded.stft) for name, ref in references.items()}
            for variant, estimate in estimates.items():
                reference = REFERENCES[variant]
                scores[variant]["si_sdr"][rows] = si_sdr(estimate, references[reference])
                scores[variant]["stft_distance"][rows] = stft_distance(stft(estimate, config=loaded.stft),
                                                                       reference_specs[reference])
    finally:
        env.close()
    return scores


def summarize(scores: dict[str, dict[str, np.ndarray]]) -> dict[str, dict[str, float]]:
    """Mean, standard error and count of every metric of every variant."""
    out = {}
    for variant, metrics in scores.items():
        out[variant] = {"episodes": int(len(next(iter(metrics.values()))))}
        for name, values in metrics.items():
            out[variant][name] = float(np.mean(values))
            out[variant][f"{name}_sem"] = float(np.std(values, ddof=1) / np.sqrt(len(values))) if len(values) > 1 else 0.0
    return out
