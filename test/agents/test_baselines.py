"""Each training-free baseline's defining behaviour, on synthetic observations and on small scenes."""

import dataclasses

import numpy as np
import pytest

from m2h_ros.agents.base import ControllerObservation, EpisodeStart
from m2h_ros.agents.baselines import (DirectionOfArrival, MoveForward, ProximityPrior, RandomActions,
                                      RotateInPlace, StandInPlace)
from m2h_ros.agents.registry import LEARNED, TRAINING_FREE, controller_class, make_controller
from m2h_ros.agents.rollout import controller_observation
from m2h_ros.core.audio.doa import gcc_phat_itd, interaural_level_difference, lateral_sine, max_itd_samples
from m2h_ros.core.audio.stft import stft
from m2h_ros.core.world.env import BatchEnv
from m2h_ros.core.world.episodes import MOVE_FORWARD, STOP, TURN_LEFT, TURN_RIGHT, EpisodeConfig, generate_episodes
from m2h_ros.errors import ConfigError
from m2h_ros.models.runner import SeparationStep

F, T, N = 512, 32, 16000


def start(task="near_target", seed=7, episode_id="e0", max_steps=20) -> EpisodeStart:
    return EpisodeStart(episode_id, task, "speech", max_steps, seed)


def observe(step, pose, *, audio=None) -> ControllerObservation:
    """A one-slot observation as a baseline gets it (no separator outputs); audio silent unless given."""
    audio = np.zeros((1, 2, N), np.float32) if audio is None else audio[None].astype(np.float32)
    return ControllerObservation(step=np.array([step]), pose=np.asarray([pose], np.float32), audio=audio,
                                 separated_binaural=None, monaural=None, refined=None)


def test_no_baseline_reads_the_separator_and_every_learned_controller_does():
    # What lets the controller node answer a baseline's step without waiting for the separator.
    assert TRAINING_FREE and not any(controller_class(name).uses_separator for name in TRAINING_FREE)
    assert LEARNED and all(controller_class(name).uses_separator for name in LEARNED)


def no_separation(b: int) -> SeparationStep:
    """Separator outputs of zeros (baselines get None in their place: uses_separator is False)."""
    return SeparationStep(np.zeros((b, 2, F, T), np.float32), np.zeros((b, F, T), np.float32),
                          np.zeros((b, F, T), np.float32))


def play(controller, episodes, library, env_config):
    """One episode per slot through a BatchEnv: per step (nodes, headings, positions, actions), and
    each slot's navigation grid."""
    env = BatchEnv(episodes, library, n_envs=len(episodes), config=env_config, autoreset=False)
    obs, _ = env.reset()
    b = len(episodes)
    for slot, episode in enumerate(env.current_episodes):
        controller.reset(slot, EpisodeStart.of(episode))
    zero = no_separation(b)
    record = {"node": [obs["node"].copy()], "heading": [obs["heading"].copy()], "xy": [obs["pose"][:, :2].copy()],
              "action": []}
    try:
        for step in range(episodes[0].max_steps):
            actions = controller.act(controller_observation(obs, zero, uses_separator=controller.uses_separator))
            obs, _, terminated, truncated, _ = env.step(actions)
            record["action"].append(actions)
            for key, value in (("node", obs["node"]), ("heading", obs["heading"]), ("xy", obs["pose"][:, :2])):
                record[key].append(value.copy())
            if (terminated | truncated).all():
                break
        grids = [env.scene_of(slot).grid for slot in range(b)]
    finally:
        env.close()
    return {key: np.array(value) for key, value in record.items()}, grids


def test_every_registered_training_free_controller_builds():
    for name in TRAINING_FREE:
        controller = make_controller(name, 2, seed=3)
        assert controller.name == name and controller.summary
    with pytest.raises(ConfigError, match="unknown controller 'nope'"):
        make_controller("nope", 1)


def test_stand_in_place_never_moves(small_episodes, folder_library, env_config):
    near = small_episodes(count=3, max_steps=12)
    record, _ = play(StandInPlace(3), near, folder_library, env_config)
    assert (record["action"] == STOP).all()
    assert (record["node"] == record["node"][0]).all() and (record["heading"] == record["heading"][0]).all()
    # Far-target: Stop would end the episode, so it turns back and forth on the start node.
    far = small_episodes(count=2, max_steps=10, task="far_target")
    record, _ = play(StandInPlace(2), far, folder_library, env_config)
    assert len(record["action"]) == 10 and STOP not in record["action"]
    assert (record["node"] == record["node"][0]).all()
    np.testing.assert_array_equal(record["heading"][-1], record["heading"][0])


