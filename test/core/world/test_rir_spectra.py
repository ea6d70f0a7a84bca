"""RirSpectra: the cached spectra are the padded RIRs' rfft, the LRU stays within its byte bound."""

import numpy as np
import pytest
from scipy import fft as sfft

from m2h_ros.core.world.rir_bank import RirBank
from m2h_ros.core.world.rir_spectra import RirSpectra
from m2h_ros.core.world.scene import generate_scene
from m2h_ros.errors import ConfigError


@pytest.fixture(scope="module")
def bank(fast_acoustics, rir_cache):
    return RirBank(generate_scene(0, preset="small"), fast_acoustics, cache_dir=rir_cache, progress=False)


def test_spectra_are_the_padded_rfft_and_the_lru_is_bounded(bank, fast_acoustics):
    n_fft, taps = 6000, fast_acoustics.n_taps
    spectra = RirSpectra(n_fft, taps, max_bytes=3 * 2 * (n_fft // 2 + 1) * 8 + 100)
    assert spectra.capacity == 3 and spectra.entry_bytes == 2 * 3001 * 8
    requests = [(bank, 0, 1, 2), (bank, 1, 1, 2), (bank, 0, 1, 3), (bank, 0, 1, 2)]
    found = spectra.spectra(requests)
    rirs = bank.rirs([0, 1, 0, 0], [1, 1, 1, 1], [2, 2, 3, 2])
    for spectrum, rir in zip(found, rirs):
        np.testing.assert_array_equal(spectrum, sfft.rfft(rir, n_fft, axis=-1))
        assert not spectrum.flags.writeable
    assert (spectra.hits, spectra.misses) == (0, 4)   # the repeat within one call was not cached yet
    again = spectra.spectra([(bank, 0, 1, 2), (bank, 2, 0, 0)])
    assert again[0] is found[3] and (spectra.hits, spectra.misses) == (1, 5)
    assert len(spectra) == 3 and spectra.nbytes <= 3 * spectra.entry_bytes
    # (0, 1, 2) was used last but one, (1, 1, 2) least recently: it went first.
    assert spectra.spectra([(bank, 1, 1, 2)])[0] is not found[1] and spectra.misses == 6
    spectra.clear()
    assert len(spectra) == 0


def test_no_capacity_keeps_nothing(bank, fast_acoustics):
    spectra = RirSpectra(4000, fast_acoustics.n_taps, max_bytes=0)
    first, second = spectra.spectra([(bank, 0, 0, 0)] * 2)
    np.testing.assert_array_equal(first, second)
    assert len(spectra) == 0 and spectra.misses == 2
    with pytest.raises(ConfigError, match="max_bytes"):
        RirSpectra(4000, fast_acoustics.n_taps, max_bytes=-1)
    with pytest.raises(ConfigError, match="shorter"):
        RirSpectra(100, fast_acoustics.n_taps, max_bytes=0)


def test_rirs_write_into_a_longer_buffer_and_leave_the_rest(bank, fast_acoustics):
    taps = fast_acoustics.n_taps
    buffer = np.full((2, 2, taps + 50), 7.0, np.float32)
    assert bank.rirs([0, 1], [1, 1], [2, 3], out=buffer) is buffer
    np.testing.assert_array_equal(buffer[..., :taps], bank.rirs([0, 1], [1, 1], [2, 3]))
    assert (buffer[..., taps:] == 7.0).all()
    with pytest.raises(ConfigError, match="out"):
        bank.rirs([0], [1], [2], out=np.zeros((1, 2, taps - 1), np.float32))
    with pytest.raises(ConfigError, match="out"):
        bank.rirs([0], [1], [2], out=np.zeros((1, 2, taps), np.float64))
    with pytest.raises(ConfigError, match="heading"):
        bank.rirs([0], [1], [4])
