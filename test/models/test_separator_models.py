"""Separator modules: shapes through the 5-level U-Net, presets, masks, memory handling, waveform helper."""

import numpy as np
import pytest
import torch

from m2h_ros.core.audio.stft import (
    DEFAULT_STFT,
    StftConfig,
    append_class_channel,
    from_slices,
    istft,
    log_magnitude,
    stft,
    to_slices,
)
from m2h_ros.errors import AudioError, ConfigError
from m2h_ros.models.separator import (
    ClipSeparation,
    Separator,
    SeparatorConfig,
    count_parameters,
    network_input,
    separate_clip,
)
from m2h_ros.models.unet import MemoryRefiner, UNet


def with_trained_refiner(separator: Separator) -> Separator:
    """A fresh refiner is the identity (zero last conv); give it weights so the memory matters."""
    torch.nn.init.normal_(separator.refiner.body[-1].weight, std=0.05)
    return separator


@pytest.fixture(scope="module")
def separator() -> Separator:
    torch.manual_seed(0)
    return with_trained_refiner(Separator(SeparatorConfig.preset("compact"))).eval()


def test_presets_and_config_validation() -> None:
    paper = SeparatorConfig.preset("paper")
    assert paper.unet_channels == (64, 128, 256, 512, 512)
    assert SeparatorConfig.preset("compact") == SeparatorConfig()
    assert (paper.binaural_channels, paper.monaural_channels) == (32, 16)
    assert SeparatorConfig.from_dict(paper.to_dict()) == paper
    with pytest.raises(ConfigError, match="preset"):
        SeparatorConfig.preset("huge")
    with pytest.raises(ConfigError, match="unet_channels"):
        SeparatorConfig(unet_channels=(8, 16, 32, 64))
    with pytest.raises(ConfigError, match="refiner_hidden"):
        SeparatorConfig(refiner_hidden=0)
    with pytest.raises(ConfigError, match="n_freq_slices"):
        SeparatorConfig().check_stft(StftConfig(n_freq_slices=8))


def test_unet_goes_to_1x1_and_back() -> None:
    net = UNet(33, 32, (8, 8, 8, 8, 8)).eval()
    seen = []
    hooks = [layer.register_forward_hook(lambda m, i, o: seen.append(tuple(o.shape[-2:]))) for layer in net.encoder]
    out = net(torch.rand(2, 33, 32, 32))
    for hook in hooks:
        hook.remove()
    assert seen == [(16, 16), (8, 8), (4, 4), (2, 2), (1, 1)]
    assert out.shape == (2, 32, 32, 32)
    # paper widths: skip concatenation gives 2x channels at every decoder level but the first
    paper = UNet(33, 32, (64, 128, 256, 512, 512))
    assert [layer[0].in_channels for layer in paper.decoder] == [512, 1024, 512, 256, 128]
    assert [layer[0].out_channels for layer in paper.decoder] == [512, 256, 128, 64, 32]


def test_kaiming_init_scale() -> None:
    torch.manual_seed(1)
    net = UNet(33, 32, (64, 128, 256, 512, 512))
    conv = net.encoder[3][0]
    fan_in = conv.in_channels * 16
    expected_std = np.sqrt(2.0 / (1 + 0.2**2)) / np.sqrt(fan_in)
    assert conv.weight.std().item() == pytest.approx(expected_std, rel=0.02)
    assert net.head.bias.abs().max().item() == 0.0
    refiner = MemoryRefiner(16, 32)
    assert refiner.body[0].weight.std().item() == pytest.approx(np.sqrt(2.0 / (32 * 9)), rel=0.05)
    assert refiner.body[-1].weight.abs().max().item() == 0.0


def test_untrained_refiner_is_the_identity() -> None:
    torch.manual_seed(4)
    model = Separator(SeparatorConfig(unet_channels=(4, 4, 4, 4, 4), refiner_hidden=4)).eval()
    current, previous = torch.rand(2, 16, 32, 32) * 5, torch.rand(2, 16, 32, 32) * 5
    with torch.no_grad():
        torch.testing.assert_close(model.refine(current, previous), current)


def test_monaural_is_a_gain_on_the_ear_average() -> None:
    torch.manual_seed(5)
    model = Separator(SeparatorConfig(unet_channels=(4, 4, 4, 4, 4), refiner_hidden=4)).eval()
    binaural, classes = torch.rand(2, 32, 32, 32) * 10, torch.tensor([0, 1])
    torch.nn.init.zeros_(model.monaural_predictor.head.weight)  # zero score -> gain 1
    with torch.no_grad():
        torch.testing.assert_close(model.predict_monaural(binaural, classes), (binaural[:, :16] + binaural[:, 16:]) / 2)
        # a silent band stays silent whatever the gain
        binaural[:, [3, 19]] = 0
        torch.nn.init.normal_(model.monaural_predictor.head.weight)
        assert model.predict_monaural(binaural, classes)[:, 3].abs().max() == 0


