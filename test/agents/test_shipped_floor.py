"""Floors under the shipped models on fixed small episodes (the small test scenes, real clips of the small
sound library, fast acoustics): a retrained or broken model that falls below one fails here. Each floor is
half of what the shipped models measure (said beside it; `pytest -s` prints the figures). Scores are the
paper's SI-SDR (the estimate's magnitude with the target's phase, against the dry target)."""

import dataclasses

import numpy as np
import pytest

from m2h_ros.agents.registry import make_controller
from m2h_ros.agents.rollout import evaluate_controller, truth_of
from m2h_ros.core.audio.scoring import score_magnitude
from m2h_ros.core.audio.stft import stft
from m2h_ros.core.world.env import BatchEnv
from m2h_ros.models.runner import SeparatorRunner

# Step 0 of 24 far-target episodes (the mixtures poorest there): the separator's estimate over the mixture,
# mean gain 2.21 dB (19 of 24 gain; asking for the other class: -7.2 dB).
SEPARATOR_FLOOR_DB = 1.1
# Far-target floors, on the first EPISODES far-target episodes (not chosen by how a model does there), 20
# steps, seed 0: half the mean gain of final SI-SDR over Stand In-Place's that the shipped model measures
# (-s prints the figures). The near-target models' floors are on the test scenes, where they were trained
# and evaluated: test/docs/test_results_reproduce.py.
EPISODES = 12
FLOORS_DB = {
    "move2hear": 0.51,  # pi^N + Stop (policy_navigation.pt; pi^Q does not act far-target): +1.03 dB
    "gan_et_al": 0.58,  # Gan et al. (locator.pt): +1.17 dB
}


@pytest.fixture(scope="module")
def far_episodes(small_episodes, small_library):
    return small_episodes(count=24, max_steps=20, task="far_target", library=small_library)


def test_the_shipped_separator_beats_the_mixture(far_episodes, small_library, env_config, separator):
    env = BatchEnv(far_episodes, small_library, n_envs=len(far_episodes), config=env_config)
    try:
        obs, info = env.reset()
    finally:
        env.close()
    truth = truth_of(info, np.arange(len(far_episodes)))
    classes = np.array([separator.class_index(e.target_category) for e in env.current_episodes])
    estimate = SeparatorRunner(separator, len(far_episodes)).step(obs["audio"], classes, np.ones(len(classes), bool))
    mixture = np.abs(stft(obs["audio"].mean(axis=1), config=separator.stft))
    gain = (score_magnitude(estimate.refined, obs["audio"], truth, config=separator.stft).si_sdr
            - score_magnitude(mixture, obs["audio"], truth, config=separator.stft).si_sdr)
    print(f"separator over the mixture at step 0: mean {gain.mean():+.2f} dB, {(gain > 0).sum()} of {len(gain)} gain")
    assert gain.mean() > SEPARATOR_FLOOR_DB


@pytest.mark.parametrize("name", list(FLOORS_DB))
def test_each_far_target_model_hears_better_than_standing_still(name, small_episodes, small_library, env_config,
                                                                separator):
    episodes = small_episodes(count=EPISODES, max_steps=20, task="far_target", library=small_library)
    config = dataclasses.replace(env_config, camera=True)
    final = {}
    for controller in ("stand_in_place", name):
        results = evaluate_controller(make_controller(controller, len(episodes), seed=0),
                                      SeparatorRunner(separator, len(episodes)), episodes, small_library,
                                      env_config=config, progress=False)
        final[controller] = np.array([r.final("si_sdr") for r in results])
    gain = final[name] - final["stand_in_place"]
    print(f"far-target {name} over Stand In-Place: mean {gain.mean():+.2f} dB, {np.round(gain, 2).tolist()}")
    assert gain.mean() > FLOORS_DB[name]
