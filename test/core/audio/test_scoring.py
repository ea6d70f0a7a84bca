"""The shared per-step scores: the deployable (mixture-phase) variant is held to the target as heard."""

import numpy as np
import pytest

from m2h_ros.core.audio.scoring import StepTruth, deployable_reference, score_magnitude
from m2h_ros.core.audio.stft import stft
from m2h_ros.errors import AudioError


def _truth(rng):
    dry = rng.standard_normal((3, 16000)).astype(np.float32)
    # As heard: delayed, filtered differently per ear (not a copy of the dry clip).
    left = np.roll(dry, 40, axis=-1) + 0.5 * np.roll(dry, 300, axis=-1)
    right = 0.7 * np.roll(dry, 45, axis=-1) - 0.3 * np.roll(dry, 900, axis=-1)
    return StepTruth(target_monaural=dry, target_binaural=np.stack([left, right], axis=1).astype(np.float32))


def test_the_deployable_reference_is_the_ear_mean_of_the_target_as_heard():
    # Two episodes of hand-made ears whose mean is known: 2 everywhere, then -1 everywhere; neither ear
    # nor the dry clip (zeros) equals it.
    ramp = np.arange(8, dtype=np.float32)
    ears = np.stack([np.stack([2 + ramp, 2 - ramp]), np.stack([np.full(8, 3.0), np.full(8, -5.0)])])
    truth = StepTruth(target_monaural=np.zeros((2, 8), np.float32), target_binaural=ears.astype(np.float32))
    np.testing.assert_array_equal(deployable_reference(truth), [[2.0] * 8, [-1.0] * 8])
    truth = _truth(np.random.default_rng(0))
    with pytest.raises(AudioError, match="target_binaural"):
        deployable_reference(StepTruth(truth.target_monaural, truth.target_binaural[:, 0]))


def test_the_target_as_heard_is_perfect_and_a_distractor_costs():
    rng = np.random.default_rng(1)
    truth = _truth(rng)
    heard = truth.target_binaural
    alone = score_magnitude(np.abs(stft(heard.mean(axis=1))), heard, truth)
    assert (alone.si_sdr_mixture_phase > 40).all()
    # ... while against the dry clip (ground-truth phase) the reverberant magnitude is far from perfect.
    assert (alone.si_sdr < 10).all()
    mixture = (heard + rng.standard_normal(heard.shape).astype(np.float32)) / 2
    mixed = score_magnitude(np.abs(stft(mixture.mean(axis=1))), mixture, truth)
    assert (mixed.si_sdr_mixture_phase < alone.si_sdr_mixture_phase - 20).all()


@pytest.mark.parametrize("repeated", [True, False])
def test_a_batch_scores_each_row_as_alone(repeated):
    """An episode's steps share one target clip, whose STFT a batch computes once: every score is the
    same, bit for bit, as that row scored alone (what the live evaluator does), and a batch of
    different clips too."""
    rng = np.random.default_rng(2)
    truth = _truth(rng)
    steps = 5
    dry = np.repeat(truth.target_monaural[:1], steps, axis=0) if repeated else \
        rng.standard_normal((steps, 16000)).astype(np.float32)
    heard = np.repeat(truth.target_binaural[:1], steps, axis=0) * rng.uniform(0.5, 2.0, (steps, 1, 1)).astype(np.float32)
    mixture = (heard + rng.standard_normal(heard.shape).astype(np.float32)) / 2
    estimate = np.abs(stft(mixture.mean(axis=1))) * rng.uniform(0.5, 1.5, (steps, 1, 1)).astype(np.float32)
    batch = score_magnitude(estimate, mixture, StepTruth(dry, heard))
    for row in range(steps):
        alone = score_magnitude(estimate[row], mixture[row], StepTruth(dry[row], heard[row]))
        for name in ("si_sdr", "si_sdr_mixture_phase", "stft_distance"):
            assert getattr(batch, name)[row] == getattr(alone, name), (name, row)
    with pytest.raises(AudioError, match="NaN"):  # a NaN in a repeated clip is still named
        score_magnitude(estimate, mixture, StepTruth(np.where(np.arange(16000) == 7, np.nan, dry), heard))
