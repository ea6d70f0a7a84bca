"""What a listener gets: the audio ``separator/audio`` publishes, against the raw microphone, at step 0
of test episodes (Stand In-Place), or at their last step after a controller has moved the robot
(:func:`final_step_batches`), scored against references a deployed robot can fairly be held to.

References (ear means of binaural signals; the reasoning is in docs/design/separator.md, "What a
listener gets"):

* ``early``: the target's early image at the ears: its dry clip through the first ``EARLY_S`` (50 ms)
  of its binaural room impulse response after the direct sound: the direct path and the early
  reflections, which a listener hears as the source itself, without the late reverberation, which
  no single-channel mask can take out;
* ``as_heard``: the target alone as heard, whole RIR (``scoring.DEPLOYABLE_REFERENCE``).

Estimates (waveforms):

* ``microphone`` (the floor): the ear mean of the mixture, i.e. what the microphones give;
* ``listener``: the listener output (``models/listener.py``, separator/audio's default), ear mean;
  scored where a listener is given;
* ``masked_mixture``: f^B's mask on each ear of the mixture, ear mean (``audio_output: masked_mixture``);
* ``refined``: f^R's refined estimate of the dry target with the ear-mean mixture's phase (its
  earliest output, still ``audio_output: refined``);
* ``oracle``: the ideal mask min(|R|, |X|) on the ear-mean mixture X with its phase, R = the
  reference's share of the mixture (/ number of sources); scored against its own reference.

Metrics: SI-SDR (dB) against each reference; STOI (``pystoi``, speech targets only; NaN for music)
against the early image.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence

import numpy as np
import scipy.signal
import torch
from pystoi import stoi

from m2h_ros.agents.base import Controller, EpisodeStart
from m2h_ros.agents.rollout import controller_observation
from m2h_ros.core.audio.metrics import si_sdr
from m2h_ros.core.audio.scoring import deployable_reference
from m2h_ros.core.audio.stft import from_slices, masked_mixture, rebuild_mixture_phase, stft, to_slices
from m2h_ros.core.results import mean_sem
from m2h_ros.core.sounds.library import TARGET_CATEGORIES, SoundLibrary
from m2h_ros.core.world.env import BatchEnv, EnvConfig
from m2h_ros.core.world.episodes import Episode
from m2h_ros.errors import ConfigError
from m2h_ros.models.checkpoint import LoadedSeparator
from m2h_ros.models.listener import LoadedListener, listen
from m2h_ros.models.runner import SeparatorRunner
from m2h_ros.training.passive_eval import step_truth, step_zero_batches

EARLY_S = 0.05
REFERENCES = ("early", "as_heard")
ESTIMATES = ("microphone", "listener", "masked_mixture", "refined", "oracle")
# Stand In-Place's microphone at the same last step, beside another controller's estimates
STAND_IN_PLACE = "stand_in_place_microphone"
# STOI against the early image only: the reference a listener is held to (and half the cost)
METRICS = ("si_sdr_early", "stoi_early", "si_sdr_as_heard")


def early_images(clips: np.ndarray, rirs: np.ndarray, delays: np.ndarray, *, sample_rate: int) -> np.ndarray:
    """(B, 2, N): each dry clip (B, N) through its binaural RIR (B, 2, T) cut ``EARLY_S`` after the
    direct sound, which arrives ``delays`` (B,) samples in; one image per ear."""
    out = np.empty((clips.shape[0], rirs.shape[1], clips.shape[-1]), np.float32)
    for i, (clip, rir, delay) in enumerate(zip(clips, rirs, delays)):
        cut = int(np.ceil(delay)) + round(EARLY_S * sample_rate)
        out[i] = scipy.signal.fftconvolve(clip[None], rir[:, :cut], axes=-1)[:, : clips.shape[-1]]
    return out


def early_image(clips: np.ndarray, rirs: np.ndarray, delays: np.ndarray, *, sample_rate: int) -> np.ndarray:
    """(B, N) ear mean of :func:`early_images`."""
    return early_images(clips, rirs, delays, sample_rate=sample_rate).mean(axis=1)


def final_step_batches(env: BatchEnv, episodes: Sequence[Episode], controller: Controller, runner: SeparatorRunner,
                       *, desc: str, progress: bool) -> Iterator[tuple[np.ndarray, slice, dict, dict]]:
    """As ``step_zero_batches``, but each batch is played by ``controller`` (given ``runner``'s
    separator outputs each step, as ``evaluate_controller`` gives them) to its last step, and that
    step's ``(rows, keep, obs, info)`` is yielded: what the robot hears where the controller has taken
    it. The slots of a batch must end together, as near-target episodes of one length do; play
    episodes that end when the controller stops (far-target) one per batch."""
    if not controller.uses_separator:
        runner = None
    for rows, keep, obs, info in step_zero_batches(env, episodes, desc=desc, progress=progress):
        playing = env.current_episodes
        for slot, episode in enumerate(playing):
            controller.reset(slot, EpisodeStart.of(episode))
        classes = None if runner is None else runner.class_indices([e.target_category for e in playing])
        reset = np.ones(env.n_envs, bool)
        while True:
            separation = None if runner is None else runner.step(obs["audio"], classes, reset)
            reset[:] = False
            actions = controller.act(controller_observation(obs, separation, uses_separator=runner is not None))
            obs, _, terminated, truncated, info = env.step(actions)
            done = terminated | truncated
            if done.all():
                break
            if done.any():
                raise ConfigError(f"{controller.name} ended some episodes of a batch before the others: the last "
                                  "step is scored only for episodes that end together (play far-target episodes "
                                  "one per batch, n_envs=1)")
        yield rows, keep, obs, info


def evaluate_listener(loaded: LoadedSeparator, episodes: Sequence[Episode], library: SoundLibrary, *,
                      env_config: EnvConfig | None = None, n_envs: int = 16, listener: LoadedListener | None = None,
                      controller: Controller | None = None,
                      progress: bool = True) -> dict[str, dict[str, np.ndarray]]:
    """Per-episode scores ``{estimate: {metric: (E,)}}`` (metrics: ``METRICS``; ``listener`` only
    with a listener) at step 0, or with a ``controller`` (of ``n_envs`` slots) at the last step of
    its episodes."""
    env_config = env_config or EnvConfig(camera=False)
    if env_config.stft != loaded.stft:
        raise ConfigError(f"the environment's STFT {env_config.stft} differs from the separator's {loaded.stft}")
    config, rate = loaded.stft, loaded.stft.sample_rate
    class_map = np.array([loaded.class_index(name) for name in TARGET_CATEGORIES])
    speech = TARGET_CATEGORIES.index("speech")
    episodes = list(episodes)
    n_envs = min(n_envs, len(episodes))
    if controller is not None and controller.n_slots != n_envs:
        raise ConfigError(f"{controller.name} has {controller.n_slots} slots for {n_envs} environments")
    if listener is not None and listener.classes != loaded.classes:
        raise ConfigError(f"the listener knows classes {list(listener.classes)}, the separator {list(loaded.classes)}")
    estimates = [e for e in ESTIMATES if e != "listener" or listener is not None]
    scores = {e: {m: np.full(len(episodes), np.nan) for m in METRICS} for e in estimates}
    env = BatchEnv(episodes, library, n_envs=n_envs, config=env_config, autoreset=False)
    loaded.separator.eval()
    batches = step_zero_batches(env, episodes, desc="listener eval", progress=progress) if controller is None else \
        final_step_batches(env, episodes, controller, SeparatorRunner(loaded, n_envs),
                           desc=f"listener eval after {controller.name}", progress=progress)
    try:
        for rows, keep, obs, info in batches:
            mixture = obs["audio"][keep]
            truth = step_truth(info, keep)
            references = {"early": early_image(truth.target_monaural, env.target_rirs(range(len(rows))),
                                               info["target_delay"][keep], sample_rate=rate),
                          "as_heard": deployable_reference(truth)}
            n_sources = np.array([len(episodes[i].source_nodes) for i in rows], np.float32)
            spec = stft(mixture, config=config)
            sliced = torch.from_numpy(np.ascontiguousarray(to_slices(np.abs(spec), n_slices=config.n_freq_slices)))
            with torch.no_grad():
                step = loaded.separator(sliced, torch.from_numpy(class_map[obs["target_class"][keep]]))
                if listener is not None:
                    listener.listener.eval()
                    heard = listen(listener.listener, mixture, class_map[obs["target_class"][keep]], config=config)
            binaural = from_slices(step.binaural.numpy(), n_slices=config.n_freq_slices)
            refined = from_slices(step.refined.numpy(), n_slices=config.n_freq_slices)[:, 0]
            mixture_mean = np.abs(spec.mean(axis=1))
            waves = {"microphone": mixture.mean(axis=1),
                     "masked_mixture": masked_mixture(binaural, mixture, config=config),
                     "refined": rebuild_mixture_phase(refined, mixture, config=config)}
            if listener is not None:
                waves["listener"] = heard.mean(axis=1)
            is_speech = obs["target_class"][keep] == speech
            for name, reference in references.items():
                share = np.abs(stft(reference / n_sources[:, None], config=config))
                oracle = rebuild_mixture_phase(np.minimum(share, mixture_mean), mixture, config=config)
                for estimate, wave in {**waves, "oracle": oracle}.items():
                    scores[estimate][f"si_sdr_{name}"][rows] = si_sdr(wave, reference)
                    for k in np.flatnonzero(is_speech) if f"stoi_{name}" in METRICS else ():
                        scores[estimate][f"stoi_{name}"][rows[k]] = stoi(reference[k], wave[k], rate)
    finally:
        env.close()
    return scores


def summarize(scores: dict[str, dict[str, np.ndarray]]) -> dict[str, dict[str, float]]:
    """Mean, standard error and count of each metric (NaNs, i.e. non-speech STOI, left out); for every
    estimate also its paired difference from the microphone, from Stand In-Place's microphone where
    ``scores`` has it (``STAND_IN_PLACE``: a last-step evaluation after another controller) and, where
    both are scored, the listener's from the masked mixture."""
    out: dict[str, dict[str, float]] = {}
    for estimate, metrics in scores.items():
        row: dict[str, float] = {}
        for name, values in metrics.items():
            pairs = [(name, values), (f"{name}_minus_microphone", values - scores["microphone"][name])]
            if STAND_IN_PLACE in scores:
                pairs.append((f"{name}_minus_{STAND_IN_PLACE}", values - scores[STAND_IN_PLACE][name]))
            if estimate == "listener" and "masked_mixture" in scores:
                pairs.append((f"{name}_minus_masked_mixture", values - scores["masked_mixture"][name]))
            for label, data in pairs:
                data = data[np.isfinite(data)]
                row[label], row[f"{label}_sem"] = mean_sem(data)
                row[f"{label}_n"] = int(len(data))
        out[estimate] = row
    return out
