"""PPO on a tiny config: each quality reward has the right size on a constructed estimate, is the same
computed on the tracker's worker thread as in line, and telescopes to the episode's change of its measure, GAE matches a hand computation, a run writes loadable
checkpoints and logs, a resumed run equals an uninterrupted one, an f^R-only stage keeps the policy and lets
the approach teacher act in its slots, and experiment 6 (m2h_ros/experiments/
reward.py) reads finished runs with their training time and refuses runs that differ in more than the reward."""

import csv
import dataclasses
import json
import subprocess

import numpy as np
import pytest
import torch

from m2h_ros.core.audio.metrics import si_sdr
from m2h_ros.core.audio.stft import DEFAULT_STFT, rebuild_ground_truth_phase, stft
from m2h_ros.core.world.camera import CameraConfig
from m2h_ros.core.world.episodes import EpisodeConfig
from m2h_ros.errors import CheckpointError, ConfigError
from m2h_ros.experiments import reward
from m2h_ros.models.checkpoint import PRETRAINED_SEPARATOR_CHECKPOINT, load_separator
from m2h_ros.models.policy import load_policy
from m2h_ros.models.separator import SeparatorConfig
from m2h_ros.paths import REPO_DIR
from m2h_ros.training.ppo import PPOTrainer, gae, train
from m2h_ros.training.ppo_config import PPOConfig
from m2h_ros.training.ppo_cli import build_parser, config_from_args
from m2h_ros.training.rewards import QUALITY_REWARDS, QualityTracker, nmse, quality_measure, quality_reward
from m2h_ros.training.teacher import teacher_probabilities

TINY_SEPARATOR = SeparatorConfig(unet_channels=(8, 8, 16, 16, 16), refiner_hidden=8)  # as separator_path's
STEPS = 4


def tiny(fast_env, separator_path, **overrides) -> PPOConfig:
    episodes = EpisodeConfig(task="near_target", scene_split="train", sound_split="heard", count=3, near_radius=2.0,
                             max_steps=STEPS, scene_preset="small", min_source_distance=3.0)
    values = dict(kind="quality", episodes=episodes, env=fast_env, separator=str(separator_path), n_envs=2,
                  n_steps=STEPS, updates=4, checkpoint_every=2, threads=1, lr=3e-3)
    return PPOConfig(**{**values, **overrides})


def test_the_command_line_sets_the_entropy_coefficient():
    parser = build_parser()
    assert config_from_args(parser.parse_args(["--kind", "quality"])).entropy == 0.01  # the seed's, per kind
    assert config_from_args(parser.parse_args(["--kind", "navigation"])).entropy == 0.2
    quality = config_from_args(parser.parse_args(["--kind", "quality", "--entropy-coef", "0.2", "--frozen-refiner"]))
    assert quality.entropy == 0.2 and quality.train_refiner is False and quality.episodes.task == "near_target"
    far = config_from_args(parser.parse_args(["--kind", "navigation", "--episodes", "50"]))
    assert far.episodes.task == "far_target" and far.episodes.count == 50
    with pytest.raises(ConfigError, match="entropy_coef"):
        config_from_args(parser.parse_args(["--kind", "quality", "--entropy-coef", "-1"]))


def test_the_approach_kind_trains_on_distance_gained_alone_without_stop():
    approach = config_from_args(build_parser().parse_args(["--kind", "approach", "--no-camera"]))
    assert approach.episodes.task == "far_target" and approach.episodes.max_steps == 80
    assert (approach.env.success_reward, approach.env.distance_reward, approach.env.step_penalty) == (0.0, 1.0, 0.0)
    assert not approach.env.camera and not approach.policy_config().stop and approach.entropy == 0.2
    assert approach.episodes.scene_split == "train" and config_from_args(build_parser().parse_args(
        ["--kind", "approach", "--scene-split", "train24"])).episodes.scene_split == "train24"
    with pytest.raises(ConfigError, match="kind='approach' trains with EnvConfig"):
        PPOConfig(kind="approach")  # EnvConfig's navigation reward is not this kind's


