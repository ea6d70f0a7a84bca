"""``m2h-separate``: extract one target class from a stereo (binaural) recording with a trained separator.

The file is resampled to the separator's rate (16 kHz), scaled to the mixture power the separator was
trained on, and cut into 1 s frames (the last one zero-padded). Each frame gives what ``separator_node``
publishes on ``separator/audio`` (``--output``, as its ``audio_output``): by default the listener output,
the target's early image at both ears (a stereo file; ``--mono`` writes their mean); ``masked_mixture``,
f^B's mask on each ear; or ``refined``, f^B -> f^M -> f^R with the refiner's memory carried from frame
to frame, rebuilt with the mixture's phase (mono; the ground-truth phase the paper reports is not
available for a real recording). The frames are concatenated without overlap (the centred STFT rebuilds
each 1 s frame completely), scaled back, resampled to the input rate and written. Errors in the input
end the program with exit code 2 and a one-line message.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import scipy.signal
import soundfile as sf
import torch
from tqdm import tqdm

from m2h_ros.core.audio.stft import AUDIO_OUTPUTS
from m2h_ros.errors import AudioError, ConfigError, M2HError
from m2h_ros.models.checkpoint import DEFAULT_SEPARATOR_CHECKPOINT, LoadedSeparator, load_separator
from m2h_ros.models.device import DEVICES, resolve_device
from m2h_ros.models.listener import DEFAULT_LISTENER_CHECKPOINT, LoadedListener, load_listener
from m2h_ros.models.runner import SeparatorRunner
from m2h_ros.models.threads import inference_threads
from m2h_ros.paths import PACKAGE_DIR

# Checkpoint metadata entry giving the mean power of the training mixtures; inputs are scaled to it.
MIXTURE_POWER_KEY = "mixture_power"
# Used when a checkpoint does not record it: the clip normalisation power of the sound library.
FALLBACK_MIXTURE_POWER = 1.2
SILENT_POWER = 1e-10  # mean power below this (about -100 dBFS) counts as a silent file
PROGRESS_MIN_FRAMES = 30  # show a progress bar for files of at least this many seconds


def _resample(audio: np.ndarray, source_rate: int, target_rate: int) -> np.ndarray:
    if source_rate == target_rate:
        return audio
    divisor = math.gcd(source_rate, target_rate)
    return scipy.signal.resample_poly(audio, target_rate // divisor, source_rate // divisor, axis=0).astype(np.float32)


def check_stereo(audio: np.ndarray) -> None:
    """Raise AudioError unless ``audio`` is a usable (N, 2) recording: stereo, finite, not silent."""
    if audio.ndim != 2 or audio.shape[1] != 2:
        channels = 1 if audio.ndim == 1 else audio.shape[1]
        raise AudioError(f"input has {channels} channel(s); m2h-separate needs a stereo (binaural) recording")
    if audio.shape[0] == 0:
        raise AudioError("input holds no samples")
    if not np.all(np.isfinite(audio)):
        raise AudioError("input holds NaN or infinite samples")
    if float(np.mean(np.square(audio, dtype=np.float64))) < SILENT_POWER:
        raise AudioError("input is silent (mean power below -100 dBFS)")


def separate_recording(loaded: LoadedSeparator, audio: np.ndarray, sample_rate: int, target: str, *,
                       output: str = "refined", listener: LoadedListener | None = None,
                       binaural: bool = False) -> np.ndarray:
    """Stereo recording (N, 2) at ``sample_rate`` -> the ``output`` (an ``AUDIO_OUTPUTS`` name; ``listener``
    needs ``listener``) at the same rate: (N, 2) where it has two ears and ``binaural``, else (N,)."""
    class_index = loaded.class_index(target)
    check_stereo(audio)
    if output not in AUDIO_OUTPUTS:
        raise ConfigError(f"output {output!r}: one of {', '.join(AUDIO_OUTPUTS)}")
    config = loaded.stft
    mixture = _resample(np.asarray(audio, dtype=np.float32), sample_rate, config.sample_rate)
    target_power = float(loaded.metadata.get(MIXTURE_POWER_KEY, FALLBACK_MIXTURE_POWER))
    gain = math.sqrt(target_power / float(np.mean(np.square(mixture, dtype=np.float64))))
    frame = config.clip_samples
    n_frames = -(-mixture.shape[0] // frame)
    padded = np.zeros((n_frames * frame, 2), dtype=np.float32)
    padded[: mixture.shape[0]] = mixture * gain
    frames = padded.reshape(n_frames, frame, 2).transpose(0, 2, 1)  # (frames, 2, samples)
    # The node's runner: the same fused networks, memory and outputs as separator/audio
    runner = SeparatorRunner(loaded, 1, listener=listener if output == "listener" else None)
    classes = np.array([class_index])
    pieces = []
    for k, clip in enumerate(tqdm(frames, desc="separating", unit="s", disable=n_frames < PROGRESS_MIN_FRAMES,
                                  leave=False)):
        if output == "listener":
            piece = runner.listen(clip[None], classes, binaural=binaural)[0]
        else:
            step = runner.step(clip[None], classes, np.array([k == 0]))
            piece = step.waveform(clip[None], config=config, output=output, binaural=binaural)[0]
        pieces.append(piece.reshape(-1, frame))
    separated = np.concatenate(pieces, axis=-1).T[: mixture.shape[0]] / gain  # (samples, channels)
    separated = _resample(separated, config.sample_rate, sample_rate)
    out = np.zeros((audio.shape[0], separated.shape[1]), dtype=np.float32)
    n = min(out.shape[0], separated.shape[0])
    out[:n] = separated[:n]
    return out if out.shape[1] == 2 else out[:, 0]


def _write(path: Path, audio: np.ndarray, sample_rate: int) -> None:
    fmt = path.suffix.lstrip(".").upper()
    if fmt not in sf.available_formats():
        raise AudioError(f"cannot write {path}: unknown audio format {path.suffix!r}")
    if sf.check_format(fmt, "FLOAT"):
        sf.write(path, audio, sample_rate, subtype="FLOAT")
    else:  # integer formats (e.g. FLAC) would wrap around outside [-1, 1]
        sf.write(path, np.clip(audio, -1.0, 1.0), sample_rate)


def _shipped(path: Path) -> str:
    """A shipped file as the package names it, the same wherever the package is installed."""
    return path.relative_to(PACKAGE_DIR.parent).as_posix() if path.is_relative_to(PACKAGE_DIR.parent) else str(path)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="m2h-separate",
        description="Extract the target sound class from a stereo (binaural) recording.",
    )
    parser.add_argument("input", type=Path, help="stereo wav/flac/ogg file, any length and sample rate")
    parser.add_argument("output", type=Path, help="output file (format from the extension): stereo for the "
                        "listener and masked_mixture outputs unless --mono, else mono")
    parser.add_argument("--target", required=True, help="target class, one of the checkpoint's classes (e.g. speech)")
    parser.add_argument("--checkpoint", type=Path, default=DEFAULT_SEPARATOR_CHECKPOINT,
                        help=f"separator checkpoint (default: the shipped {_shipped(DEFAULT_SEPARATOR_CHECKPOINT)})")
    parser.add_argument("--output", dest="audio_output", default=AUDIO_OUTPUTS[0], choices=AUDIO_OUTPUTS,
                        help="what to extract, as separator_node's audio_output (default: %(default)s, the target's "
                        "early image at both ears)")
    parser.add_argument("--mono", action="store_true", help="the ear mean (one channel), for a speech recogniser")
    parser.add_argument("--listener", type=Path, default=DEFAULT_LISTENER_CHECKPOINT,
                        help=f"listener checkpoint for --output listener (default: the shipped {_shipped(DEFAULT_LISTENER_CHECKPOINT)})")
    parser.add_argument("--device", default="cpu", choices=DEVICES,
                        help="torch device: cpu (default), cuda, or auto (CUDA when present)")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    threads = torch.get_num_threads()
    torch.set_num_threads(inference_threads(1))  # frames go through one at a time
    try:
        loaded = load_separator(args.checkpoint, map_location=resolve_device(args.device, field="--device"))
        loaded.class_index(args.target)  # fail on an unknown class before reading the audio
        try:
            audio, sample_rate = sf.read(args.input, dtype="float32", always_2d=True)
        except (sf.LibsndfileError, RuntimeError, OSError) as exc:
            raise AudioError(f"cannot read {args.input}: {exc}") from exc
        listener = None
        if args.audio_output == "listener":
            listener = load_listener(args.listener, map_location=resolve_device(args.device, field="--device"))
        separated = separate_recording(loaded, audio, sample_rate, args.target, output=args.audio_output,
                                       listener=listener, binaural=not args.mono)
        _write(args.output, separated, sample_rate)
    except M2HError as exc:
        print(f"m2h-separate: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    finally:
        torch.set_num_threads(threads)  # main() also runs in-process (tests): leave the process as found
    return 0


if __name__ == "__main__":
    sys.exit(main())
