"""In-process evaluation: controllers play episodes on a ``BatchEnv`` with the separator batched over
the slots, scored per step with the same core functions the evaluator node uses.

Slot s plays episodes s, s + B, s + 2B, ... of the list (``EnvConfig.shuffle=False``), each episode
exactly once; a slot whose share is done keeps playing wrapped-around episodes whose results are
dropped. Separator memory and controller state reset at each episode's first step, so an episode's
numbers do not depend on the slot or batch size (up to float rounding in batched convolutions).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from tqdm import tqdm

from m2h_ros.agents.base import Controller, ControllerObservation, EpisodeStart
from m2h_ros.core.audio.scoring import StepTruth, score_magnitude
from m2h_ros.core.results import EpisodeResult, EpisodeTracker
from m2h_ros.core.sounds.library import SoundLibrary
from m2h_ros.core.world.env import BatchEnv, EnvConfig
from m2h_ros.core.world.episodes import Episode
from m2h_ros.errors import ConfigError
from m2h_ros.models.runner import SeparationStep, SeparatorRunner


def controller_observation(obs: dict, separation: SeparationStep, *,
                           uses_separator: bool = True) -> ControllerObservation:
    """What a controller sees of an environment observation (no ground truth: ``info`` is not read);
    the separator's outputs only if it ``uses_separator`` (as the controller node gives them)."""
    outputs = (separation.binaural, separation.monaural, separation.refined) if uses_separator else (None,) * 3
    return ControllerObservation(
        step=obs["step"], pose=obs["pose"], audio=obs["audio"], separated_binaural=outputs[0],
        monaural=outputs[1], refined=outputs[2], rgb=obs.get("rgb"),
        depth=None if "depth" not in obs else obs["depth"][..., 0])


ESTIMATES = ("refined", "monaural")


def new_tracker(episode: Episode, controller: str, info: dict, slot: int, start_pose: np.ndarray) -> EpisodeTracker:
    result = EpisodeResult(episode_id=episode.episode_id, controller=controller, task=episode.task,
                           sound_split=episode.sound_split, scene_id=episode.scene_id,
                           target_class=episode.target_category,
                           shortest_path=float(info["geodesic_distance"][slot]))
    return EpisodeTracker(result, start_pose)


def truth_of(info: dict, rows) -> StepTruth:
    return StepTruth(target_monaural=info["target_monaural"][rows], target_binaural=info["target_binaural"][rows])


def evaluate_controller(controller: Controller, runner: SeparatorRunner, episodes: Sequence[Episode],
                        library: SoundLibrary, *, env_config: EnvConfig = EnvConfig(camera=False),
                        rir_cache_dir: Path | None = None, threads: int = 1, progress: bool = True,
                        estimate: str = "refined") -> list[EpisodeResult]:
    """Play every episode once with ``controller`` (B = its slots = the runner's); results in list order.
    ``estimate``: the separator output scored, "refined" (f^R, the pipeline's) or "monaural" (f^M: no f^R)."""
    if estimate not in ESTIMATES:
        raise ConfigError(f"estimate must be one of {ESTIMATES}, got {estimate!r}")
    episodes = list(episodes)
    b = controller.n_slots
    if runner.n_slots != b:
        raise ConfigError(f"controller has {b} slots, separator runner {runner.n_slots}")
    if controller.uses_camera and not env_config.camera:
        raise ConfigError(f"controller {controller.name} needs the camera: use EnvConfig(camera=True)")
    b = min(b, len(episodes))
    if b != controller.n_slots:
        raise ConfigError(f"{len(episodes)} episodes for {controller.n_slots} slots: use at most as many slots")
    config = dataclasses.replace(env_config, shuffle=False)
    env = BatchEnv(episodes, library, n_envs=b, config=config, rir_cache_dir=rir_cache_dir, threads=threads)
    results: list[EpisodeResult | None] = [None] * len(episodes)
    started = np.zeros(b, np.int64)  # episodes each slot has started
    trackers: list[EpisodeTracker | None] = [None] * b
    total_steps = sum(e.max_steps + 1 for e in episodes)
    bar = tqdm(total=total_steps, desc=f"evaluate {controller.name}", unit="step", disable=not progress)

    def start(slot: int, obs: dict, info: dict) -> None:
        index = int(started[slot]) * b + slot
        started[slot] += 1
        episode = env.current_episodes[slot]
        controller.reset(slot, EpisodeStart.of(episode))
        trackers[slot] = new_tracker(episode, controller.name, info, slot, obs["pose"][slot]) \
            if index < len(episodes) else None

    def observe(slots: np.ndarray, obs: dict, info: dict, separation: SeparationStep) -> None:
        scores = score_magnitude(getattr(separation, estimate), obs["audio"][slots], truth_of(info, slots),
                                 config=runner.loaded.stft)
        for row, slot in enumerate(slots.tolist()):
            if trackers[slot] is None:
                continue
            trackers[slot].observe(int(obs["step"][slot]), si_sdr=scores.si_sdr[row],
                                   si_sdr_mixture_phase=scores.si_sdr_mixture_phase[row],
                                   stft_distance=scores.stft_distance[row], position=obs["pose"][slot],
                                   at_target=bool(info["at_target"][slot]))
            bar.update()

    try:
        obs, info = env.reset()
        for slot in range(b):
            start(slot, obs, info)
        classes = np.array([runner.loaded.class_index(e.target_category) for e in env.current_episodes])
        reset = np.ones(b, bool)
        all_slots = np.arange(b)
        while any(r is None for r in results):
            separation = runner.step(obs["audio"], classes, reset)
            observe(all_slots, obs, info, separation)
            actions = controller.act(controller_observation(obs, separation,
                                                            uses_separator=controller.uses_separator))
            for slot in range(b):
                if trackers[slot] is not None:
                    trackers[slot].act(int(obs["step"][slot]), int(actions[slot]))
            obs, _, terminated, truncated, info = env.step(actions)
            reset = terminated | truncated
            ended = np.flatnonzero(reset)
            if len(ended):
                final_obs, final_info = info["final_observation"], info["final_info"]
                # The terminal observation continues its episode's memory: separate and score it.
                separation = runner.step(final_obs["audio"][ended], classes[ended], np.zeros(len(ended), bool),
                                         rows=ended)
                observe(ended, final_obs, final_info, separation)
                for slot in ended.tolist():
                    if trackers[slot] is not None:
                        result = trackers[slot].finish()
                        results[(int(started[slot]) - 1) * b + slot] = result
                    start(slot, obs, info)
                    classes[slot] = runner.loaded.class_index(env.current_episodes[slot].target_category)
    finally:
        bar.close()
        env.close()
    return results  # type: ignore[return-value]
