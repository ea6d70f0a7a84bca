"""The policy network: the paper's layers, the original's initialisation, sequence evaluation equal
to stepping, inputs as a controller sees them, and self-describing checkpoints."""

import numpy as np
import pytest
import torch

from m2h_ros.errors import CheckpointError, ConfigError
from m2h_ros.models.checkpoint import save_separator
from m2h_ros.core.audio.stft import to_slices
from m2h_ros.models.policy import (PolicyConfig, PolicyInputs, PolicyNet, area_downsample, load_policy,
                                   policy_input_buffers, policy_inputs, save_policy, sliced_policy_inputs, warm_start)
from m2h_ros.models.separator import Separator, SeparatorConfig

SMALL = PolicyConfig(hidden=16, channels=(4, 8, 4), image_size=40)


def random_inputs(config: PolicyConfig, n: int, seed: int = 0) -> PolicyInputs:
    g = torch.Generator().manual_seed(seed)
    audio_channels = 32 if config.inputs == "separation" else 33
    return PolicyInputs(
        torch.randint(0, 256, (n, 3, config.image_size, config.image_size), dtype=torch.uint8, generator=g)
        if config.camera else None,
        torch.rand(n, audio_channels, 32, 32, generator=g) * 3,
        torch.rand(n, 32, 32, 32, generator=g) * 3 if config.inputs == "separation" else None)


def convs(encoder) -> list[torch.nn.Conv2d]:
    return [m for m in encoder.modules() if isinstance(m, torch.nn.Conv2d)]


def test_paper_preset_has_the_seed_layers():
    net = PolicyNet(PolicyConfig.preset("paper", stop=True))
    visual, binaural = convs(net.visual_encoder), convs(net.audio_encoder)
    assert [c.kernel_size[0] for c in visual] == [8, 4, 3] and [c.stride[0] for c in visual] == [4, 2, 1]
    assert [c.out_channels for c in visual] == [32, 64, 32] and visual[0].in_channels == 3  # RGB only
    assert [c.kernel_size[0] for c in binaural] == [8, 4, 2] and binaural[0].in_channels == 32
    assert convs(net.monaural_encoder)[0].in_channels == 32  # [f^M estimate, f^R memory] x 16 slices
    assert net.visual_encoder.cnn[-2].out_features == 512
    assert (net.gru.input_size, net.gru.hidden_size, net.gru.num_layers, net.gru.bidirectional) == (3 * 512, 512, 1,
                                                                                                      False)
    assert net.actor.out_features == 4 and net.critic.out_features == 1
    assert PolicyNet(PolicyConfig.preset("paper")).actor.out_features == 3  # no Stop: the three moves
    mixture = PolicyNet(PolicyConfig.preset("compact", inputs="mixture", stop=True))
    assert mixture.monaural_encoder is None and convs(mixture.audio_encoder)[0].in_channels == 33
    assert mixture.gru.input_size == 2 * 128


def test_initialisation_follows_the_original():
    torch.manual_seed(0)
    net = PolicyNet(PolicyConfig.preset("paper"))
    weight = convs(net.audio_encoder)[0].weight
    assert weight.std().item() == pytest.approx(np.sqrt(2.0 / weight[0].numel()), rel=0.05)  # Kaiming normal
    assert all(torch.all(b == 0) for n, b in net.named_parameters() if n.endswith("bias"))
    hh = net.gru.weight_hh_l0
    torch.testing.assert_close(hh.T @ hh, torch.eye(512), atol=1e-4, rtol=0)  # orthogonal
    with torch.no_grad():
        out = net.step(random_inputs(net.config, 8), net.initial_hidden(8), torch.ones(8, dtype=torch.bool))
    probs = torch.softmax(out.logits, -1)
    assert (probs - 1 / 3).abs().max() < 0.02  # the actor's gain 0.01: near-uniform at the start


