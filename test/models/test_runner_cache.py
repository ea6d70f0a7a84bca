"""SeparatorRunner's pose cache: reused f^B / f^M outputs give what running them again gives (to float
tolerance against the uncached runner, bit for bit against a runner that starts with an empty cache,
as a resumed training run does), with two torch threads, where oneDNN's batched results differ in the
last bits by batch composition; misses split over the helper thread and the channels_last outputs change no
number."""

import numpy as np
import pytest
import torch

from m2h_ros.errors import ConfigError
from m2h_ros.models.checkpoint import DEFAULT_SEPARATOR_CHECKPOINT, load_separator
from m2h_ros.core.audio.stft import from_slices
from m2h_ros.models.runner import SeparationStep, SeparatorRunner

SLOTS = 5
TOLERANCE = 2e-5  # relative to the output's peak, as test_separator_inference


@pytest.fixture(scope="module")
def loaded():
    return load_separator(DEFAULT_SEPARATOR_CHECKPOINT)


@pytest.fixture
def two_threads():
    threads = torch.get_num_threads()
    torch.set_num_threads(2)
    yield
    torch.set_num_threads(threads)


def clip(episode: int, slot: int, pose: int) -> np.ndarray:
    """The binaural clip a slot hears at a pose in an episode (same pose, same clip)."""
    rng = np.random.default_rng([episode, slot, pose])
    return (rng.standard_normal((2, 16000)) * rng.uniform(0.2, 2.0)).astype(np.float32)


def assert_close(expected, actual, what: str) -> None:
    for name in ("binaural", "monaural", "refined"):
        a, b = getattr(expected, name), getattr(actual, name)
        assert float(np.abs(a - b).max()) <= TOLERANCE * float(np.abs(a).max()), f"{name}, {what}"


def assert_equal(expected, actual, what: str) -> None:
    for name in ("binaural", "monaural", "refined"):
        assert np.array_equal(getattr(expected, name), getattr(actual, name)), f"{name}, {what}"


def test_cached_outputs_equal_recomputed_ones(loaded, two_threads):
    cached = SeparatorRunner(loaded, SLOTS, pose_cache=2)
    plain = SeparatorRunner(loaded, SLOTS)
    resumed = None
    classes = np.array([0, 1, 0, 1, 1])
    rng = np.random.default_rng(3)
    episode = np.zeros(SLOTS, np.int64)
    partial = 0
    for step in range(12):
        reset = np.ones(SLOTS, bool) if step == 0 else rng.random(SLOTS) < 0.15
        episode += reset & (step > 0)
        poses = rng.integers(0, 3, SLOTS)  # 3 poses, 2 kept per slot: hits, misses and evictions
        audio = np.stack([clip(int(episode[s]), s, int(poses[s])) for s in range(SLOTS)])
        keys = [(int(p), 0) for p in poses]  # reused across episodes: a reset must drop them
        hits = cached.cache_hits
        got = cached.step(audio, classes, reset, keys=keys)
        partial += 0 < cached.cache_hits - hits < SLOTS
        assert_close(plain.step(audio, classes, reset), got, f"step {step}")
        if resumed is not None:
            assert_equal(got, resumed.step(audio, classes, reset, keys=keys), f"step {step} after the restart")
        rows = np.array([1, 3])  # some slots only, as the trainer separates terminal observations
        sub = cached.step(audio[rows], classes[rows], np.zeros(2, bool), rows=rows, keys=[keys[r] for r in rows])
        assert_close(plain.step(audio[rows], classes[rows], np.zeros(2, bool), rows=rows), sub, f"rows, step {step}")
        if resumed is not None:
            assert_equal(sub, resumed.step(audio[rows], classes[rows], np.zeros(2, bool), rows=rows,
                                           keys=[keys[r] for r in rows]), f"rows, step {step} after the restart")
        if step == 5:  # a restart: same memory, empty cache
            resumed = SeparatorRunner(loaded, SLOTS, pose_cache=2)
            resumed.memory = cached.memory.clone()
    assert cached.cache_hits > 0 and cached.cache_misses > 0 and partial > 0
    assert all(len(cache) <= 2 for cache in cached._cache)


def test_without_keys_or_cache_nothing_is_kept(loaded):
    runner = SeparatorRunner(loaded, 2)
    audio = np.stack([clip(0, s, 0) for s in range(2)])
    runner.step(audio, np.zeros(2, np.int64), np.ones(2, bool), keys=[(0, 0), (0, 0)])
    assert runner.cache_hits == runner.cache_misses == 0
    with pytest.raises(ConfigError, match="pose_cache"):
        SeparatorRunner(loaded, 2, pose_cache=-1)
    with pytest.raises(ConfigError, match="keys"):
        SeparatorRunner(loaded, 2, pose_cache=4).step(audio, np.zeros(2, np.int64), np.ones(2, bool), keys=[(0, 0)])


def test_two_threaded_misses_and_channels_last_outputs_change_no_number(loaded, two_threads):
    """Cache misses split over the helper thread give the one-thread front's outputs bit for bit; the
    outputs are the networks' sliced channels_last tensors, with the (F, T) arrays made from them."""
    split = SeparatorRunner(loaded, SLOTS, pose_cache=2)
    single = SeparatorRunner(loaded, SLOTS, pose_cache=2)
    assert split._helper is not None  # two CPUs: tests run where the trainer does
    single._helper = None
    classes = np.array([1, 0, 1, 1, 0])
    rng = np.random.default_rng(5)
    for step in range(6):
        reset = np.ones(SLOTS, bool) if step == 0 else np.zeros(SLOTS, bool)
        poses = rng.integers(0, 3, SLOTS)
        audio = np.stack([clip(0, s, int(poses[s])) for s in range(SLOTS)])
        keys = [(int(p), 0) for p in poses]
        got = split.step(audio, classes, reset, keys=keys)
        assert_equal(single.step(audio, classes, reset, keys=keys), got, f"step {step}")
        for name in ("binaural", "monaural", "refined"):
            tensor = getattr(got.sliced, name)
            assert tensor.is_contiguous(memory_format=torch.channels_last), f"{name}, step {step}"
            array = getattr(got, name)
            assert np.array_equal(from_slices(tensor.numpy(), n_slices=16).reshape(array.shape), array)
    assert split.cache_hits > 0 and split.memory.is_contiguous(memory_format=torch.channels_last)
    zero = np.zeros((1, 512, 32), np.float32)
    with pytest.raises(ConfigError, match="three arrays or its sliced"):
        SeparationStep(zero, zero)
