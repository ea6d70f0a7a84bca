"""What a listener gets: the early image keeps the direct sound and the first 50 ms after it, and the
masked mixture gives each ear's own mixture back under a full mask and the target as heard under an
ideal one."""

import numpy as np
import pytest

from m2h_ros.core.audio.metrics import si_sdr
from m2h_ros.core.audio.stft import DEFAULT_STFT, masked_mixture, stft
from m2h_ros.training.listener_eval import early_image

RATE = DEFAULT_STFT.sample_rate


def test_the_early_image_keeps_the_first_50_ms_after_the_direct_sound():
    clip = np.random.default_rng(0).standard_normal((1, RATE)).astype(np.float32)
    rir = np.zeros((1, 2, 4000), np.float32)
    rir[0, 0, 100], rir[0, 1, 103] = 1.0, 0.5           # direct sound at each ear
    rir[0, :, 100 + 790] = 0.25                          # an early reflection, inside 50 ms
    rir[0, :, 100 + 1200] = 0.25                         # late: left out
    image = early_image(clip, rir, np.array([100.4]), sample_rate=RATE)[0]
    want = np.zeros(RATE)
    want[100:] += 0.5 * clip[0, :-100]
    want[103:] += 0.25 * clip[0, :-103]
    want[890:] += 0.25 * clip[0, :-890]
    np.testing.assert_allclose(image, want, atol=1e-5)


def test_a_full_mask_gives_the_microphone_and_an_ideal_one_the_target_as_heard():
    rng = np.random.default_rng(1)
    t = np.arange(RATE) / RATE
    target = np.stack([np.sin(2 * np.pi * 440 * t), 0.6 * np.sin(2 * np.pi * 440 * (t - 0.0004))])  # ITD
    distractor = 0.3 * rng.standard_normal((2, RATE))
    mixture = (target + distractor).astype(np.float32)
    np.testing.assert_allclose(masked_mixture(np.abs(stft(mixture)), mixture), mixture.mean(axis=0), atol=1e-4)
    ideal = np.minimum(np.abs(stft(target.astype(np.float32))), np.abs(stft(mixture)))
    out = masked_mixture(ideal, mixture)
    assert si_sdr(out, target.mean(axis=0)) > 15.0 > si_sdr(mixture.mean(axis=0), target.mean(axis=0))


def test_the_last_step_is_heard_where_the_controller_took_the_robot(small_library):
    """final_step_batches yields each episode's last step as the controller played it: Stand In-Place
    still at its start, a random walker where its own actions, replayed in a fresh environment, end."""
    from m2h_ros.agents.registry import make_controller
    from m2h_ros.agents.rollout import evaluate_controller
    from m2h_ros.core.world.env import BatchEnv, EnvConfig
    from m2h_ros.core.world.episodes import EpisodeConfig, episodes_for
    from m2h_ros.models.checkpoint import DEFAULT_SEPARATOR_CHECKPOINT, load_separator
    from m2h_ros.models.runner import SeparatorRunner
    from m2h_ros.training.listener_eval import final_step_batches

    episodes = episodes_for(EpisodeConfig(task="near_target", scene_split="test", scene_preset="small",
                                          min_source_distance=3.0, sound_split="unheard", count=6, max_steps=4), small_library)
    loaded, config = load_separator(DEFAULT_SEPARATOR_CHECKPOINT), EnvConfig(camera=False)

    def last_steps(name: str) -> dict[int, dict]:
        env = BatchEnv(episodes, small_library, n_envs=4, config=config, autoreset=False)
        try:
            return {int(row): {k: v[i] for k, v in obs.items()}
                    for rows, keep, obs, _ in final_step_batches(env, episodes, make_controller(name, 4),
                                                                 SeparatorRunner(loaded, 4), desc="", progress=False)
                    for i, row in enumerate(rows)}
        finally:
            env.close()

    still = last_steps("stand_in_place")
    assert sorted(still) == list(range(6))
    for row, obs in still.items():
        assert obs["step"] == 4
        assert obs["node"] == episodes[row].start_node and obs["heading"] == episodes[row].start_heading
    walked = last_steps("random")
    played = evaluate_controller(make_controller("random", 2), SeparatorRunner(loaded, 2), episodes, small_library,
                                 env_config=config, progress=False)
    replay = BatchEnv(episodes, small_library, n_envs=1, config=config, autoreset=False)
    try:
        moved = 0
        for row, result in enumerate(played):
            replay.reset(episodes=[row])
            for action in result.actions:
                obs, *_ = replay.step(np.array([action]))
            assert (walked[row]["node"], walked[row]["heading"]) == (obs["node"][0], obs["heading"][0])
            moved += obs["node"][0] != episodes[row].start_node
        assert moved, "the random walker never left its start: the comparison shows nothing"
    finally:
        replay.close()