def test_rotate_in_place_turns_on_the_start_node(small_episodes, folder_library, env_config):
    record, _ = play(RotateInPlace(2), small_episodes(count=2, max_steps=8), folder_library, env_config)
    assert (record["action"] == TURN_LEFT).all() and (record["node"] == record["node"][0]).all()
    np.testing.assert_array_equal(record["heading"][1:5] - record["heading"][:4], np.where(
        record["heading"][:4] == 3, -3, 1))


def test_move_forward_turns_right_when_blocked_synthetic():
    controller = MoveForward(1)
    controller.reset(0, start())
    assert controller.act(observe(0, (0.5, 0.5, 0.0)))[0] == MOVE_FORWARD
    assert controller.act(observe(1, (1.5, 0.5, 0.0)))[0] == MOVE_FORWARD  # it moved
    assert controller.act(observe(2, (1.5, 0.5, 0.0)))[0] == TURN_RIGHT  # it did not: blocked
    assert controller.act(observe(3, (1.5, 0.5, -np.pi / 2)))[0] == MOVE_FORWARD  # a turn is no failed move
    controller.reset(0, start(seed=8))  # a new episode forgets the last move
    assert controller.act(observe(0, (1.5, 0.5, 0.0)))[0] == MOVE_FORWARD


def test_move_forward_in_a_scene_turns_right_exactly_after_failed_moves(small_episodes, folder_library, env_config):
    record, _ = play(MoveForward(3), small_episodes(count=3, max_steps=30), folder_library, env_config)
    actions = record["action"]
    failed = (actions[:-1] == MOVE_FORWARD) & (record["node"][1:-1] == record["node"][:-2])
    np.testing.assert_array_equal(actions[1:] == TURN_RIGHT, failed)
    assert failed.any() and (actions == MOVE_FORWARD).sum() > failed.sum()  # it meets walls and moves


def test_proximity_prior_never_leaves_its_circle(small_episodes, folder_library, env_config):
    episodes = small_episodes(count=4, max_steps=150)
    for radius in (1.0, 2.5):
        record, _ = play(ProximityPrior(4, seed=1, radius=radius), episodes, folder_library, env_config)
        distance = np.linalg.norm(record["xy"] - record["xy"][0], axis=-1)
        assert distance.max() <= radius + 1e-5
        assert distance.max() >= radius - 1.0  # it does explore the circle
        assert set(np.unique(record["action"])) <= {MOVE_FORWARD, TURN_LEFT, TURN_RIGHT}
    with pytest.raises(ConfigError, match="radius"):
        ProximityPrior(1, radius=0.0)


def test_random_is_reproducible_per_seeds_and_independent_of_the_slot():
    def actions(controller, slot_of_episode, steps=40):
        for slot, seed in slot_of_episode.items():
            controller.reset(slot, start(seed=seed, episode_id=f"e{seed}"))
        b = controller.n_slots
        obs = ControllerObservation.stack([observe(0, (0.5, 0.5, 0.0))] * b)
        out = np.array([controller.act(dataclasses.replace(obs, step=np.full(b, k))) for k in range(steps)])
        return {seed: out[:, slot] for slot, seed in slot_of_episode.items()}

    a = actions(RandomActions(2, seed=5), {0: 11, 1: 12})
    b = actions(RandomActions(3, seed=5), {2: 11, 0: 12, 1: 13})
    np.testing.assert_array_equal(a[11], b[11])
    np.testing.assert_array_equal(a[12], b[12])
    assert not np.array_equal(a[11], a[12])  # another episode seed, other actions
    c = actions(RandomActions(2, seed=6), {0: 11, 1: 12})
    assert not np.array_equal(a[11], c[11])  # another controller seed, other actions
    assert set(np.unique(a[11])) == {MOVE_FORWARD, TURN_LEFT, TURN_RIGHT}


def binaural(itd: int, *, gain_right: float, seed: int = 0, band: tuple[float, float] = (0, 8000)) -> np.ndarray:
    """Noise in ``band`` (Hz) that reaches the right ear ``itd`` samples after the left one
    (negative: before)."""
    noise = np.random.default_rng(seed).standard_normal(N + 32)
    spectrum = np.fft.rfft(noise)
    hz = np.fft.rfftfreq(noise.size, 1 / 16000)
    noise = np.fft.irfft(spectrum * ((hz >= band[0]) & (hz < band[1])), noise.size).astype(np.float32)
    left, right = noise[16:16 + N], noise[16 - itd:16 - itd + N] * gain_right
    return np.stack([left, right])


