"""Separator checkpoints: round trip, self-rebuilding, and clear errors for every kind of mismatch."""

import os
import stat
from pathlib import Path

import numpy as np
import pytest
import torch

from m2h_ros.core.audio.stft import DEFAULT_STFT, StftConfig
from m2h_ros.errors import CheckpointError, ConfigError
from m2h_ros.models.checkpoint import (
    DEFAULT_SEPARATOR_BUILD_COMMAND,
    DEFAULT_SEPARATOR_CHECKPOINT,
    load_separator,
    read_checkpoint,
    save_separator,
    write_checkpoint,
)
from m2h_ros.models.separator import SEPARATOR_VERSION, Separator, SeparatorConfig

TINY = SeparatorConfig(unet_channels=(4, 4, 8, 8, 8), refiner_hidden=4)
CLASSES = ("speech", "music")


@pytest.fixture
def saved(tmp_path: Path) -> tuple[Path, Separator]:
    torch.manual_seed(0)
    model = Separator(TINY)
    # give BatchNorm non-default running statistics so they must round-trip too
    model.train()
    with torch.no_grad():
        model(torch.rand(4, 32, 32, 32) * 5, torch.tensor([0, 1, 0, 1]))
    model.eval()
    path = save_separator(tmp_path / "ckpt" / "sep.pt", model, classes=CLASSES,
                          metadata={"steps": 12, "mixture_power": 0.6, "scenes": ["train_000"]})
    return path, model


def test_round_trip_rebuilds_identical_model(saved: tuple[Path, Separator]) -> None:
    path, model = saved
    loaded = load_separator(path, expected_config=TINY, expected_stft=DEFAULT_STFT, expected_classes=CLASSES)
    assert loaded.config == TINY and loaded.stft == DEFAULT_STFT and loaded.classes == CLASSES
    assert loaded.metadata == {"steps": 12, "mixture_power": 0.6, "scenes": ["train_000"]}
    assert not loaded.separator.training
    assert loaded.class_index("music") == 1
    x, c = torch.rand(2, 32, 32, 32) * 5, torch.tensor([1, 0])
    with torch.no_grad():
        for a, b in zip(model(x, c), loaded.separator(x, c), strict=True):
            torch.testing.assert_close(a, b, rtol=0, atol=0)
    with pytest.raises(ConfigError, match="unknown target class 'noise'"):
        loaded.class_index("noise")
    assert not list(path.parent.glob("*.tmp"))  # atomic write leaves no temporary file


def test_missing_and_corrupt_files(tmp_path: Path, saved: tuple[Path, Separator]) -> None:
    with pytest.raises(CheckpointError, match="not found"):
        load_separator(tmp_path / "absent.pt")
    garbage = tmp_path / "garbage.pt"
    garbage.write_bytes(b"not a checkpoint at all")
    with pytest.raises(CheckpointError, match="corrupt"):
        load_separator(garbage)
    truncated = tmp_path / "truncated.pt"
    truncated.write_bytes(saved[0].read_bytes()[:2000])
    with pytest.raises(CheckpointError, match="corrupt"):
        load_separator(truncated)
    plain = tmp_path / "plain.pt"
    torch.save([1, 2, 3], plain)
    with pytest.raises(CheckpointError, match="list"):
        load_separator(plain)


