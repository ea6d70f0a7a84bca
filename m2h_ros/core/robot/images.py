"""A robot camera's images made into what the learned controllers were trained on: the simulator's
square images (``CameraConfig``: 128 x 128 pixels, depth in metres clipped to ``max_depth``).

An image of another size is centre-cropped to the target's aspect ratio (a 640 x 480 frame keeps its
middle 480 x 480) and then area-averaged to the target size, so every output pixel is the mean of the
input pixels it covers, whatever the ratio. Depth pixels without a reading (0, NaN or inf, as depth
drivers mark them) count as ``max_depth``, as the simulator's depth does where nothing is nearer. The
field of view is not changed: a camera narrower than the simulator's 90 degrees gives a closer view of
the same scene."""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from m2h_ros.core.world.camera import CameraConfig
from m2h_ros.errors import PipelineError


@lru_cache(maxsize=16)
def _area_weights(n_in: int, n_out: int) -> np.ndarray:
    """(n_out, n_in) row-stochastic matrix: output pixel i averages the input span [i, i+1) * n_in / n_out.
    Cached: a camera sends every frame at the same size (read-only, shared between calls)."""
    edges = np.arange(n_out + 1) * (n_in / n_out)
    left, right = edges[:-1, None], edges[1:, None]
    pixels = np.arange(n_in)[None, :]
    overlap = np.clip(np.minimum(right, pixels + 1) - np.maximum(left, pixels), 0.0, None)
    weights = overlap / overlap.sum(axis=1, keepdims=True)
    weights.flags.writeable = False
    return weights


def _centre_crop(image: np.ndarray, aspect: float) -> np.ndarray:
    """The middle of ``image`` whose width / height is ``aspect``."""
    height, width = image.shape[:2]
    if width > aspect * height:
        keep = max(1, round(aspect * height))
        first = (width - keep) // 2
        return image[:, first:first + keep]
    keep = max(1, round(width / aspect))
    first = (height - keep) // 2
    return image[first:first + keep]


def _fit(image: np.ndarray, config: CameraConfig) -> np.ndarray:
    if image.shape[:2] == (config.height, config.width):
        return image.astype(np.float64)
    cropped = _centre_crop(image.astype(np.float64), config.width / config.height)
    rows = _area_weights(cropped.shape[0], config.height)
    cols = _area_weights(cropped.shape[1], config.width)
    down = np.tensordot(rows, cropped, axes=(1, 0))  # (height, W', ...)
    return np.moveaxis(np.tensordot(cols, down, axes=(1, 1)), 0, 1)  # (height, width, ...)


def fit_rgb(rgb: np.ndarray, config: CameraConfig | None = None) -> np.ndarray:
    """(H, W, 3) uint8 of any size -> (height, width, 3) uint8 of ``config``."""
    config = config or CameraConfig()
    if rgb.ndim != 3 or rgb.shape[2] != 3 or min(rgb.shape[:2]) < 1:
        raise PipelineError(f"an RGB image is (H, W, 3), got shape {rgb.shape}")
    return np.clip(np.rint(_fit(rgb, config)), 0, 255).astype(np.uint8)


def fit_depth(depth: np.ndarray, config: CameraConfig | None = None) -> np.ndarray:
    """(H, W) metres of any size -> (height, width) float32 metres of ``config``, in [0, max_depth]."""
    config = config or CameraConfig()
    if depth.ndim != 2 or min(depth.shape) < 1:
        raise PipelineError(f"a depth image is (H, W), got shape {depth.shape}")
    depth = np.asarray(depth, np.float64)
    readings = np.where(np.isfinite(depth) & (depth > 0), depth, config.max_depth)
    return np.clip(_fit(readings, config), 0.0, config.max_depth).astype(np.float32)