def test_gcc_phat_finds_the_delay_and_its_side():
    audio = np.stack([binaural(6, gain_right=0.6), binaural(-3, gain_right=1.2, seed=1), binaural(0, gain_right=1)])
    itd = gcc_phat_itd(stft(audio))
    np.testing.assert_allclose(itd, [6, -3, 0], atol=0.25)
    sines = lateral_sine(itd)
    assert sines[0] > 0.7 and -0.5 < sines[1] < -0.2 and abs(sines[2]) < 0.05
    assert max_itd_samples() == pytest.approx(0.18 / 343 * 16000)


def test_ild_is_the_level_ratio_above_1500_hz():
    high = binaural(0, gain_right=1.0, band=(2500, 6000), seed=5)
    audio = np.stack([binaural(0, gain_right=0.5), binaural(0, gain_right=2.0, band=(200, 1000)) + high])
    ild = interaural_level_difference(np.abs(stft(audio)))
    assert ild[0] == pytest.approx(20 * np.log10(2), abs=0.05)  # left louder: positive
    assert abs(ild[1]) < 0.1  # the right ear's louder low band does not count
    assert interaural_level_difference(np.zeros((1, 2, F, T)))[0] == 0


# Synthetic observations: a source seen from the robot (ILD only, so no delay needed).
LEFT, RIGHT, AHEAD = binaural(0, gain_right=0.5), binaural(0, gain_right=2.0), binaural(0, gain_right=1.0)


def doa_actions(sequence, task="near_target"):
    """DoA's actions, one per observation's audio in ``sequence``."""
    controller = DirectionOfArrival(1)
    controller.reset(0, start(task=task))
    return [int(controller.act(observe(step, (0.5, 0.5, 0.0), audio=audio))[0])
            for step, audio in enumerate(sequence)]


def test_doa_turns_toward_a_source_on_its_left_then_steps_and_stays():
    # A source on the left: its first (probe) turn already faces it; the source is then ahead.
    assert doa_actions([LEFT, AHEAD, AHEAD, AHEAD, AHEAD]) == [TURN_LEFT, MOVE_FORWARD, STOP, STOP, STOP]
    # On the right: after the probe it is behind, so two right turns.
    assert doa_actions([RIGHT, AHEAD, AHEAD, AHEAD, AHEAD]) == [TURN_LEFT, TURN_RIGHT, TURN_RIGHT, MOVE_FORWARD,
                                                                 STOP]
    # Ahead: after the probe it is on the right: turn back. Behind: on the left after the probe.
    assert doa_actions([AHEAD, RIGHT, AHEAD, AHEAD]) == [TURN_LEFT, TURN_RIGHT, MOVE_FORWARD, STOP]
    assert doa_actions([AHEAD, LEFT, AHEAD, AHEAD]) == [TURN_LEFT, TURN_LEFT, MOVE_FORWARD, STOP]
    # Far-target: it stays by turning back and forth (Stop would end the episode).
    assert doa_actions([LEFT, AHEAD, AHEAD, AHEAD, AHEAD], task="far_target") == [
        TURN_LEFT, MOVE_FORWARD, TURN_LEFT, TURN_RIGHT, TURN_LEFT]


def test_doa_steps_toward_the_target_rendered_in_a_scene(small_library, env_config):
    """The target alone as rendered on small scenes (real sounds: the synthetic ones have little
    energy above 1.5 kHz); with the distractor, scripts/bench/doa_cues.py measures it."""
    episodes = generate_episodes(EpisodeConfig(count=16, max_steps=5, seed=3, scene_split="test", scene_preset="small",
                                               min_source_distance=3.0, near_radius=2.0), small_library)
    env = BatchEnv(episodes, small_library, n_envs=len(episodes), config=env_config, autoreset=False)
    controller = DirectionOfArrival(len(episodes))
    for slot, episode in enumerate(episodes):
        controller.reset(slot, EpisodeStart.of(episode))
    obs, info = env.reset()
    grids = [env.scene_of(slot).grid for slot in range(len(episodes))]
    zero = no_separation(len(episodes))
    facing = {}
    for _ in range(4):
        actions = controller.act(controller_observation(dict(obs, audio=info["target_binaural"]), zero, uses_separator=False))
        for slot in np.flatnonzero(actions == MOVE_FORWARD):
            d = grids[slot].positions[episodes[slot].target_node] - grids[slot].positions[obs["node"][slot]]
            facing.setdefault(slot, np.cos(np.arctan2(d[1], d[0]) - obs["pose"][slot, 2]) > np.cos(np.pi / 4) - 1e-6)
        obs, _, _, _, info = env.step(actions)
    env.close()
    assert len(facing) == len(episodes)
    assert np.mean(list(facing.values())) >= 0.75  # a random heading: about 0.25
