"""m2h-separate, run in-process on tiny files with a randomly initialised compact checkpoint."""

from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
import torch

from m2h_ros import separate_cli
from m2h_ros.models.checkpoint import load_separator, save_separator
from m2h_ros.models.separator import Separator, SeparatorConfig, separate_clip

CLASSES = ("speech", "music")


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory: pytest.TempPathFactory) -> Path:
    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("ckpt") / "separator_compact.pt"
    separator = Separator(SeparatorConfig.preset("compact"))
    torch.nn.init.normal_(separator.refiner.body[-1].weight, std=0.05)  # else f^R is the identity
    return save_separator(path, separator, classes=CLASSES,
                          metadata={"mixture_power": 0.5})


def stereo(seconds: float, rate: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * rate)) / rate
    tone = 0.2 * np.sin(2 * np.pi * 330.0 * t)
    return np.stack([tone + 0.05 * rng.standard_normal(t.size), 0.7 * tone + 0.05 * rng.standard_normal(t.size)],
                    axis=1).astype(np.float32)


def run(*args: object) -> int:
    return separate_cli.main([str(a) for a in args])


def test_separates_any_rate_and_length(tmp_path: Path, checkpoint: Path) -> None:
    source = tmp_path / "in.flac"
    sf.write(source, stereo(2.3, 22050), 22050)
    out = tmp_path / "out.wav"
    assert run(source, out, "--target", "speech", "--checkpoint", checkpoint) == 0
    audio, rate = sf.read(out, always_2d=True)
    info = sf.info(out)
    # the default output, the listener's, keeps both ears
    assert rate == 22050 and audio.shape == (int(2.3 * 22050), 2) and info.subtype == "FLOAT"
    assert np.all(np.isfinite(audio)) and np.sqrt(np.mean(audio**2)) > 1e-4
    assert run(source, tmp_path / "mono.wav", "--target", "speech", "--checkpoint", checkpoint, "--mono") == 0
    mono, _ = sf.read(tmp_path / "mono.wav", always_2d=True)
    np.testing.assert_allclose(mono[:, 0], audio.mean(axis=1), atol=1e-4 * np.abs(audio).max())
    flac_out = tmp_path / "out.flac"
    assert run(source, flac_out, "--target", "music", "--checkpoint", checkpoint, "--output", "refined") == 0
    assert sf.info(flac_out).frames == int(2.3 * 22050) and sf.info(flac_out).channels == 1
    assert run(source, out, "--target", "music", "--checkpoint", checkpoint, "--output", "masked_mixture") == 0
    assert sf.info(out).channels == 2


def test_frames_carry_the_refiner_memory(checkpoint: Path) -> None:
    loaded = load_separator(checkpoint)
    audio = stereo(2.0, 16000, seed=1)
    separated = separate_cli.separate_recording(loaded, audio, 16000, "music", output="refined")
    gain = np.sqrt(0.5 / np.mean(np.square(audio, dtype=np.float64)))
    frames = (audio * gain).reshape(2, 16000, 2).transpose(0, 2, 1)
    first = separate_clip(loaded.separator, frames[:1], 1)
    second = separate_clip(loaded.separator, frames[1:], 1, memory=first.memory)
    expected = np.concatenate([first.waveform[0], second.waveform[0]]) / gain
    np.testing.assert_allclose(separated, expected, atol=1e-5 * np.abs(expected).max())
    # without the memory the second second would come out differently
    fresh = separate_clip(loaded.separator, frames[1:], 1).waveform[0] / gain
    assert not np.allclose(separated[16000:], fresh, atol=1e-3 * np.abs(fresh).max())
    # the input is normalised to the trained mixture power, so the output follows the input's scale
    np.testing.assert_allclose(separate_cli.separate_recording(loaded, 10 * audio, 16000, "music", output="refined"),
                               10 * separated,
                               rtol=1e-3, atol=1e-4 * np.abs(separated).max())


@pytest.mark.parametrize("case,message", [
    ("mono", "1 channel(s); m2h-separate needs a stereo"),
    ("silent", "silent"),
    ("nan", "NaN"),
    ("class", "unknown target class 'noise'"),
])
def test_bad_input_exits_2_with_one_line(tmp_path: Path, checkpoint: Path, capsys: pytest.CaptureFixture,
                                         case: str, message: str) -> None:
    source = tmp_path / "in.wav"
    audio = {"mono": stereo(1.0, 16000)[:, 0], "silent": np.zeros((16000, 2), np.float32),
             "nan": np.full((16000, 2), np.nan, np.float32), "class": stereo(1.0, 16000)}[case]
    sf.write(source, audio, 16000, subtype="FLOAT")
    target = "noise" if case == "class" else "speech"
    assert run(source, tmp_path / "out.wav", "--target", target, "--checkpoint", checkpoint) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1 and err.startswith("m2h-separate: error:")
    assert not (tmp_path / "out.wav").exists()


def test_missing_checkpoints_and_files(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                       capsys: pytest.CaptureFixture, checkpoint: Path) -> None:
    source = tmp_path / "in.wav"
    sf.write(source, stereo(0.5, 16000), 16000)
    fake_default = tmp_path / "models" / "default" / "separator_compact.pt"
    monkeypatch.setattr(separate_cli, "DEFAULT_SEPARATOR_CHECKPOINT", fake_default)
    monkeypatch.setattr("m2h_ros.models.checkpoint.DEFAULT_SEPARATOR_CHECKPOINT", fake_default)
    assert run(source, tmp_path / "out.wav", "--target", "speech") == 2
    assert "python -m m2h_ros.training.pretrain_separator" in capsys.readouterr().err
    assert run(tmp_path / "absent.wav", tmp_path / "out.wav", "--target", "speech", "--checkpoint", checkpoint) == 2
    assert "cannot read" in capsys.readouterr().err
    assert run(source, tmp_path / "out.xyz", "--target", "speech", "--checkpoint", checkpoint) == 2
    assert "unknown audio format" in capsys.readouterr().err
    with pytest.raises(SystemExit) as info:
        run(source)  # argparse usage errors also exit with 2
    assert info.value.code == 2


def test_device_option(tmp_path: Path, checkpoint: Path, capsys: pytest.CaptureFixture) -> None:
    source = tmp_path / "in.wav"
    sf.write(source, stereo(1.5, 16000), 16000, subtype="FLOAT")
    assert run(source, tmp_path / "default.wav", "--target", "speech", "--checkpoint", checkpoint) == 0
    assert run(source, tmp_path / "cpu.wav", "--target", "speech", "--checkpoint", checkpoint, "--device", "cpu") == 0
    default, cpu = sf.read(tmp_path / "default.wav")[0], sf.read(tmp_path / "cpu.wav")[0]
    np.testing.assert_array_equal(cpu, default)
    code = run(source, tmp_path / "cuda.wav", "--target", "speech", "--checkpoint", checkpoint, "--device", "cuda")
    if torch.cuda.is_available():
        assert code == 0
        np.testing.assert_allclose(sf.read(tmp_path / "cuda.wav")[0], cpu, atol=1e-4 * np.abs(cpu).max())
    else:
        assert code == 2 and "--device='cuda' but no CUDA device is available" in capsys.readouterr().err