def test_the_command_line_sets_the_final_weight_and_learning_rate():
    parser = build_parser()
    default = config_from_args(parser.parse_args(["--kind", "quality"]))
    assert default.final_weight == 10.0 and default.lr == 1e-4  # the original's final term, the seed's Adam
    run = config_from_args(parser.parse_args(["--kind", "quality", "--quality-reward", "si_sdr", "--final-weight", "0",
                                              "--lr", "3e-4"]))
    assert run.final_weight == 0.0 and run.lr == 3e-4 and run.quality_reward == "si_sdr"
    assert default.init_policy == "" and config_from_args(parser.parse_args(
        ["--kind", "quality", "--init-policy", "m2h_ros/models/default/policy_navigation.pt"])).init_policy.endswith(
        "policy_navigation.pt")
    with pytest.raises(ConfigError, match="final_weight"):
        config_from_args(parser.parse_args(["--kind", "quality", "--final-weight", "-1"]))
    with pytest.raises(ConfigError, match="lr"):
        config_from_args(parser.parse_args(["--kind", "quality", "--lr", "2"]))


def test_the_shipped_recipes_read_from_their_files(monkeypatch, capsys):
    monkeypatch.chdir(REPO_DIR)  # as scripts/train_shipped.sh runs them
    parser = build_parser()
    stage2 = config_from_args(parser.parse_args(["@params/recipes/policy_quality.args", "--threads", "2", "--updates",
                                                 "1000", "--seed", "1", "--init-policy", "stage1/policy.pt"]))
    assert (stage2.kind, stage2.n_envs, stage2.episodes.count, stage2.train_refiner, stage2.quality_reward) == \
        ("quality", 32, 10000, False, "si_sdr")
    assert (stage2.final_weight, stage2.lr, stage2.location_coef, stage2.checkpoint_every) == (0.0, 3e-4, 1.0, 50)
    assert (stage2.threads, stage2.updates, stage2.seed, stage2.init_policy) == (2, 1000, 1, "stage1/policy.pt")
    navigation = config_from_args(parser.parse_args(["@params/recipes/policy_navigation.args", "--lr", "1e-4"]))
    assert (navigation.kind, navigation.updates, navigation.teacher_coef, navigation.episodes.task) == \
        ("navigation", 1500, 1.0, "far_target")
    assert navigation.lr == 1e-4  # a flag after the file overrides it
    approach = config_from_args(parser.parse_args(["@params/recipes/policy_approach.args", "--threads", "1"]))
    assert (approach.kind, approach.entropy_coef, approach.episodes.scene_split, approach.updates, approach.seed) == \
        ("approach", 0.02, "train24", 2000, 0)  # what the shipped policy_approach.pt trained with
    assert approach.init_policy.endswith("models/default/policy_navigation_stage2.pt")  # pi^N before stage 3
    refiner_stage = config_from_args(parser.parse_args(["@params/recipes/policy_quality.args", "--no-frozen-refiner"]))
    assert refiner_stage.refiner_trained and not stage2.refiner_trained
    # Both train against the passively pretrained separator, not the default one whose f^R trained beside pi^Q.
    for config in (stage2, navigation, refiner_stage, approach):
        assert (REPO_DIR / config.separator).resolve() == PRETRAINED_SEPARATOR_CHECKPOINT.resolve()
    with pytest.raises(SystemExit):
        parser.parse_args(["@params/recipes/no_such_recipe.args"])
    assert "no_such_recipe.args" in capsys.readouterr().err


def _fields_that_differ(current: dict, recorded: dict, prefix: str = "") -> set[str]:
    """Dotted names of the fields whose values differ; a field the recorded config lacks counts as equal."""
    names = set()
    for name, value in current.items():
        if name not in recorded:
            continue
        if isinstance(value, dict) and isinstance(recorded[name], dict):
            names |= _fields_that_differ(value, recorded[name], f"{prefix}{name}.")
        elif recorded[name] != value:
            names.add(prefix + name)
    return names