def test_step_shapes_ranges_and_memory(separator: Separator) -> None:
    torch.manual_seed(2)
    mixture = torch.rand(3, 32, 32, 32) * 20
    classes = torch.tensor([0, 1, 1])
    with torch.no_grad():
        first = separator(mixture, classes)
        assert first.mask.shape == first.binaural.shape == (3, 32, 32, 32)
        assert first.monaural.shape == first.refined.shape == (3, 16, 32, 32)
        assert 0 <= first.mask.min() and first.mask.max() <= 1
        torch.testing.assert_close(first.binaural, first.mask * mixture)
        assert (first.monaural > 0).all() and (first.refined >= 0).all() and (first.refined > 0).any()
        # first step: previous := current
        torch.testing.assert_close(first.refined, separator.refine(first.monaural, first.monaural))
        second = separator(mixture, classes, first.refined)
        assert not torch.allclose(second.refined, first.refined)
        # per-sample reset: sample 1 restarts, the others keep their memory
        reset = torch.tensor([False, True, False])
        mixed = separator(mixture, classes, first.refined, reset)
        torch.testing.assert_close(mixed.refined[1], first.refined[1])
        torch.testing.assert_close(mixed.refined[[0, 2]], second.refined[[0, 2]])
        # the class plane changes the output
        other = separator(mixture, torch.tensor([1, 0, 0]))
        assert not torch.allclose(other.mask, first.mask)
    with pytest.raises(AudioError, match="memory"):
        separator(mixture, classes, torch.zeros(3, 16, 16, 32))
    with pytest.raises(AudioError, match="mixture"):
        separator(mixture[:, :16], classes)


def test_torch_input_layout_matches_core_front_end(separator: Separator) -> None:
    binaural = np.random.default_rng(6).standard_normal((2, 2, 16000)).astype(np.float32)
    seen = []
    hook = separator.binaural_separator.register_forward_pre_hook(lambda module, args: seen.append(args[0]))
    with torch.no_grad():
        separator(torch.from_numpy(to_slices(np.abs(stft(binaural)))), torch.tensor([0, 1]))
    hook.remove()
    expected = append_class_channel(to_slices(log_magnitude(stft(binaural))), np.array([0, 1]))
    np.testing.assert_allclose(seen[0].numpy(), expected, rtol=1e-6, atol=1e-6)


def test_gradients_reach_all_three_networks() -> None:
    torch.manual_seed(3)
    model = Separator(SeparatorConfig(unet_channels=(4, 4, 4, 4, 4), refiner_hidden=4)).train()
    out = model(torch.rand(2, 32, 32, 32), torch.tensor([0, 1]), torch.rand(2, 16, 32, 32))
    (out.refined.mean() + out.binaural.mean()).backward()
    for part in (model.binaural_separator, model.monaural_predictor, model.refiner):
        assert any(p.grad is not None and p.grad.abs().sum() > 0 for p in part.parameters())


def test_parameter_counts_differ_by_preset() -> None:
    compact, paper = (count_parameters(Separator(SeparatorConfig.preset(name))) for name in ("compact", "paper"))
    assert compact < 1_500_000 < 30_000_000 < paper


def test_separate_clip_network_input_is_the_sliced_magnitude() -> None:
    spec = stft(np.random.default_rng(6).standard_normal((3, 2, 16000)).astype(np.float32))
    sliced = network_input(spec)
    assert sliced.is_contiguous(memory_format=torch.channels_last)
    assert np.array_equal(sliced.numpy(), to_slices(np.abs(spec)))


def test_separate_clip_from_waveform(separator: Separator) -> None:
    rng = np.random.default_rng(5)
    binaural = rng.standard_normal((2, 2, 16000)).astype(np.float32)
    result = separate_clip(separator, binaural, 1)
    assert isinstance(result, ClipSeparation)
    assert result.magnitude.shape == (2, 512, 32) and result.waveform.shape == (2, 16000)
    assert result.memory.shape == (2, 16, 32, 32)
    # the magnitude is the un-sliced refined estimate of a direct module call
    mixture = torch.from_numpy(to_slices(np.abs(stft(binaural))))
    with torch.no_grad():
        direct = separator(mixture, torch.tensor([1, 1]))
    expected = from_slices(direct.refined.numpy())[:, 0]
    # float tolerance relative to the peak: separate_clip computes in channels_last (other summation order)
    np.testing.assert_allclose(result.magnitude, expected, rtol=1e-5, atol=1e-5 * np.abs(expected).max())
    # its waveform is that magnitude with the phase of the mean of the two mixture channels
    phase = np.exp(1j * np.angle(stft(binaural.mean(axis=1)))).astype(np.complex64)
    np.testing.assert_allclose(result.waveform, istft(result.magnitude * phase, length=16000), atol=1e-5)
    following = separate_clip(separator, binaural, np.array([1, 1]), memory=result.memory, config=DEFAULT_STFT)
    assert not np.allclose(following.magnitude, result.magnitude)
    with pytest.raises(AudioError, match="binaural"):
        separate_clip(separator, binaural[:, :1], 1)

