"""The fast inference path (BatchNorm folded, fused activations, prepacked oneDNN weights) computes
the same f^B / f^M / f^R outputs as the separator as trained, and the thread count by batch size."""

import io

import numpy as np
import pytest
import torch
from torch import nn

from m2h_ros.core.audio.stft import from_slices, stft, to_slices
from m2h_ros.errors import ConfigError
from m2h_ros.models.checkpoint import DEFAULT_SEPARATOR_CHECKPOINT, load_separator
from m2h_ros.models.inference import FusedConv, fuse_for_inference
from m2h_ros.models.separator import Separator, SeparatorConfig, separate_clip
from m2h_ros.models.threads import SINGLE_THREAD_MAX_BATCH, inference_threads

# float32 rounding of a folded affine map and another summation order, relative to the output's peak
TOLERANCE = 2e-5


@pytest.fixture(scope="module", autouse=True)
def one_thread():
    """Batch-1 inference runs on one thread (models.threads); it also keeps these tests fast when the
    machine's other core is busy and OpenMP threads would spin."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def trained_like(config: SeparatorConfig, seed: int = 0) -> Separator:
    """Random weights with BatchNorm statistics away from (0, 1) and a non-zero refiner, in eval mode."""
    torch.manual_seed(seed)
    separator = Separator(config)
    with torch.no_grad():
        for layer in separator.modules():
            if isinstance(layer, nn.BatchNorm2d):
                layer.running_mean.uniform_(-0.5, 0.5)
                layer.running_var.uniform_(0.3, 3.0)
                layer.weight.uniform_(0.5, 1.5)
                layer.bias.uniform_(-0.3, 0.3)
        nn.init.normal_(separator.refiner.body[-1].weight, std=0.05)
    return separator.eval()


def assert_steps_close(expected, actual) -> None:
    for name, a, b in zip(expected._fields, expected, actual, strict=True):
        assert a.shape == b.shape, name
        peak = float(a.abs().max())
        assert peak > 0, name
        assert float((a - b).abs().max()) <= TOLERANCE * peak, f"{name} differs by {float((a - b).abs().max())}"


@pytest.fixture(scope="module")
def pair() -> tuple[Separator, Separator]:
    reference = trained_like(SeparatorConfig.preset("compact"))
    return reference, fuse_for_inference(reference)


def inputs(batch: int, seed: int, channels_last: bool):
    generator = torch.Generator().manual_seed(seed)
    mixture = torch.rand(batch, 32, 32, 32, generator=generator) * 10
    memory = torch.rand(batch, 16, 32, 32, generator=generator)
    if channels_last:
        mixture, memory = (x.contiguous(memory_format=torch.channels_last) for x in (mixture, memory))
    classes = torch.arange(batch) % 2
    return mixture, classes, memory


@pytest.mark.parametrize("batch", [1, 3])
@pytest.mark.parametrize("channels_last", [False, True])
def test_fused_equals_reference_on_random_input(pair, batch: int, channels_last: bool) -> None:
    reference, fused = pair
    mixture, classes, memory = inputs(batch, seed=batch, channels_last=channels_last)
    reset = torch.arange(batch) == 0
    with torch.inference_mode():
        for args in ((mixture, classes), (mixture, classes, memory), (mixture, classes, memory, reset)):
            assert_steps_close(reference(*args), fused(*args))


def test_fused_equals_reference_without_onednn(pair, monkeypatch) -> None:
    reference = pair[0]
    monkeypatch.setattr(torch.backends.mkldnn, "is_available", lambda: False)
    fused = fuse_for_inference(reference)  # a fresh copy: kernels are chosen on first use
    mixture, classes, memory = inputs(2, seed=7, channels_last=False)
    with torch.inference_mode():
        assert_steps_close(reference(mixture, classes, memory), fused(mixture, classes, memory))


def test_fused_small_widths_batch_and_thread_changes() -> None:
    # another width set; batch sizes and thread counts alternate (weights are packed per thread count)
    reference = trained_like(SeparatorConfig(unet_channels=(8, 16, 24, 24, 32), refiner_hidden=8), seed=3)
    fused = fuse_for_inference(reference)
    with torch.inference_mode():
        for batch, threads in ((1, 1), (4, 2), (1, 2), (2, 1)):
            torch.set_num_threads(threads)
            mixture, classes, memory = inputs(batch, seed=10 + batch, channels_last=True)
            assert_steps_close(reference(mixture, classes, memory), fused(mixture, classes, memory))
    torch.set_num_threads(1)


def test_fused_copy_structure_and_original_untouched() -> None:
    reference = trained_like(SeparatorConfig.preset("compact")).train()
    before = {name: tensor.clone() for name, tensor in reference.state_dict().items()}
    fused = fuse_for_inference(reference)
    assert reference.training and not fused.training
    assert any(isinstance(m, nn.BatchNorm2d) for m in reference.modules())
    assert not any(isinstance(m, (nn.BatchNorm2d, nn.Conv2d, nn.ConvTranspose2d)) for m in fused.modules())
    # 10 + 1 per U-Net (the head), 2 in the refiner
    assert sum(isinstance(m, FusedConv) for m in fused.modules()) == 2 * 11 + 2
    assert all(not p.requires_grad for p in fused.parameters())
    after = reference.state_dict()
    assert before.keys() == after.keys() and all(torch.equal(before[k], after[k]) for k in before)


def test_used_fused_copy_can_be_copied_and_pickled(pair) -> None:
    reference, fused = pair
    mixture, classes, memory = inputs(1, seed=4, channels_last=True)
    with torch.inference_mode():
        fused(mixture, classes, memory)  # packs the weights
        again = fuse_for_inference(fused)  # a deep copy of a used copy
        buffer = io.BytesIO()
        torch.save(fused, buffer)
        buffer.seek(0)
        loaded = torch.load(buffer, weights_only=False)
        for model in (again, loaded):
            assert_steps_close(reference(mixture, classes, memory), model(mixture, classes, memory))


def test_batchnorm_that_follows_no_conv_is_refused() -> None:
    separator = Separator(SeparatorConfig.preset("compact"))
    separator.refiner.body = nn.Sequential(nn.BatchNorm2d(32), nn.Conv2d(32, 16, 3, padding=1))
    with pytest.raises(ConfigError, match="BatchNorm2d"):
        fuse_for_inference(separator)


def test_shipped_checkpoint_fast_path_equals_reference_path() -> None:
    """Over an episode's steps (memory carried), separate_clip with the fused copy gives the shipped
    separator's numbers, and both equal a plain module call on contiguous input (the old path)."""
    loaded = load_separator(DEFAULT_SEPARATOR_CHECKPOINT)
    reference, fused = loaded.separator, fuse_for_inference(loaded.separator)
    rng = np.random.default_rng(11)
    t = np.arange(16000) / 16000
    voice = np.sin(2 * np.pi * 220 * t) * (1 + np.sin(2 * np.pi * 3 * t))
    classes = np.array([0, 1])
    memory = {"reference": None, "fused": None, "plain": None}
    for step in range(3):
        binaural = (np.stack([voice, 0.7 * voice])[None] + rng.standard_normal((2, 2, 16000)) * 0.5).astype(np.float32)
        results = {}
        for name, model in (("reference", reference), ("fused", fused)):
            results[name] = separate_clip(model, binaural, classes, memory=memory[name], config=loaded.stft)
            memory[name] = results[name].memory
        with torch.no_grad():
            sliced = torch.from_numpy(np.ascontiguousarray(to_slices(np.abs(stft(binaural)))))
            memory["plain"] = reference(sliced, torch.from_numpy(classes), memory["plain"]).refined
        plain = from_slices(memory["plain"].numpy())[:, 0]
        expected, actual = results["reference"], results["fused"]
        for a, b, what in ((expected.magnitude, actual.magnitude, "magnitude"),
                           (expected.waveform, actual.waveform, "waveform"),
                           (plain, actual.magnitude, "magnitude against the plain call")):
            np.testing.assert_allclose(b, a, atol=TOLERANCE * np.abs(a).max(), err_msg=f"{what}, step {step}")
        assert float((expected.memory - actual.memory).abs().max()) <= TOLERANCE * float(expected.memory.abs().max())


def test_inference_threads_by_batch_size() -> None:
    assert inference_threads(1) == 1
    assert inference_threads(SINGLE_THREAD_MAX_BATCH, cpus=16) == 1
    assert inference_threads(SINGLE_THREAD_MAX_BATCH + 1, cpus=2) == 2
    assert inference_threads(32, cpus=16) == 16
    assert inference_threads(32, cpus=1) == 1
    for bad in (0, -1, 1.5, True):
        with pytest.raises(ConfigError):
            inference_threads(bad)
    with pytest.raises(ConfigError):
        inference_threads(4, cpus=0)
