"""The listener output: started from f^B it is f^B's masked mixture, its two-ear filter learns to take a
distractor out where a mask cannot, it keeps its shapes and checkpoint, and it refuses bad input."""

from pathlib import Path

import numpy as np
import pytest
import torch

from m2h_ros.core.audio.metrics import si_sdr
from m2h_ros.core.audio.stft import DEFAULT_STFT, masked_mixture, stft
from m2h_ros.errors import AudioError, CheckpointError, ConfigError
from m2h_ros.models.checkpoint import save_separator
from m2h_ros.models.inference import fuse_for_inference
from m2h_ros.models.listener import Listener, ListenerConfig, listen, load_listener, save_listener
from m2h_ros.models.separator import Separator, SeparatorConfig
from m2h_ros.training.listener_train import (ListenerExamples, ListenerTrainConfig, WaveformTransform,
                                             listener_loss, si_sdr_torch, train_listener)

RATE = DEFAULT_STFT.sample_rate
CLASSES = ("speech", "music")


def random_separator(seed: int = 0) -> Separator:
    torch.manual_seed(seed)
    separator = Separator(SeparatorConfig.preset("compact")).eval()
    for module in separator.modules():  # BatchNorm statistics other than (0, 1), so copying them matters
        if isinstance(module, torch.nn.BatchNorm2d):
            module.running_mean.uniform_(-0.1, 0.1)
            module.running_var.uniform_(0.5, 1.5)
    return separator