def test_sequence_evaluation_equals_stepping_with_resets():
    torch.manual_seed(1)
    net = PolicyNet(SMALL).eval()
    t, n = 5, 3
    inputs = random_inputs(SMALL, t * n, seed=2)
    starts = torch.zeros(t, n, dtype=torch.bool)
    starts[0] = True
    starts[3, 1] = True  # slot 1 starts a new episode at step 3
    hidden0 = torch.randn(n, SMALL.hidden)
    with torch.no_grad():
        whole = net.evaluate(inputs, hidden0, starts)
        hidden, logits = hidden0, []
        for step in range(t):
            out = net.step(inputs.index(slice(step * n, (step + 1) * n)), hidden, starts[step])
            hidden = out.hidden
            logits.append(out.logits)
        fresh = net.step(inputs.index(slice(3 * n + 1, 3 * n + 2)), torch.zeros(1, SMALL.hidden),
                         torch.zeros(1, dtype=torch.bool))
    torch.testing.assert_close(whole.logits, torch.stack(logits))
    torch.testing.assert_close(whole.hidden, hidden)
    torch.testing.assert_close(whole.logits[3, 1], fresh.logits[0])  # the reset really cleared the state


def test_inputs_are_log_magnitudes_in_the_sliced_layout_and_the_class_plane():
    rng = np.random.default_rng(0)
    binaural = rng.random((2, 2, 512, 32), dtype=np.float32) * 5
    mono, refined = (rng.random((2, 512, 32), dtype=np.float32) for _ in range(2))
    audio = rng.standard_normal((2, 2, 16000)).astype(np.float32)
    rgb = rng.integers(0, 256, (2, 80, 80, 3), dtype=np.uint8)
    args = dict(separated_binaural=binaural, monaural=mono, refined=refined, audio=audio, target_class=np.array([0, 1]),
                rgb=rgb)
    inputs = policy_inputs(SMALL, **args)
    np.testing.assert_allclose(inputs.audio[0, 16 + 3].numpy(), np.log1p(binaural[0, 1, 96:128]), rtol=1e-6)
    np.testing.assert_allclose(inputs.monaural[1, 16].numpy(), np.log1p(refined[1, :32]), rtol=1e-6)
    assert inputs.rgb.shape == (2, 3, 40, 40) and inputs.rgb.dtype == torch.uint8
    mixture = policy_inputs(PolicyConfig(inputs="mixture", camera=False), **args)
    assert mixture.rgb is None and mixture.monaural is None and mixture.audio.shape == (2, 33, 32, 32)
    assert torch.all(mixture.audio[1, 32] == 2.0) and torch.all(mixture.audio[0, 32] == 1.0)  # class index + 1
    with pytest.raises(ConfigError, match="RGB"):
        policy_inputs(SMALL, **{**args, "rgb": None})


