"""Camera images as robot drivers publish them (rgb8, bgr8, 16UC1 millimetres, 32FC1 metres, padded
rows) read into the arrays the controllers take; a wrong encoding or size is named."""

import array

import numpy as np
import pytest
from sensor_msgs.msg import Image

from m2h_ros.errors import PipelineError
from m2h_ros.ros import convert


def image(encoding: str, values: np.ndarray, *, pad: int = 0) -> Image:
    height, width = values.shape[:2]
    rows = values.reshape(height, -1).view(np.uint8).reshape(height, -1)
    padded = np.concatenate([rows, np.full((height, pad), 7, np.uint8)], axis=1)
    return Image(height=height, width=width, encoding=encoding, step=padded.shape[1],
                 data=array.array("B", padded.tobytes()))


def test_drivers_encodings_and_padded_rows_are_read():
    rgb = np.random.default_rng(1).integers(0, 256, (3, 5, 3), dtype=np.uint8)
    np.testing.assert_array_equal(convert.image_from_msg(image("rgb8", rgb, pad=1)), rgb)
    np.testing.assert_array_equal(convert.image_from_msg(image("bgr8", rgb[..., ::-1].copy(), pad=3)), rgb)
    millimetres = np.array([[0, 1500], [2250, 65535]], "<u2")
    np.testing.assert_allclose(convert.image_from_msg(image("16UC1", millimetres, pad=2)),
                               millimetres / 1000.0, rtol=1e-6)
    metres = np.array([[0.5, np.nan]], "<f4")
    np.testing.assert_array_equal(convert.image_from_msg(image("32FC1", metres)), metres)


def test_a_wrong_encoding_or_size_is_named():
    with pytest.raises(PipelineError, match="'mono8' is not one of"):
        convert.image_from_msg(Image(height=1, width=1, encoding="mono8", step=1, data=[0]))
    with pytest.raises(PipelineError, match="rgb8 image of 2x2 \\(step 6\\) holds 9 bytes"):
        convert.image_from_msg(Image(height=2, width=2, encoding="rgb8", step=6, data=[0] * 9))