def test_the_shipped_pi_n_is_the_fifth_stage_of_train_shipped_navigation(monkeypatch):
    monkeypatch.chdir(REPO_DIR)
    # scripts/train_shipped.sh navigation's stage 5, as its command line reads (seed = stage)
    stage5 = config_from_args(build_parser().parse_args(
        ["@params/recipes/policy_navigation.args", "--threads", "2", "--scene-split", "train48", "--entropy-coef", "0.01",
         "--seed", "5", "--init-policy", "runs/policy_navigation/stage4/policy.pt"])).to_dict()
    shipped = load_policy(REPO_DIR / "m2h_ros/models/default/policy_navigation.pt",
                          policy_kind="navigation").metadata["config"]
    # A field newer than the file (at any depth, e.g. the acoustics' head) is left at its default by the command line.
    assert _fields_that_differ(stage5, shipped) == set()
    assert (shipped["updates"], shipped["teacher_coef"], shipped["entropy_coef"]) == (1500, 1.0, 0.01)
    assert shipped["episodes"]["scene_split"] == "train48"
    script = (REPO_DIR / "scripts" / "train_shipped.sh").read_text()
    assert "init=m2h_ros/models/default/policy_quality.pt\n    for stage in 1 2 3 4 5; do" in script
    assert '--threads "$THREADS" --scene-split train48 --entropy-coef 0.01 \\\n            --seed "$stage"' in script
    assert "cp OUT/stage5/policy.pt m2h_ros/models/default/policy_navigation.pt" in script
    # The approach policy starts where it did: pi^N + Stop's first two stages, the recipe alone (policy_navigation_stage2.pt).
    assert ('--init-policy "$OUT/navigation_stage1/policy.pt" \\\n        --out "$OUT/navigation_stage2"' in script
            and '--init-policy "$OUT/navigation_stage2/policy.pt" \\\n        --out "$OUT/approach"' in script)


def test_train_shipped_names_its_kinds():
    result = subprocess.run(["bash", str(REPO_DIR / "scripts" / "train_shipped.sh"), "pi_x"], capture_output=True,
                            text=True, timeout=30)
    assert result.returncode == 2 and "unknown kind 'pi_x' (quality, refiner, navigation or approach)" in result.stderr


def test_gae_matches_a_hand_computation():
    rewards = torch.tensor([[1.0], [2.0], [3.0]])
    values = torch.tensor([[0.5], [1.0], [1.5]])
    dones = torch.tensor([[False], [True], [False]])
    next_value = torch.tensor([2.0])
    g, lam = 0.9, 0.8
    d2 = 3.0 + g * 2.0 - 1.5
    d1 = 2.0 - 1.0  # the episode ended: no bootstrap, no carry
    d0 = 1.0 + g * 1.0 - 0.5
    expected = torch.tensor([[d0 + g * lam * d1], [d1], [d2]])
    torch.testing.assert_close(gae(rewards, values, dones, next_value, gamma=g, lam=lam), expected)


def test_nmse_is_relative_to_the_target_power():
    target = np.ones((2, 4, 3), np.float32) * np.array([1.0, 2.0])[:, None, None]
    np.testing.assert_allclose(nmse(target * 1.5, target), [0.25, 0.25])


def test_each_quality_reward_has_the_size_of_its_measures_improvement():
    """An estimate whose magnitude error halves: NMSE falls to a quarter (reward 3/4 of it), SNR rises by
    20 log10 2 = 6.02 dB exactly, SI-SDR of the ground-truth-phase rebuild by ~6.02 dB (the error, of
    random sign in every bin, rebuilds into a waveform nearly orthogonal to the target); the last step adds
    -10 x NMSE or +10 x the dB measure."""
    rng = np.random.default_rng(0)
    wave = rng.standard_normal((3, DEFAULT_STFT.clip_samples)).astype(np.float32)
    spec = stft(wave)
    target = np.abs(spec)
    error = 0.3 * target * rng.choice([-1.0, 1.0], target.shape).astype(np.float32)  # magnitudes stay >= 0
    worse, better = target + error, target + 0.5 * error
    last = np.array([False, True, False])

    def measure(name, estimate):
        return quality_measure(name, estimate, target_spec=spec, target_mag=target, target_wave=wave,
                               config=DEFAULT_STFT)

    before, after = measure("nmse", worse), measure("nmse", better)
    np.testing.assert_allclose(after, before / 4, rtol=1e-5)
    reward = quality_reward("nmse", before, after, last, final_weight=10.0)
    np.testing.assert_allclose(reward, 0.75 * before - 10.0 * after * last, rtol=1e-5)
    original = before - after  # the formulation before quality_reward existed: the default is bit-identical
    original[last] -= 10.0 * after[last]
    np.testing.assert_array_equal(reward, original)
    for name in ("snr", "si_sdr"):
        before, after = measure(name, worse), measure(name, better)
        reward = quality_reward(name, before, after, last, final_weight=10.0)
        np.testing.assert_allclose(reward[~last], 20 * np.log10(2), rtol=1e-5 if name == "snr" else 0.02)
        np.testing.assert_allclose(reward[last], after[last] - before[last] + 10.0 * after[last], rtol=1e-12)
    # SI-SDR is measured on the waveform rebuilt with the target's phase: the exact estimate's is ~perfect.
    assert np.all(measure("si_sdr", target) > 60) and np.all(measure("si_sdr", better) < 30)
    # ... and is the evaluation's score of it, bit for bit (the reward is given the target's STFT).
    np.testing.assert_array_equal(measure("si_sdr", better), si_sdr(rebuild_ground_truth_phase(better, wave), wave))
    with pytest.raises(ConfigError, match="quality_reward"):
        PPOConfig(quality_reward="pesq")


