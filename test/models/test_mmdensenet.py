"""The MMDenseNet-style backbone of f^B / f^M: shapes, band isolation, selection by SeparatorConfig,
checkpoint round trip (and old checkpoints loading as U-Nets), the fused inference copy."""

from pathlib import Path

import pytest
import torch

from m2h_ros.errors import CheckpointError, ConfigError
from m2h_ros.models.checkpoint import load_separator, save_separator
from m2h_ros.models.inference import fuse_for_inference
from m2h_ros.models.mmdensenet import MMDenseNet, band_slices
from m2h_ros.models.separator import Separator, SeparatorConfig
from m2h_ros.models.unet import UNet

TINY = SeparatorConfig(backbone="mmdensenet", dense_growth=2, refiner_hidden=4)
CLASSES = ("speech", "music")


def with_running_stats(model: Separator) -> Separator:
    """A few training-mode passes so BatchNorm statistics are not the identity."""
    model.train()
    with torch.no_grad():
        for _ in range(2):
            model(torch.rand(4, 32, 32, 32) * 5, torch.tensor([0, 1, 0, 1]))
    return model.eval()


def test_bands_cover_the_slices() -> None:
    assert band_slices(16) == [(0, 4), (4, 8), (8, 16)]
    with pytest.raises(ConfigError, match="one slice per band"):
        band_slices(2)


def test_mmdensenet_shapes_and_band_isolation() -> None:
    torch.manual_seed(0)
    net = MMDenseNet(32, groups=2, n_slices=16, extra=1, growth=2).eval()
    x = torch.rand(2, 33, 32, 32)
    assert net(x).shape == (2, 32, 32, 32)
    # The low band's net sees slices 0-3 of each ear and the class plane, nothing else.
    changed = x.clone()
    changed[:, 8:16] += 1.0  # ear 0, slices 8-15 (high band)
    changed[:, 20:32] += 1.0  # ear 1, slices 4-15 (mid and high)
    with torch.no_grad():
        low, full = net.band_nets[0], net.full_net
        assert torch.equal(low(net._band_input(x, 0, 4)), low(net._band_input(changed, 0, 4)))
        assert not torch.equal(full(x), full(changed))
        assert not torch.equal(net(x), net(changed))
        shifted = x.clone()
        shifted[:, 2] += 1.0  # ear 0, slice 2: the low band does see it
        assert not torch.equal(low(net._band_input(x, 0, 4)), low(net._band_input(shifted, 0, 4)))


def test_config_selects_the_backbone() -> None:
    assert SeparatorConfig().backbone == "unet"
    unet = Separator(SeparatorConfig(unet_channels=(4, 4, 4, 4, 4), refiner_hidden=4))
    dense = Separator(TINY)
    assert isinstance(unet.binaural_separator, UNet) and isinstance(unet.monaural_predictor, UNet)
    assert isinstance(dense.binaural_separator, MMDenseNet) and isinstance(dense.monaural_predictor, MMDenseNet)
    x, classes = torch.rand(2, 32, 32, 32) * 5, torch.tensor([0, 1])
    with torch.no_grad():
        for a, b in zip(unet.eval()(x, classes), dense.eval()(x, classes), strict=True):
            assert a.shape == b.shape
        mask = dense(x, classes).mask
    assert float(mask.min()) >= 0.0 and float(mask.max()) <= 1.0
    assert SeparatorConfig.from_dict(TINY.to_dict()) == TINY
    assert TINY.summary == "mmdensenet growth 2"
    with pytest.raises(ConfigError, match="backbone must be one of"):
        SeparatorConfig(backbone="transformer")
    with pytest.raises(ConfigError, match="dense_growth"):
        SeparatorConfig(backbone="mmdensenet", dense_growth=0)
    with pytest.raises(ConfigError, match="one slice per band"):
        SeparatorConfig(backbone="mmdensenet", n_freq_slices=2)


def test_checkpoint_round_trip_needs_no_flags(tmp_path: Path) -> None:
    torch.manual_seed(1)
    model = with_running_stats(Separator(TINY))
    path = save_separator(tmp_path / "dense.pt", model, classes=CLASSES)
    loaded = load_separator(path)
    assert loaded.config == TINY and isinstance(loaded.separator.binaural_separator, MMDenseNet)
    x, classes = torch.rand(2, 32, 32, 32) * 5, torch.tensor([1, 0])
    with torch.no_grad():
        for a, b in zip(model(x, classes), loaded.separator(x, classes), strict=True):
            torch.testing.assert_close(a, b, rtol=0, atol=0)
    with pytest.raises(CheckpointError, match="model_args.backbone is 'mmdensenet', expected 'unet'"):
        load_separator(path, expected_config=SeparatorConfig())


def test_checkpoint_without_the_field_loads_as_unet(tmp_path: Path) -> None:
    config = SeparatorConfig(unet_channels=(4, 4, 8, 8, 8), refiner_hidden=4)
    path = save_separator(tmp_path / "old.pt", Separator(config).eval(), classes=CLASSES)
    payload = torch.load(path, weights_only=True)
    for name in ("backbone", "dense_growth"):  # as written before the fields existed
        del payload["model_args"][name]
    torch.save(payload, path)
    loaded = load_separator(path)
    assert loaded.config == config and isinstance(loaded.separator.monaural_predictor, UNet)
    payload["model_args"]["backbone"] = "resnet"
    torch.save(payload, path)
    with pytest.raises(CheckpointError, match="invalid settings.*backbone"):
        load_separator(path)


def test_fused_copy_matches() -> None:
    torch.manual_seed(2)
    model = with_running_stats(Separator(TINY))
    fused = fuse_for_inference(model)
    x, classes, memory = torch.rand(3, 32, 32, 32) * 5, torch.tensor([0, 1, 0]), torch.rand(3, 16, 32, 32)
    with torch.inference_mode():
        for a, b in zip(model(x, classes, memory), fused(x, classes, memory), strict=True):
            torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-4 * float(a.abs().max()))
    assert not any(isinstance(m, torch.nn.BatchNorm2d) for m in fused.modules())
