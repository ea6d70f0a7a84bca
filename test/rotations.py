"""Rotation matrices of quaternions, for checking frames by where they send axes."""

import numpy as np


def rotation_matrix(x: float, y: float, z: float, w: float) -> np.ndarray:
    """The 3 x 3 rotation of the unit quaternion (x, y, z, w)."""
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
