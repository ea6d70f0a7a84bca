"""A robot camera's images of any size and encoding become the simulator's 128 x 128 RGB and metric
depth: centre-cropped to square, area-averaged, depth without a reading counted as the far limit."""

import numpy as np
import pytest

from m2h_ros.core.robot.images import fit_depth, fit_rgb
from m2h_ros.core.world.camera import CameraConfig
from m2h_ros.errors import PipelineError

SMALL = CameraConfig(width=4, height=4)


def test_a_wide_frame_keeps_its_middle_square_and_each_pixel_is_the_mean_of_its_block():
    rng = np.random.default_rng(0)
    frame = rng.integers(0, 256, (8, 12, 3), dtype=np.uint8)
    frame[:, :2] = 255  # the strips a centre crop drops
    frame[:, 10:] = 0
    got = fit_rgb(frame, SMALL)
    middle = frame[:, 2:10].astype(np.float64)
    blocks = middle.reshape(4, 2, 4, 2, 3).mean(axis=(1, 3))
    assert got.dtype == np.uint8 and got.shape == (4, 4, 3)
    np.testing.assert_array_equal(got, np.rint(blocks).astype(np.uint8))


def test_a_non_integer_ratio_averages_by_covered_area():
    depth = np.arange(36, dtype=np.float32).reshape(6, 6) / 10 + 1  # 6 -> 4: each output covers 1.5 pixels
    got = fit_depth(depth, SMALL)
    rows = np.array([[1, .5, 0, 0, 0, 0], [0, .5, 1, 0, 0, 0], [0, 0, 0, 1, .5, 0], [0, 0, 0, 0, .5, 1]]) / 1.5
    np.testing.assert_allclose(got, rows @ depth @ rows.T, rtol=1e-6)
    assert fit_depth(depth[:4, :4], SMALL) is not depth  # already the size: unchanged values
    np.testing.assert_array_equal(fit_depth(depth[:4, :4], SMALL), depth[:4, :4])


def test_depth_without_a_reading_counts_as_the_far_limit_and_is_clipped():
    depth = np.full((4, 4), 2.0, np.float32)
    depth[0, 0], depth[0, 1], depth[1, 0], depth[1, 1] = 0.0, np.nan, np.inf, 50.0
    got = fit_depth(depth, SMALL)
    assert got[0, 0] == got[0, 1] == got[1, 0] == got[1, 1] == SMALL.max_depth
    assert np.all(got[2:] == 2.0)


def test_the_default_is_the_policies_camera():
    assert fit_rgb(np.zeros((480, 640, 3), np.uint8)).shape == (128, 128, 3)
    assert fit_depth(np.ones((480, 640), np.float32)).shape == (128, 128)


@pytest.mark.parametrize("shape", [(4, 4), (4, 4, 4), (0, 4, 3)])
def test_a_wrong_shape_is_named(shape):
    with pytest.raises(PipelineError, match="RGB image is"):
        fit_rgb(np.zeros(shape, np.uint8), SMALL)
