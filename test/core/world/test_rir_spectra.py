"""RirSpectra: the cached spectra are the padded RIRs' rfft, the LRU stays within its byte bound;
StoredRirSpectra: the stored ones are the same arrays, bit for bit."""

import numpy as np
import pytest
from scipy import fft as sfft

from m2h_ros.core.world.rir_bank import RirBank
from m2h_ros.core.world.rir_spectra import RirSpectra, StoredRirSpectra
from m2h_ros.core.world.scene import generate_scene
from m2h_ros.errors import CacheError, ConfigError


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


def test_stored_spectra_equal_the_computed_ones_bit_for_bit(bank, fast_acoustics):
    n_fft, n = 6000, bank.n_nodes
    stored = StoredRirSpectra(bank, n_fft)
    computed = RirSpectra(n_fft, fast_acoustics.n_taps, max_bytes=0)
    rng = np.random.default_rng(2)
    requests = [(int(s), int(r), int(h)) for s, r, h in zip(rng.integers(n, size=12), rng.integers(n, size=12),
                                                            rng.integers(4, size=12))]
    requests += [(n - 1, n - 1, 3), (0, 0, 0)]
    for (source, receiver, heading), spectrum in zip(requests, computed.spectra([(bank, *r) for r in requests])):
        found = stored.spectrum(source, receiver, heading)
        np.testing.assert_array_equal(found, spectrum)
        assert found.dtype == np.complex64 and not found.flags.writeable
    # A second instance maps the files the first wrote (one per source node) and does not rewrite them.
    written = {path: path.stat().st_mtime_ns for path in stored.directory.glob("src_*.npy")}
    again = StoredRirSpectra(bank, n_fft)
    again.build()
    assert len(list(again.directory.glob("src_*.npy"))) == n
    assert all(path.stat().st_mtime_ns == mtime for path, mtime in written.items())
    assert again.size_on_disk() >= n * n * 4 * 2 * (n_fft // 2 + 1) * 8
    np.testing.assert_array_equal(again.spectrum(*requests[0]), stored.spectrum(*requests[0]))
    with pytest.raises(ConfigError, match="source"):
        stored.spectrum(n, 0, 0)
    with pytest.raises(ConfigError, match="shorter"):
        StoredRirSpectra(bank, fast_acoustics.n_taps - 1)


def test_a_stored_spectra_file_of_another_shape_is_refused(bank, tmp_path):
    stored = StoredRirSpectra(bank, 5000)
    np.save(stored.path(1), np.zeros((2, 2), np.complex64))
    with pytest.raises(CacheError, match="delete it to rebuild"):
        stored.spectrum(1, 0, 0)
    stored.path(1).unlink()
    assert stored.spectrum(1, 0, 0).shape == (2, 2501)