def test_area_downsample_averages_blocks():
    rgb = np.zeros((1, 4, 4, 3), np.uint8)
    rgb[0, :2, :2] = 100
    rgb[0, 0, 0] = 200
    out = area_downsample(rgb, 2)
    assert out.shape == (1, 3, 2, 2) and out[0, 0, 0, 0] == 125 and out[0, 2, 1, 1] == 0 and out.dtype == torch.uint8
    rng = np.random.default_rng(0)
    for shape, size in (((3, 128, 128, 3), 64), ((2, 96, 96, 3), 32), ((2, 64, 128, 3), 32)):
        rgb = rng.integers(0, 256, shape, np.uint8)
        image = torch.from_numpy(rgb).permute(0, 3, 1, 2).float()
        expected = torch.round(torch.nn.functional.avg_pool2d(image, (shape[1] // size, shape[2] // size)))
        out = area_downsample(rgb, size)
        assert torch.equal(out, expected.to(torch.uint8)), shape  # bit for bit, incl. 3 x 3 blocks, ties
        assert out.is_contiguous(memory_format=torch.channels_last)
    with pytest.raises(ConfigError, match="multiple"):
        area_downsample(np.zeros((1, 5, 5, 3), np.uint8), 2)
    with pytest.raises(ConfigError, match="too small"):
        PolicyConfig(image_size=32)


def test_checkpoint_round_trip_and_errors(tmp_path):
    torch.manual_seed(3)
    net = PolicyNet(SMALL).eval()
    path = save_policy(tmp_path / "p.pt", net, policy_kind="quality", metadata={"updates": 7})
    loaded = load_policy(path, policy_kind="quality")
    assert loaded.config == SMALL and loaded.metadata == {"updates": 7} and loaded.policy_kind == "quality"
    inputs = random_inputs(SMALL, 2)
    with torch.no_grad():
        a = net.step(inputs, net.initial_hidden(2), torch.ones(2, dtype=torch.bool)).logits
        b = loaded.net.step(inputs, net.initial_hidden(2), torch.ones(2, dtype=torch.bool)).logits
    torch.testing.assert_close(a, b)
    with pytest.raises(CheckpointError, match="'quality' policy, expected 'navigation'"):
        load_policy(path, policy_kind="navigation")
    separator = save_separator(tmp_path / "s.pt", Separator(SeparatorConfig(unet_channels=(4, 4, 4, 4, 4),
                                                                             refiner_hidden=4)), classes=("speech",))
    with pytest.raises(CheckpointError, match="m2h_separator"):
        load_policy(separator)
    with pytest.raises(CheckpointError, match="not found"):
        load_policy(tmp_path / "none.pt")


def test_warm_start_copies_everything_and_matches_actor_rows_by_action(tmp_path):
    torch.manual_seed(4)
    navigation = PolicyNet(PolicyConfig(**{**SMALL.to_dict(), "stop": True})).eval()
    with torch.no_grad():
        navigation.actor.weight.normal_()  # rows distinguishable (the orthogonal init's gain is 0.01)
        navigation.actor.bias.normal_()
    source = load_policy(save_policy(tmp_path / "n.pt", navigation, policy_kind="navigation"))
    quality = PolicyNet(SMALL)
    warm_start(quality, source)
    inputs, starts = random_inputs(SMALL, 3), torch.ones(3, dtype=torch.bool)
    with torch.no_grad():
        ours = quality.eval().step(inputs, quality.initial_hidden(3), starts)
        theirs = navigation.step(inputs, navigation.initial_hidden(3), starts)
    # pi^N's outputs are STOP, FORWARD, LEFT, RIGHT; pi^Q's FORWARD, LEFT, RIGHT
    torch.testing.assert_close(ours.logits, theirs.logits[:, 1:])
    torch.testing.assert_close(ours.value, theirs.value)
    # the other way round the STOP row keeps its own initialisation
    back = PolicyNet(navigation.config)
    own_stop = back.actor.weight[0].detach().clone()
    warm_start(back, load_policy(save_policy(tmp_path / "q.pt", quality, policy_kind="quality")))
    torch.testing.assert_close(back.actor.weight[0], own_stop)
    torch.testing.assert_close(back.actor.weight[1:], quality.actor.weight)
    with pytest.raises(ConfigError, match="hidden differ"):
        warm_start(PolicyNet(PolicyConfig(**{**SMALL.to_dict(), "hidden": 8})), source)


@pytest.mark.parametrize("kind", ["quality", "navigation", "approach", "novelty", "av_navigator"])
def test_shipped_policies_act_as_with_nchw_convolutions(kind):
    """The encoders compute in channels_last (the speed path); a checkpoint trained before gives the
    numbers of the NCHW path it was trained with, to float tolerance, in a step and over a sequence."""
    from pathlib import Path  # noqa: PLC0415

    import m2h_ros.models.policy as policy_module  # noqa: PLC0415

    net = load_policy(Path(policy_module.__file__).parent / "default" / f"policy_{kind}.pt", policy_kind=kind).net
    t, n = 6, 4
    inputs = random_inputs(net.config, t * n, seed=5)
    starts = torch.zeros(t, n, dtype=torch.bool)
    starts[0], starts[2, 1] = True, True
    hidden0 = torch.randn(n, net.config.hidden, generator=torch.Generator().manual_seed(1))
    assert not inputs.audio.is_contiguous(memory_format=torch.channels_last)  # the encoder converts it
    with torch.no_grad():
        fast_step = net.step(inputs.index(slice(0, n)), hidden0, starts[0])
        fast = net.evaluate(inputs, hidden0, starts)
        cl = PolicyInputs(*(None if x is None else x.contiguous(memory_format=torch.channels_last) for x in inputs))
        already = net.evaluate(cl, hidden0, starts)
        original = policy_module.ConvEncoder.forward
        try:
            policy_module.ConvEncoder.forward = lambda self, x: self.cnn(x.contiguous())  # the NCHW path
            slow_step = net.step(inputs.index(slice(0, n)), hidden0, starts[0])
            slow = net.evaluate(inputs, hidden0, starts)
        finally:
            policy_module.ConvEncoder.forward = original
    for a, b in ((fast_step, slow_step), (fast, slow), (already, slow)):
        # Rounding grows with the terms summed, not with one output: a small logit beside large ones (stage 12 of
        # pi^N: 0.07 beside 4.3) is as far apart as the large ones, so the tolerance scales with the largest.
        for mine, theirs in ((a.logits, b.logits), (a.value, b.value)):
            torch.testing.assert_close(mine, theirs, rtol=1e-4, atol=1e-5 * max(1.0, float(theirs.abs().max())))
        # The GRU state carries six steps of rounding: one of the approach policy's 512 values is 1.6e-5 apart.
        torch.testing.assert_close(a.hidden, b.hidden, rtol=1e-4, atol=5e-5)
    assert torch.equal(already.logits, fast.logits)


def test_policy_inputs_are_channels_last_and_the_same_from_every_path():
    """What the rollout stores is already in the encoders' layout (no copy): written into the rollout's
    buffers, whose flat view the update takes as is; the separator's sliced tensors (channels_last, as
    SeparatorRunner gives them) make the numbers the controllers' (F, T) arrays make, bit for bit."""
    config = PolicyConfig.preset("compact")
    rng = np.random.default_rng(0)
    # Magnitudes over many decades, some below 0 (clamped): log1p's every branch.
    binaural, mono, refined = ((np.exp(rng.uniform(-23, 9, shape)) * rng.choice([1, 1, 1, -1], shape)).astype(np.float32)
                               for shape in ((3, 2, 512, 32), (3, 512, 32), (3, 512, 32)))
    rgb = rng.integers(0, 256, (3, 128, 128, 3), np.uint8)
    arrays = dict(separated_binaural=binaural, monaural=mono, refined=refined, audio=None,
                  target_class=np.zeros(3, np.int64), rgb=rgb)
    inputs = policy_inputs(config, **arrays)
    for x in inputs:
        assert x.is_contiguous(memory_format=torch.channels_last)
    np.testing.assert_allclose(inputs.monaural[2, 16 + 5].numpy(), np.log1p(np.maximum(refined[2, 160:192], 0)),
                               rtol=1e-6)  # f^R's band 5

    def sliced(x):
        return torch.from_numpy(to_slices(x, n_slices=16)).contiguous(memory_format=torch.channels_last)

    buffers = policy_input_buffers(config, steps=2, slots=3)
    for t in range(2):
        got = sliced_policy_inputs(config, binaural=sliced(binaural), monaural=sliced(mono[:, None]),
                                   refined=sliced(refined[:, None]), rgb=rgb, out=buffers.index(t))
        assert all(g.data_ptr() == b[t].data_ptr() for g, b in zip(got, buffers, strict=True))  # written in place
    into = policy_inputs(config, **arrays, out=policy_input_buffers(config, steps=1, slots=3).index(0))
    for expected, buffer, written in zip(inputs, buffers, into, strict=True):
        assert torch.equal(expected, buffer[0]) and torch.equal(expected, buffer[1]) and torch.equal(expected, written)
    flat = buffers.flat()
    assert all(x.is_contiguous(memory_format=torch.channels_last) and x.shape[0] == 6 for x in flat)
    assert all(f.data_ptr() == b.data_ptr() for f, b in zip(flat, buffers, strict=True))  # a view

    mixture = PolicyConfig(inputs="mixture", camera=False)
    audio = rng.standard_normal((3, 2, 16000)).astype(np.float32)
    args = {**arrays, "audio": audio, "target_class": np.array([0, 2, 1])}
    written = policy_inputs(mixture, **args, out=policy_input_buffers(mixture, steps=1, slots=3).index(0))
    fresh = policy_inputs(mixture, **args)
    assert torch.equal(written.audio, fresh.audio) and fresh.audio.is_contiguous(memory_format=torch.channels_last)
    with pytest.raises(ConfigError, match="separation policies"):
        sliced_policy_inputs(mixture, binaural=sliced(binaural), monaural=sliced(mono[:, None]),
                             refined=sliced(refined[:, None]), rgb=None)
