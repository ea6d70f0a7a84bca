"""One pose's audio, as BatchEnv renders it: the sources' RIR spectra times their clips' spectra, one
inverse FFT for the target alone and the mixture, and the separators' log-magnitude input.

Shared by ``BatchEnv`` and its render processes (``render_worker``), so a pose renders to the same
numbers wherever it is rendered.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy import fft as sfft

from m2h_ros.core.audio.stft import StftConfig, stft
from m2h_ros.core.world.rir_bank import RirBank
from m2h_ros.core.world.rir_spectra import RirSpectra, StoredRirSpectra


def source_spectra(bank: RirBank, stored: StoredRirSpectra | None, cache: RirSpectra, sources: Sequence[int],
                   node: int, heading: int) -> list[np.ndarray]:
    """(2, F) RIR spectrum of each source to (node, heading): from the stored files, else ``cache``."""
    if stored is not None:
        return [stored.spectrum(source, node, heading) for source in sources]
    return cache.spectra([(bank, source, node, heading) for source in sources])


def render_pose(found: Sequence[np.ndarray], clip_spectra: np.ndarray, weight: np.float32, *, n_fft: int,
                n_samples: int) -> np.ndarray:
    """(4, S) view: the target alone at the pose (rows 0-1), then the clean mixture (rows 2-3), from the
    sources' RIR spectra ``found`` (target first) and their clips' spectra (>= len(found), F), the
    mixture scaled by ``weight`` (1 / number of sources)."""
    count = len(found)
    # Convolution in the frequency domain; by linearity the mixture needs one inverse FFT, and
    # target and mixture go through it together (pocketfft vectorises over >= 4 rows).
    both = np.empty((4, found[0].shape[-1]), np.complex64)
    target, mixture = both[:2], both[2:]
    np.multiply(found[0], clip_spectra[0], out=target)
    if count == 1:
        mixture[:] = target
    for j in range(1, count):
        if j == 1:   # source 1 + target: the sum over sources, bit for bit
            np.multiply(found[1], clip_spectra[1], out=mixture)
            mixture += target
        else:
            mixture += found[j] * clip_spectra[j]
    # Scaled through a float32 view: the same products (the imaginary part of w + 0j adds exact
    # zeros) without numpy's cast of the scalar to complex, 4x slower for these rows.
    mixture.view(np.float32)[:] *= weight
    return sfft.irfft(both, n_fft, axis=-1, overwrite_x=True)[:, :n_samples]


def log_magnitude_into(audio: np.ndarray, out: np.ndarray, *, config: StftConfig) -> np.ndarray:
    """log(1 + |STFT(audio)|) of a (2, S) waveform written into ``out`` (2, F, T) float32."""
    # log(1 + |X|) as log(|X| + 1): numpy's float32 log1p is ~5x slower than its log; they differ by
    # < 1e-6 here.
    magnitude = np.abs(stft(audio, config=config), out=out)
    magnitude += 1.0
    return np.log(magnitude, out=magnitude)