def two_ear_scene(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(n, 2, N) mixtures and (n, 2, N) targets: a noise target straight ahead (the same at both ears)
    and a noise distractor at the side (one ear hears it 8 samples after the other, at 0.8 gain), each
    source's spectrum alike, so no magnitude mask tells them apart but the phase does."""
    rng = np.random.default_rng(seed)
    target = rng.standard_normal((n, RATE)).astype(np.float32)
    distractor = rng.standard_normal((n, RATE + 8)).astype(np.float32)
    targets = np.stack([target, target], axis=1)
    distractors = np.stack([distractor[:, 8:], 0.8 * distractor[:, :-8]], axis=1)
    return (targets + distractors).astype(np.float32), targets


def test_a_listener_started_from_f_b_gives_f_b_masked_mixture():
    separator = random_separator()
    listener = Listener.from_separator(separator).eval()
    mixture, _ = two_ear_scene(3, seed=1)
    classes = np.array([0, 1, 0])
    spec = stft(mixture)
    with torch.no_grad():
        mask, _ = separator.separate_binaural(
            torch.from_numpy(np.ascontiguousarray(np.abs(spec).reshape(3, 32, 32, 32))), torch.from_numpy(classes))
    expected = masked_mixture(np.abs(spec) * mask.numpy().reshape(3, 2, 512, 32), mixture, binaural=True)
    out = listen(listener, mixture, classes)
    assert out.shape == (3, 2, RATE)
    np.testing.assert_allclose(out, expected, atol=1e-4 * np.abs(expected).max())
    fused = listen(fuse_for_inference(listener), mixture, classes)
    np.testing.assert_allclose(fused, out, atol=1e-4 * np.abs(out).max())
    with_taps = listen(Listener.from_separator(separator, filter_taps=3).eval(), mixture, classes)
    np.testing.assert_allclose(with_taps, out, atol=1e-6 * np.abs(out).max())


def test_earlier_frames_reach_the_output_through_the_filter_taps():
    """A filter that passes only the left ear one frame late gives the left ear's spectrum shifted by a frame."""
    listener = Listener(ListenerConfig(filter_taps=2)).eval()
    torch.nn.init.constant_(listener.unet.head.bias, -30.0)  # mask ~0
    torch.nn.init.zeros_(listener.unet.head.weight)
    bias = torch.zeros(listener.filter_head.out_channels).reshape(-1, 16)  # (terms, slices), terms as in forward
    # out ear 0, input "ear x tap" index 2 (tap 1 of ear 0), real part -> index ((0 * 4) + 2) * 2 + 0
    bias[(0 * 4 + 2) * 2] = 1.0
    with torch.no_grad():
        listener.filter_head.bias.copy_(bias.reshape(-1))
    spec = torch.randn(1, 2, 512, 32, dtype=torch.complex64)
    with torch.no_grad():
        out = listener(spec, torch.zeros(1, dtype=torch.int64))
    torch.testing.assert_close(out[0, 0, :, 1:], spec[0, 0, :, :-1], atol=1e-5, rtol=1e-5)
    assert out[0, 0, :, 0].abs().max() < 1e-5 and out[0, 1].abs().max() < 1e-5


def test_the_two_ear_filter_learns_to_take_out_a_distractor_a_mask_cannot(tmp_path: Path):
    torch.manual_seed(0)
    mixture, targets = two_ear_scene(64, seed=2)
    examples = ListenerExamples(mixture.astype(np.float16), targets.astype(np.float16), np.zeros(64, np.int64))
    listener = Listener(ListenerConfig(unet_channels=(8, 8, 8, 8, 8)))
    train_listener(listener, examples, class_map=np.array([0, 1]), stft_config=DEFAULT_STFT,
                   config=ListenerTrainConfig(steps=60, batch_size=8, learning_rate=3e-3, validation_fraction=0.0,
                                              checkpoint_every=30), state_path=tmp_path / "state.pt",
                   log=lambda line: None, progress=False)
    test_mixture, test_targets = two_ear_scene(4, seed=3)
    out = listen(listener.eval(), test_mixture, np.zeros(4, np.int64))
    microphone = si_sdr(test_mixture, test_targets)
    ideal = np.minimum(np.abs(stft(test_targets)), np.abs(stft(test_mixture)))
    ideal_mask_gain = si_sdr(masked_mixture(ideal, test_mixture, binaural=True), test_targets) - microphone
    gain = si_sdr(out, test_targets) - microphone
    # an ideal magnitude mask gains about 2.4 dB at each ear here, the trained filter about 6
    assert gain.min() > ideal_mask_gain.max() + 2.0, (gain, ideal_mask_gain)


def test_training_resumes_from_its_state(tmp_path: Path):
    mixture, targets = two_ear_scene(16, seed=4)
    examples = ListenerExamples(mixture.astype(np.float16), targets.astype(np.float16), np.zeros(16, np.int64))

    class Killed(Exception):
        pass

    def run(state: Path, *, kill_at: str | None = None) -> Listener:
        def log(line: str) -> None:
            if kill_at and line.startswith(kill_at):
                raise Killed
        torch.manual_seed(0)
        listener = Listener(ListenerConfig(unet_channels=(8, 8, 8, 8, 8)))
        train_listener(listener, examples, class_map=np.array([0, 1]), stft_config=DEFAULT_STFT,
                       config=ListenerTrainConfig(steps=4, batch_size=4, validation_fraction=0.0, checkpoint_every=2),
                       state_path=state, log=log, progress=False)
        return listener

    whole = run(tmp_path / "whole.pt")
    with pytest.raises(Killed):
        run(tmp_path / "parts.pt", kill_at="step 2 ")  # killed after its step-2 checkpoint
    resumed = run(tmp_path / "parts.pt")
    for a, b in zip(whole.state_dict().values(), resumed.state_dict().values(), strict=True):
        torch.testing.assert_close(a, b)


def test_the_waveform_transform_and_loss_match_the_core():
    mixture, targets = two_ear_scene(2, seed=5)
    transform = WaveformTransform(DEFAULT_STFT)
    spec = transform.stft(torch.from_numpy(mixture))
    np.testing.assert_allclose(spec.numpy(), stft(mixture), atol=1e-3)
    np.testing.assert_allclose(transform.istft(spec, RATE).numpy(), mixture, atol=1e-4)
    np.testing.assert_allclose(si_sdr_torch(torch.from_numpy(mixture), torch.from_numpy(targets)).numpy(),
                               si_sdr(mixture, targets), atol=1e-3)
    # the loss: minus the mean of the per-ear and the ear-mean SI-SDR
    ears, mean = si_sdr(mixture, targets).mean(axis=1), si_sdr(mixture.mean(axis=1), targets.mean(axis=1))
    assert float(listener_loss(torch.from_numpy(mixture), torch.from_numpy(targets))) == pytest.approx(
        -np.mean((ears + mean) / 2), abs=1e-3)


def test_bad_input_raises_a_clear_error():
    listener = Listener.from_separator(random_separator()).eval()
    mixture, _ = two_ear_scene(1, seed=6)
    bad = mixture.copy()
    bad[0, 1, 100] = np.nan
    with pytest.raises(AudioError, match="NaN"):
        listen(listener, bad, np.array([0]))
    with pytest.raises(AudioError, match=r"\(B, 2, N\)"):
        listen(listener, mixture[:, :1], np.array([0]))
    with pytest.raises(AudioError, match="complex"):
        listener(torch.zeros(1, 2, 512, 32), torch.zeros(1, dtype=torch.int64))
    with pytest.raises(ConfigError, match="unet_channels"):
        ListenerConfig(unet_channels=(8, 8))


def test_checkpoint_round_trip_and_refusals(tmp_path: Path):
    listener = Listener.from_separator(random_separator(seed=1)).eval()
    torch.nn.init.normal_(listener.filter_head.weight, std=0.01)
    path = save_listener(tmp_path / "listener.pt", listener, classes=CLASSES, metadata={"command": "test"})
    loaded = load_listener(path)
    assert loaded.classes == CLASSES and loaded.metadata == {"command": "test"} and loaded.class_index("music") == 1
    mixture, _ = two_ear_scene(1, seed=7)
    np.testing.assert_array_equal(listen(loaded.listener, mixture, np.array([1])), listen(listener, mixture, np.array([1])))
    with pytest.raises(ConfigError, match="unknown target class"):
        loaded.class_index("noise")
    separator_path = save_separator(tmp_path / "separator.pt", random_separator(), classes=CLASSES)
    with pytest.raises(CheckpointError, match="expected 'm2h_listener'"):
        load_listener(separator_path)
    with pytest.raises(CheckpointError, match="not found"):
        load_listener(tmp_path / "absent.pt")


def test_examples_with_approach_are_heard_on_the_way_to_the_target(small_library):
    """render_examples(approach=1) walks each episode along a shortest path to its target, so the
    examples after the start are heard closer to it than a random walk's; approach=0 keeps the random
    walk's examples exactly as before the option existed (the same draws)."""
    from m2h_ros.core.world.env import BatchEnv, EnvConfig
    from m2h_ros.core.world.episodes import MOVE_FORWARD, TURN_RIGHT, EpisodeConfig, episodes_for
    from m2h_ros.training.listener_train import render_examples

    episodes = episodes_for(EpisodeConfig(task="near_target", scene_split="test", scene_preset="small",
                                          min_source_distance=3.0, sound_split="unheard", count=4), small_library)
    config = EnvConfig(camera=False)
    walked = {p: render_examples(episodes, small_library, env_config=config, poses=4, approach=p, n_envs=4,
                                 progress=False) for p in (0.0, 1.0)}
    # The random walk, replayed by hand with the draws render_examples makes, ends where it did.
    rng, env = np.random.default_rng(0), BatchEnv(episodes, small_library, n_envs=4, config=config, autoreset=False)
    try:
        obs, _ = env.reset(episodes=list(range(4)))
        heard = [obs["audio"]]
        for _ in range(3):
            obs, *_ = env.step(rng.integers(MOVE_FORWARD, TURN_RIGHT + 1, 4))
            heard.append(obs["audio"])
    finally:
        env.close()
    # render_examples stacks pose by pose, each pose a batch of the 4 episodes
    np.testing.assert_array_equal(walked[0.0].mixture, np.concatenate(heard).astype(np.float16))
    target_share = {p: [float(si_sdr(e.early[k].astype(np.float64).mean(0), e.mixture[k].astype(np.float64).mean(0)))
                        for k in range(4, 16)] for p, e in walked.items()}
    # the target's share of what is heard after the start: 3.6 dB approaching, 2.6 walking at random
    assert np.mean(target_share[1.0]) > np.mean(target_share[0.0]) + 0.5, target_share
