"""What a listener gets: the early image keeps the direct sound and the first 50 ms after it, and the
masked mixture gives each ear's own mixture back under a full mask and the target as heard under an
ideal one."""

import numpy as np

from m2h_ros.core.audio.metrics import si_sdr
from m2h_ros.core.audio.stft import DEFAULT_STFT, masked_mixture, stft
from m2h_ros.training.listener_eval import early_image

RATE = DEFAULT_STFT.sample_rate


def test_the_early_image_keeps_the_first_50_ms_after_the_direct_sound():
    clip = np.random.default_rng(0).standard_normal((1, RATE)).astype(np.float32)
    rir = np.zeros((1, 2, 4000), np.float32)
    rir[0, 0, 100], rir[0, 1, 103] = 1.0, 0.5           # direct sound at each ear
    rir[0, :, 100 + 790] = 0.25                          # an early reflection, inside 50 ms
    rir[0, :, 100 + 1200] = 0.25                         # late: left out
    image = early_image(clip, rir, np.array([100.4]), sample_rate=RATE)[0]
    want = np.zeros(RATE)
    want[100:] += 0.5 * clip[0, :-100]
    want[103:] += 0.25 * clip[0, :-103]
    want[890:] += 0.25 * clip[0, :-890]
    np.testing.assert_allclose(image, want, atol=1e-5)


def test_a_full_mask_gives_the_microphone_and_an_ideal_one_the_target_as_heard():
    rng = np.random.default_rng(1)
    t = np.arange(RATE) / RATE
    target = np.stack([np.sin(2 * np.pi * 440 * t), 0.6 * np.sin(2 * np.pi * 440 * (t - 0.0004))])  # ITD
    distractor = 0.3 * rng.standard_normal((2, RATE))
    mixture = (target + distractor).astype(np.float32)
    np.testing.assert_allclose(masked_mixture(np.abs(stft(mixture)), mixture), mixture.mean(axis=0), atol=1e-4)
    ideal = np.minimum(np.abs(stft(target.astype(np.float32))), np.abs(stft(mixture)))
    out = masked_mixture(ideal, mixture)
    assert si_sdr(out, target.mean(axis=0)) > 15.0 > si_sdr(mixture.mean(axis=0), target.mean(axis=0))
