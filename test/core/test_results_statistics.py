"""The statistics every results table reports: a mean with its standard error (paired differences) or with
a 95% Student t interval (episode tables), checked against scipy's own."""

import math

import numpy as np
import pytest
from scipy import stats

from m2h_ros.core.results import mean_ci, mean_sem


def test_mean_and_standard_error_match_scipy():
    values = np.random.default_rng(3).normal(1.5, 2.0, size=37)
    mean, sem = mean_sem(values)
    assert mean == pytest.approx(values.mean(), abs=1e-12)
    assert sem == pytest.approx(stats.sem(values), rel=1e-12)


def test_confidence_interval_matches_scipys_t_interval():
    values = np.random.default_rng(4).normal(-0.3, 0.8, size=12)
    mean, half_width = mean_ci(values)
    low, high = stats.t.interval(0.95, len(values) - 1, loc=values.mean(), scale=stats.sem(values))
    assert mean == pytest.approx(values.mean(), abs=1e-12)
    assert half_width == pytest.approx((high - low) / 2, rel=1e-9)
    assert mean_ci(values, level=0.5)[1] < half_width
    # the very number scipy.stats gives, for small and large samples (tables printed before stay the same)
    for n in (2, 12, 40, 1000):
        sample = values[:n] if n <= len(values) else np.resize(values, n) * np.linspace(1, 2, n)
        assert mean_ci(sample)[1] == float(stats.t.ppf(0.975, n - 1) * mean_sem(sample)[1])


@pytest.mark.parametrize("summary", [mean_sem, mean_ci])
def test_one_value_has_no_spread_and_none_has_no_mean(summary):
    assert summary([2.5]) == (2.5, 0.0)
    assert all(math.isnan(v) for v in summary([]))