@pytest.mark.parametrize("name", QUALITY_REWARDS)
def test_the_quality_trackers_threaded_rewards_are_the_in_line_ones(name):
    """Steps submitted two ahead of their settling (episodes ending in between replace the targets the
    pending steps read) give the rewards of measuring in line, bit for bit, and those are each step's
    change of the measure against the episode's target."""
    rng = np.random.default_rng(1)
    n, config = 3, DEFAULT_STFT
    waves = rng.standard_normal((12, n, config.clip_samples)).astype(np.float32)
    magnitudes = np.abs(stft(waves[0]))
    steps = [(np.abs(magnitudes * rng.uniform(0.5, 1.5, magnitudes.shape)).astype(np.float32),
              np.array(ended, np.int64)) for ended in ([], [1], [], [0, 2], [0, 1, 2], [])]
    threaded, in_line = (QualityTracker(name, final_weight=2.0, config=config, threaded=flag) for flag in (True, False))
    for tracker in (threaded, in_line):
        tracker.start(waves[0], magnitudes)
    measure, targets = in_line.measure_now.copy(), waves[0].copy()
    pending, got, expected = [], [], []
    for k, (estimate, ended) in enumerate(steps):
        fresh = estimate[ended] * 0.9
        pending.append(threaded.submit(estimate, ended, fresh, waves[k + 1][: len(ended)]))
        if k % 2:
            pending[-1].start()  # runs beside the next submit, which replaces ended slots' targets; others start late
        expected.append(in_line.settle(in_line.submit(estimate, ended, fresh, waves[k + 1][: len(ended)])))
        if len(pending) == 2:
            got.append(threaded.settle(pending.pop(0)))
        after = quality_measure(name, estimate, target_spec=stft(targets), target_mag=np.abs(stft(targets)),
                                target_wave=targets, config=config)
        sign, last = (-1.0 if name == "nmse" else 1.0), np.isin(np.arange(n), ended)
        np.testing.assert_allclose(expected[-1], sign * (after - measure) + sign * 2.0 * after * last, rtol=1e-6)
        targets[ended] = waves[k + 1][: len(ended)]
        measure = after.copy()
        if len(ended):
                measure[ended] = quality_measure(name, fresh, target_spec=stft(targets[ended]),
                                             target_mag=np.abs(stft(targets[ended])), target_wave=targets[ended],
                                             config=config)
    got.append(threaded.settle(pending.pop()))
    np.testing.assert_array_equal(np.array(got), np.array(expected))
    for key, value in in_line.state().items():
        np.testing.assert_array_equal(threaded.state()[key], value, err_msg=key)


@pytest.mark.parametrize("name", QUALITY_REWARDS)
def test_quality_rewards_telescope_to_the_episodes_change(name, fast_env, separator_path, folder_library, tmp_path):
    trainer = PPOTrainer(tiny(fast_env, separator_path, quality_reward=name), folder_library, out_dir=tmp_path,
                         progress=False)
    try:
        trainer._begin()
        first = trainer.quality.measure_now.copy()
        rollout, _, finished = trainer._collect()  # n_steps == episode length: every slot ends at the last step
    finally:
        trainer.env.close()
    assert len(finished) == 2 and all(r["length"] == STEPS for r in finished)
    total = torch.stack(rollout.rewards).sum(dim=0).numpy()
    last = np.array([r["final_quality"] for r in finished])
    final_nmse = np.array([r["final_nmse"] for r in finished])
    if name == "nmse":
        np.testing.assert_allclose(total, first - last - 10.0 * last, rtol=1e-5, atol=1e-6)
        np.testing.assert_array_equal(last, final_nmse)
        assert np.all(first > 0)
    else:
        np.testing.assert_allclose(total, last - first + 10.0 * last, rtol=1e-5, atol=1e-5)
    if name == "snr":
        np.testing.assert_allclose(last, -10 * np.log10(final_nmse), rtol=1e-9)
    assert torch.stack(rollout.dones)[-1].all() and not torch.stack(rollout.dones)[:-1].any()
    assert np.all(np.isfinite(total))