def test_default_checkpoint_missing_names_the_build_command(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    fake_default = tmp_path / "default" / "separator_compact.pt"
    monkeypatch.setattr("m2h_ros.models.checkpoint.DEFAULT_SEPARATOR_CHECKPOINT", fake_default)
    with pytest.raises(CheckpointError, match="pretrain_separator"):
        load_separator(fake_default)
    assert DEFAULT_SEPARATOR_CHECKPOINT.name == "separator_compact.pt"
    assert "pretrain_separator" in DEFAULT_SEPARATOR_BUILD_COMMAND and "train_shipped.sh refiner" in \
        DEFAULT_SEPARATOR_BUILD_COMMAND
    fake_pretrained = tmp_path / "default" / "separator_compact_pretrained.pt"
    monkeypatch.setattr("m2h_ros.models.checkpoint.PRETRAINED_SEPARATOR_CHECKPOINT", fake_pretrained)
    with pytest.raises(CheckpointError, match=r"separator_compact_pretrained.pt not found.*`python -m "
                                              r"m2h_ros.training.pretrain_separator`"):
        load_separator(fake_pretrained)


def test_wrong_kind(tmp_path: Path) -> None:
    path = write_checkpoint(tmp_path / "policy.pt", kind="m2h_policy", model_args={"hidden": 512},
                            state_dict={"w": torch.zeros(2)})
    assert read_checkpoint(path, kind="m2h_policy")["model_args"] == {"hidden": 512}
    with pytest.raises(CheckpointError, match="'m2h_policy' model, expected 'm2h_separator'"):
        load_separator(path)


def test_settings_mismatch_names_the_fields(saved: tuple[Path, Separator]) -> None:
    path, _ = saved
    with pytest.raises(CheckpointError, match=r"stft.hop_length is 512, expected 256"):
        load_separator(path, expected_stft=StftConfig(hop_length=256))
    with pytest.raises(CheckpointError, match=r"model_args.unet_channels is \[4, 4, 8, 8, 8\]"):
        load_separator(path, expected_config=SeparatorConfig())
    with pytest.raises(CheckpointError, match=r"classes are \['speech', 'music'\], expected \['music', 'speech'\]"):
        load_separator(path, expected_classes=("music", "speech"))


def test_shape_mismatch_names_the_tensor(tmp_path: Path, saved: tuple[Path, Separator]) -> None:
    payload = torch.load(saved[0], weights_only=True)
    payload["state_dict"]["refiner.body.0.weight"] = torch.zeros(3, 32, 3, 3)
    del payload["state_dict"]["refiner.body.1.bias"]
    broken = tmp_path / "broken.pt"
    torch.save(payload, broken)
    with pytest.raises(CheckpointError) as info:
        load_separator(broken)
    message = str(info.value)
    assert "missing refiner.body.1.bias" in message
    assert "refiner.body.0.weight has shape (3, 32, 3, 3), model expects (4, 32, 3, 3)" in message


def test_invalid_stored_settings_and_metadata(tmp_path: Path) -> None:
    path = write_checkpoint(tmp_path / "bad.pt", kind="m2h_separator", model_args={"unet_channels": [1, 2]},
                            state_dict={}, stft=DEFAULT_STFT.to_dict(), classes=["speech"],
                            separator_version=SEPARATOR_VERSION)
    with pytest.raises(CheckpointError, match="invalid settings.*unet_channels"):
        load_separator(path)
    with pytest.raises(ConfigError, match="metadata.when"):
        save_separator(tmp_path / "x.pt", Separator(TINY), classes=CLASSES, metadata={"when": object()})
    with pytest.raises(ConfigError, match="classes"):
        save_separator(tmp_path / "x.pt", Separator(TINY), classes=["speech", "speech"])


def test_old_separator_version_is_refused(tmp_path: Path, saved: tuple[Path, Separator]) -> None:
    payload = torch.load(saved[0], weights_only=True)
    del payload["separator_version"]  # files written before the entry existed are version 1
    old = tmp_path / "old.pt"
    torch.save(payload, old)
    with pytest.raises(CheckpointError, match=f"version-1 separator .* needs version {SEPARATOR_VERSION}; retrain"):
        load_separator(old)


def test_written_files_are_world_readable(tmp_path: Path) -> None:
    previous = os.umask(0o022)
    try:
        path = write_checkpoint(tmp_path / "a.pt", kind="k", model_args={}, state_dict={})
        assert stat.S_IMODE(path.stat().st_mode) == 0o644
        os.umask(0o077)
        path = write_checkpoint(tmp_path / "b.pt", kind="k", model_args={}, state_dict={})
        assert stat.S_IMODE(path.stat().st_mode) == 0o600
    finally:
        os.umask(previous)


@pytest.mark.parametrize("value,type_name", [(np.float64(0.5), "float64"), (np.int64(3), "int64"),
                                             (torch.__version__, "TorchVersion"), ({1: "a"}.keys(), "dict_keys")])
def test_metadata_must_be_exactly_plain(tmp_path: Path, value: object, type_name: str) -> None:
    # numpy scalars and torch's version string subclass float/str but fail weights_only loading
    with pytest.raises(ConfigError, match=f"metadata.x holds a {type_name}"):
        write_checkpoint(tmp_path / "m.pt", kind="k", model_args={}, state_dict={}, metadata={"x": value})
    path = write_checkpoint(tmp_path / "m.pt", kind="k", model_args={}, state_dict={},
                            metadata={"x": [str(torch.__version__), float(np.float64(0.5)), (1, None, True)]})
    assert read_checkpoint(path, kind="k")["metadata"] == {"x": [str(torch.__version__), 0.5, (1, None, True)]}