def test_eval_listener_pairs_two_listeners_episode_by_episode_and_refuses_other_runs(tmp_path, capsys):
    """--paired-with: this run's listener minus the other's on the same episodes (NaN STOI of music left
    out), and a run of another head, task, count or step is refused before anything is computed."""
    import json

    from scripts_as_modules import load_script

    script = load_script("eval_listener")
    mine = {"heard": {"listener": {"si_sdr_early": np.array([1.0, 2.0, 3.0]),
                                   "stoi_early": np.array([0.8, np.nan, 0.9])}}}
    other = {"listener": "a.pt", "per_episode": {"heard": {"si_sdr_early": [0.5, 2.5, 2.0],
                                                          "stoi_early": [0.7, None, 0.95]}}}
    table = script.paired_table(mine, other, tmp_path / "other_run")
    # SI-SDR differences +0.5, -0.5, +1.0: mean +0.333, better on 2 of 3; STOI +0.1, -0.05: mean +0.025
    assert "| heard | +0.333 ± 0.441 | 2 of 3 | +0.025 ± 0.075 |" in table, table
    saved = tmp_path / "other_run"
    saved.mkdir()
    (saved / "results.json").write_text(json.dumps({"task": "near_target", "count_per_split": 500, "head": "free_field:0.2",
                                 "controller": None}))
    assert script.main(["--paired-with", str(saved), "--out", str(tmp_path / "out")]) != 0
    assert "its head is 'free_field:0.2', this run's 'kemar'" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_far_target_episodes_are_heard_where_the_controller_stopped(small_library):
    """Far-target episodes end when the controller stops: a batch whose slots stop at different steps is
    refused, naming the fix, and one episode per batch is heard at the step it stopped."""
    from m2h_ros.agents.base import Controller, EpisodeStart
    from m2h_ros.core.world.env import BatchEnv, EnvConfig
    from m2h_ros.core.world.episodes import STOP, TURN_LEFT, EpisodeConfig, episodes_for
    from m2h_ros.errors import ConfigError
    from m2h_ros.models.checkpoint import DEFAULT_SEPARATOR_CHECKPOINT, load_separator
    from m2h_ros.models.runner import SeparatorRunner
    from m2h_ros.training.listener_eval import final_step_batches

    def stop_step(start) -> int:
        return 1 + start.seed % 3

    class StopsEarly(Controller):
        name, summary, uses_separator = "stops_early", "turns, then stops at a step set by the episode", False

        def _act(self, obs):
            return np.array([STOP if step >= stop_step(start) else TURN_LEFT
                             for step, start in zip(obs.step, self.starts)], np.int64)

    episodes = episodes_for(EpisodeConfig(task="far_target", scene_split="test", scene_preset="small",
                                          min_source_distance=3.0, sound_split="unheard", count=6, max_steps=8),
                            small_library)
    stops = [stop_step(EpisodeStart.of(e)) for e in episodes]
    assert len(set(stops)) > 1, "the episodes must stop at different steps for this test to show anything"
    loaded, config = load_separator(DEFAULT_SEPARATOR_CHECKPOINT), EnvConfig(camera=False)

    def last_steps(n_envs: int) -> dict[int, int]:
        env = BatchEnv(episodes, small_library, n_envs=n_envs, config=config, autoreset=False)
        try:
            return {int(row): int(obs["step"][i])
                    for rows, keep, obs, _ in final_step_batches(env, episodes, StopsEarly(n_envs),
                                                                 SeparatorRunner(loaded, n_envs), desc="", progress=False)
                    for i, row in enumerate(rows)}
        finally:
            env.close()

    with pytest.raises(ConfigError, match="one per batch"):
        last_steps(6)
    assert last_steps(1) == {row: stop + 1 for row, stop in enumerate(stops)}