def test_a_mixed_reward_adds_the_weighted_navigation_reward(fast_env, separator_path, folder_library, tmp_path):
    config = tiny(fast_env, separator_path, quality_reward="si_sdr", final_weight=0.0, navigation_coef=2.0)
    trainer = PPOTrainer(config, folder_library, out_dir=tmp_path, progress=False)
    env_rewards, env_step = [], trainer.env.step

    def recording_step(actions):
        result = env_step(actions)
        env_rewards.append(result[1].astype(np.float64))
        return result

    trainer.env.step = recording_step
    try:
        trainer._begin()
        first = trainer.quality.measure_now.copy()
        rollout, _, finished = trainer._collect()
    finally:
        trainer.env.close()
    total = torch.stack(rollout.rewards).sum(dim=0).numpy()
    navigation = np.sum(env_rewards, axis=0)  # 0.25 per metre gained, -0.01 a step
    last = np.array([r["final_quality"] for r in finished])
    np.testing.assert_allclose(total, last - first + 2.0 * navigation, rtol=1e-5, atol=1e-5)
    assert np.all(navigation != -0.01 * STEPS)  # every slot moved relative to its target
    with pytest.raises(ConfigError, match="navigation_coef=-1"):
        tiny(fast_env, separator_path, navigation_coef=-1)
    assert config_from_args(build_parser().parse_args(["--kind", "quality", "--navigation-coef", "4"])).navigation_coef == 4.0


def test_the_refiner_learns_from_the_memory_acting_used(fast_env, separator_path, folder_library, tmp_path):
    trainer = PPOTrainer(tiny(fast_env, separator_path, n_steps=2 * STEPS), folder_library, out_dir=tmp_path,
                         progress=False)
    acting = []  # the refined estimate of each observation the policy acted on (not episodes' final ones)
    step = trainer.runner.step

    def recording(*args, **kwargs):
        result = step(*args, **kwargs)
        if "rows" not in kwargs:
            acting.append(np.array(result.refined))
        return result

    trainer.runner.step = recording
    try:
        trainer._begin()
        rollout, _, _ = trainer._collect()
    finally:
        trainer.env.close()
    starts = torch.stack(rollout.starts)
    continued = [(t, slot) for t in range(1, len(rollout.memory)) for slot in range(2) if not starts[t, slot]]
    assert len(continued) >= STEPS
    for t, slot in continued:  # the memory stored with observation t is the estimate of t - 1
        np.testing.assert_array_equal(rollout.memory[t][slot].reshape(-1).numpy(), acting[t - 1][slot].reshape(-1))


