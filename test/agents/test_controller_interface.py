"""A controller never gets the ground truth, and in-process evaluation plays episodes in order."""

import dataclasses
import inspect
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from m2h_ros.agents.base import Controller, ControllerObservation, EpisodeStart
from m2h_ros.agents.registry import make_controller
from m2h_ros.agents.rollout import controller_observation, evaluate_controller
from m2h_ros.core.world.env import BatchEnv
from m2h_ros.models.runner import SeparationStep, SeparatorRunner

MSG_DIR = Path(__file__).resolve().parents[2] / "msg_defs" / "msg"


def ground_truth_message_fields() -> set[str]:
    fields = set()
    for line in (MSG_DIR / "GroundTruth.msg").read_text().splitlines():
        words = line.split("#")[0].split()
        if len(words) >= 2:
            fields.add(words[1])
    return fields - {"header", "episode_id", "step", "sample_rate"}  # bookkeeping, not truth


class Recording(Mapping):
    """A read-only dict that remembers which keys were read."""

    def __init__(self, values: dict) -> None:
        self.values, self.read = values, set()

    def __getitem__(self, key):
        self.read.add(key)
        return self.values[key]

    def __iter__(self):
        return iter(self.values)

    def __len__(self):
        return len(self.values)


def test_a_controller_gets_no_ground_truth_field(small_episodes, folder_library, env_config):
    env = BatchEnv(small_episodes(count=2, max_steps=3), folder_library, n_envs=2, config=env_config)
    try:
        obs, info = env.reset()
    finally:
        env.close()
    truth = set(info) | ground_truth_message_fields()
    assert {"target_monaural", "target_binaural", "target_delay", "geodesic_distance", "at_target"} <= truth
    given = {f.name for f in dataclasses.fields(ControllerObservation)} | {f.name for f in dataclasses.fields(EpisodeStart)}
    assert not given & truth, given & truth
    # The rollout's conversion reads nothing but the observation, and only keys the env observes.
    assert list(inspect.signature(controller_observation).parameters) == ["obs", "separation", "uses_separator"]
    recording = Recording(obs)
    zero = np.zeros((2, 2, 512, 32), np.float32)
    controller_observation(recording, SeparationStep(zero, zero[:, 0], zero[:, 0]))
    assert recording.read <= set(obs) | {"rgb", "depth"}  # the camera's, off here
    assert not recording.read & truth
    # A controller acts on that observation alone.
    assert list(inspect.signature(Controller.act).parameters) == ["self", "obs"]


def test_evaluate_controller_plays_each_episode_once_in_order(small_episodes, folder_library, env_config, separator):
    episodes = small_episodes(count=3, max_steps=4, seed=2)
    results = evaluate_controller(make_controller("random", 2, seed=1), SeparatorRunner(separator, 2), episodes,
                                  folder_library, env_config=env_config, progress=False)
    assert [r.episode_id for r in results] == [e.episode_id for e in episodes]
    for r in results:
        assert r.steps == 4 and len(r.si_sdr) == len(r.si_sdr_mixture_phase) == len(r.stft_distance) == 5
        assert np.isfinite(r.si_sdr + r.si_sdr_mixture_phase + r.stft_distance).all()
        assert r.controller == "random" and r.task == "near_target" and r.shortest_path > 0
    # The same episodes one at a time: the same actions and (up to batched rounding) the same scores.
    alone = evaluate_controller(make_controller("random", 1, seed=1), SeparatorRunner(separator, 1), episodes,
                                folder_library, env_config=env_config, progress=False)
    for a, b in zip(results, alone):
        assert a.actions == b.actions
        np.testing.assert_allclose(a.si_sdr, b.si_sdr, atol=1e-3)