def test_training_writes_checkpoints_and_resumes_exactly(fast_env, separator_path, folder_library, tmp_path):
    config = tiny(fast_env, separator_path)
    whole = train(config, folder_library, out_dir=tmp_path / "whole", progress=False, command="test")
    part = train(config, folder_library, out_dir=tmp_path / "part", progress=False, stop_after=1)
    assert len(part.history) == 1
    resumed = train(config, folder_library, out_dir=tmp_path / "part", progress=False)
    for name, tensor in whole.net.state_dict().items():
        torch.testing.assert_close(resumed.net.state_dict()[name], tensor, rtol=0, atol=0, msg=name)
    same = ("env_steps", "episodes", "return_window", "final_nmse_window", "value_loss", "action_loss", "entropy",
            "refiner_l1")
    # Weights are bit-identical; logged float64 means may differ in the last bit (numpy's reductions
    # round with the arrays' memory alignment, and restored arrays are new allocations).
    for got, expected in zip(resumed.history, whole.history, strict=True):
        assert [got[k] for k in same] == pytest.approx([expected[k] for k in same], rel=1e-12, abs=0)

    initial = PPOTrainer(config, folder_library, out_dir=tmp_path / "unused", progress=False)
    initial.env.close()
    assert any(not torch.equal(t, initial.net.state_dict()[n]) for n, t in whole.net.state_dict().items())
    warm = PPOTrainer(dataclasses.replace(config, init_policy=str(whole.checkpoint)), folder_library,
                      out_dir=tmp_path / "warm", progress=False)
    warm.env.close()
    for name, tensor in whole.net.state_dict().items():
        torch.testing.assert_close(warm.net.state_dict()[name], tensor, rtol=0, atol=0, msg=name)
    loaded = load_policy(whole.checkpoint, policy_kind="quality")
    for name, tensor in whole.net.state_dict().items():
        torch.testing.assert_close(loaded.net.state_dict()[name], tensor.cpu())  # loaded on the CPU
    assert loaded.metadata["updates"] == 4 and loaded.metadata["command"] == "test"
    refined = load_separator(tmp_path / "whole" / "separator.pt", expected_config=TINY_SEPARATOR)
    original = load_separator(separator_path)
    assert not torch.equal(refined.separator.refiner.body[0].weight, original.separator.refiner.body[0].weight)
    torch.testing.assert_close(refined.separator.monaural_predictor.head.weight,
                               original.separator.monaural_predictor.head.weight)  # f^M frozen
    stage = refined.metadata["refiner_trained_with"]  # the f^R stage's provenance, also beside it as JSON
    assert (stage["command"], stage["updates"], stage["env_steps"]) == ("test", 4, 4 * 2 * STEPS)
    assert json.loads((tmp_path / "whole" / "separator.json").read_text())["refiner_trained_with"] == stage
    with open(tmp_path / "whole" / "log.csv") as f:
        rows = list(csv.DictReader(f))
    assert [int(r["update"]) for r in rows] == [1, 2, 3, 4] and int(rows[-1]["env_steps"]) == 4 * 2 * STEPS
    assert (tmp_path / "whole" / "curve.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

    with pytest.raises(CheckpointError, match="other settings.*lr"):
        train(dataclasses.replace(config, lr=1e-3), folder_library, out_dir=tmp_path / "part", progress=False)


def test_a_refiner_only_stage_keeps_the_policy_and_lets_the_teacher_act(fast_env, separator_path, folder_library,
                                                                       tmp_path):
    start = train(tiny(fast_env, separator_path, updates=1), folder_library, out_dir=tmp_path / "start", progress=False)
    config = tiny(fast_env, separator_path, frozen_policy=True, teacher_slots=1, init_policy=str(start.checkpoint),
                  n_steps=3 * STEPS, updates=2)
    trainer = PPOTrainer(config, folder_library, out_dir=tmp_path / "stage", progress=False)
    step, followed = trainer.env.step, []

    def recording(actions):  # slot 0's action must be one the teacher gives at the pose it acts from
        teacher = teacher_probabilities(trainer.env.current_episodes[:1], trainer.obs["node"][:1],
                                        trainer.obs["heading"][:1], trainer.actions.numpy())[0]
        followed.append(teacher[list(trainer.actions.numpy()).index(actions[0])] > 0)
        return step(actions)

    trainer.env.step = recording
    try:
        result = trainer.run()
    finally:
        trainer.env.close()
    assert len(followed) == 2 * 3 * STEPS and all(followed)
    for name, tensor in start.net.state_dict().items():
        torch.testing.assert_close(result.net.state_dict()[name], tensor, rtol=0, atol=0, msg=name)
    refined = load_separator(tmp_path / "stage" / "separator.pt", expected_config=TINY_SEPARATOR)
    assert not torch.equal(refined.separator.refiner.body[0].weight,
                           load_separator(separator_path).separator.refiner.body[0].weight)
    assert np.isnan(result.history[-1]["action_loss"]) and np.isfinite(result.history[-1]["refiner_l1"])

    for overrides, message in ((dict(teacher_slots=1), "needs frozen_policy"),
                               (dict(frozen_policy=True, train_refiner=False), "needs train_refiner"),
                               (dict(frozen_policy=True, location_coef=1.0), "location_coef must be 0"),
                               (dict(frozen_policy=True, teacher_slots=3), "exceeds n_envs=2")):
        with pytest.raises(ConfigError, match=message):
            tiny(fast_env, separator_path, **overrides)


def test_av_navigator_and_novelty_train_with_the_camera(fast_env, separator_path, folder_library, tmp_path):
    env = dataclasses.replace(fast_env, camera=True, camera_config=CameraConfig(width=64, height=64))
    for kind in ("av_navigator", "novelty"):
        config = tiny(fast_env, separator_path, kind=kind, env=env, updates=1)
        result = train(config, folder_library, out_dir=tmp_path / kind, progress=False)
        loaded = load_policy(result.checkpoint, policy_kind=kind)
        assert loaded.config.camera and loaded.config.stop == (kind == "av_navigator")
        assert loaded.config.inputs == ("mixture" if kind == "av_navigator" else "separation")
        assert np.isfinite(result.history[-1]["value_loss"]) and not (tmp_path / kind / "separator.pt").exists()
        if kind == "novelty":  # every step is rewarded 1/sqrt(n) for some n >= 1, so returns are positive
            assert 0 < result.history[-1]["return_window"] <= STEPS


def test_approach_trains_without_stop_on_the_distance_gained(fast_env, separator_path, folder_library, tmp_path):
    env = dataclasses.replace(fast_env, success_reward=0.0, distance_reward=1.0, step_penalty=0.0)
    config = tiny(fast_env, separator_path, kind="approach", env=env, updates=2)
    result = train(config, folder_library, out_dir=tmp_path, progress=False)
    loaded = load_policy(result.checkpoint, policy_kind="approach")
    assert not loaded.config.stop and loaded.config.inputs == "separation"
    # An episode's return is the geodesic distance it gained: at most its start distance, at least minus
    # what STEPS moves of 1 m can lose.
    returns = result.history[-1]["return_window"]
    assert np.isfinite(returns) and -STEPS <= returns <= STEPS and returns != 0


def test_speed_paths_give_the_plain_paths_losses(fast_env, separator_path, folder_library, tmp_path, monkeypatch):
    """The update's speed paths (channels_last encoders and f^R rows, the GRU over reset-free stretches)
    give the losses and weights of the plain ones (NCHW, one GRU call per step, f^R's minibatches as
    ``[:, slots].flatten(0, 1)`` of the stacked rollout) to float tolerance; 2 minibatches, camera on."""
    import copy  # noqa: PLC0415

    import torch.nn.functional as F  # noqa: PLC0415

    from m2h_ros.models import policy as policy_module  # noqa: PLC0415

    # On CUDA both paths run in IEEE float32 (models.device.ieee_float32_cuda): cuDNN's default TF32 put them 1e-3 apart.
    env = dataclasses.replace(fast_env, camera=True, camera_config=CameraConfig(width=64, height=64))
    config = tiny(env, separator_path, n_envs=4, n_minibatches=2, preset="compact", n_steps=STEPS + 2)
    trainer = PPOTrainer(config, folder_library, out_dir=tmp_path, progress=False)
    try:
        trainer._begin()
        rollout, next_value, _ = trainer._collect()  # episodes end and start inside it
    finally:
        trainer.env.close()
    assert torch.stack(rollout.starts)[1:].any()  # a cut inside the sequence
    # The tiny refiner's last conv is zero (memory = estimate): make memory and refiner matter.
    g = torch.Generator().manual_seed(0)
    rollout.memory = [m * torch.rand(m.shape, generator=g).contiguous(memory_format=torch.channels_last) * 2
                      for m in rollout.memory]
    with torch.no_grad():
        weight = trainer.separator.refiner.body[-1].weight
        weight.copy_(torch.randn(weight.shape, generator=g) * 0.1)
    start = copy.deepcopy((trainer.net.state_dict(), trainer.optimizer.state_dict(),
                           trainer.separator.refiner.state_dict(), trainer.refiner_optimizer.state_dict()))
    rng_state = copy.deepcopy(trainer.rng.bit_generator.state)

    def run(update_refiner):
        trainer.net.load_state_dict(start[0])
        trainer.optimizer.load_state_dict(start[1])
        trainer.separator.refiner.load_state_dict(start[2])
        trainer.refiner_optimizer.load_state_dict(start[3])
        trainer.rng.bit_generator.state = copy.deepcopy(rng_state)
        losses = trainer._update_policy(rollout, next_value)
        losses["refiner_l1"] = update_refiner()
        return losses, copy.deepcopy((trainer.net.state_dict(), trainer.separator.refiner.state_dict()))

    def plain_refiner():  # the update as it was written before, on NCHW tensors
        monaural, memory, target, starts = (torch.stack(x).contiguous().to(trainer.device) for x in
                                            (rollout.monaural, rollout.memory, rollout.target, rollout.starts))
        params, per_batch, total = list(trainer.separator.refiner.parameters()), 2, []
        for _ in range(config.refiner_epochs):
            order = trainer.rng.permutation(config.n_envs)
            for b in range(2):
                slots = torch.from_numpy(order[b * per_batch: (b + 1) * per_batch])
                refined = trainer.separator.refine(monaural[:, slots].flatten(0, 1), memory[:, slots].flatten(0, 1),
                                                   starts[:, slots].flatten())
                loss = F.l1_loss(refined, target[:, slots].flatten(0, 1))
                trainer.refiner_optimizer.zero_grad()
                loss.backward()
                trainer._step(trainer.refiner_optimizer, params)
                total.append(loss.item())
        return float(np.mean(total))

    def plain_recur(self, features, hidden, starts):
        outputs = []
        for t in range(features.shape[0]):
            hidden = hidden * (~starts[t]).unsqueeze(1).to(hidden.dtype)
            out, h = self.gru(features[t: t + 1], hidden.unsqueeze(0))
            hidden = h[0]
            outputs.append(out[0])
        return torch.stack(outputs), hidden

    fast_losses, fast_weights = run(lambda: trainer._update_refiner(rollout))
    monkeypatch.setattr(policy_module.ConvEncoder, "forward", lambda self, x: self.cnn(x.contiguous()))
    monkeypatch.setattr(policy_module.PolicyNet, "_recur", plain_recur)
    plain_losses, plain_weights = run(plain_refiner)
    assert fast_losses == pytest.approx(plain_losses, rel=1e-4, abs=1e-6, nan_ok=True)  # teacher_ce: nan, no teacher
    for fast, plain in zip(fast_weights, plain_weights, strict=True):
        for name, tensor in plain.items():
            # atol: float32 rounding of near-zero weights (1.6e-6 seen on CUDA); an Adam step is lr = 3e-3
            torch.testing.assert_close(fast[name], tensor, rtol=1e-4, atol=1e-5, msg=lambda m, name=name: f"{name}: {m}")
    assert any(not torch.equal(t, start[0][n]) for n, t in fast_weights[0].items())  # the update did move them



def test_reward_experiment_reads_compares_and_plots_runs(fast_env, separator_path, folder_library, tmp_path):
    config = tiny(fast_env, separator_path, updates=1, train_refiner=False)
    for name in ("nmse", "snr"):
        train(dataclasses.replace(config, quality_reward=name), folder_library, out_dir=tmp_path / name,
              progress=False, command=f"train {name}")
    runs = [reward.load_run(tmp_path / name) for name in ("nmse", "snr")]
    assert [r.label for r in runs] == ["pi^Q (nmse)", "pi^Q (snr)"]
    reward.check_comparable(runs)
    timing = runs[1].timing()
    assert timing["updates"] == 1 and timing["env_steps"] == 2 * STEPS and timing["command"] == "train snr"
    assert timing["env_steps_per_s"] == pytest.approx(timing["env_steps"] / timing["wall_seconds"])
    assert timing["median_update_env_steps_per_s"] == pytest.approx(np.median([r["sps"] for r in runs[1].log]))
    table = reward.timing_table(runs)
    assert table.count("\n") == 4 and "pi^Q (snr) | 1 | 8 |" in table
    png = reward.plot_training(runs, tmp_path / "curves.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

    with pytest.raises(ConfigError, match="share a reward"):
        reward.check_comparable([runs[0], runs[0]])
    # Second stages, each from its own reward's first run, or all from one policy: comparable; from another
    # reward's run: refused.
    for name, start in (("nmse", "nmse"), ("snr", "snr"), ("snr_from_nmse", "nmse"), ("si_sdr_from_snr", "snr")):
        train(dataclasses.replace(config, quality_reward=name.split("_from")[0], seed=1,
                                  init_policy=str(tmp_path / start / "policy.pt")),
              folder_library, out_dir=tmp_path / f"{name}_stage2", progress=False)
    stage2 = {name: reward.load_run(tmp_path / f"{name}_stage2") for name in ("nmse", "snr", "snr_from_nmse",
                                                                             "si_sdr_from_snr")}
    reward.check_comparable([stage2["nmse"], stage2["snr"]])
    reward.check_comparable([stage2["nmse"], stage2["snr_from_nmse"]])
    with pytest.raises(ConfigError, match="continues .*snr, which trained pi\\^Q \\(snr\\)"):
        reward.check_comparable([stage2["nmse"], stage2["si_sdr_from_snr"]])
    train(dataclasses.replace(config, quality_reward="si_sdr", seed=1), folder_library, out_dir=tmp_path / "seed1",
          progress=False)
    with pytest.raises(ConfigError, match="differs .* in seed$"):
        reward.check_comparable([runs[0], reward.load_run(tmp_path / "seed1")])
    train(dataclasses.replace(config, train_refiner=True), folder_library, out_dir=tmp_path / "refined",
          progress=False)
    with pytest.raises(ConfigError, match="trained f\\^R"):
        reward.load_run(tmp_path / "refined")
    with pytest.raises(ConfigError, match="not a finished training run"):
        reward.load_run(tmp_path / "missing")
