#!/usr/bin/env python3
"""Write a spherical-head HRIR set as a SOFA file (SimpleFreeFieldHRIR, written with sofar).

    python scripts/write_head_sofa.py --out sphere.sofa [--radius 0.0875] [--rate 48000]

No package ships a measured head other than KEMAR, so this stands in for "your robot's head": a rigid
sphere with the ears at +-90 degrees azimuth (Brown & Duda, "A structural model for binaural sound
synthesis", 1998): each ear is the sphere's head-shadow filter
H(w, theta) = (1 + j alpha(theta) w / 2 w0) / (1 + j w / 2 w0), w0 = c / radius,
alpha(theta) = (1 + alpha_min / 2) + (1 - alpha_min / 2) cos(theta / theta_min * 180 deg)
(alpha_min 0.1, theta_min 150 deg, theta the angle between the source and the ear), delayed by
Woodworth's arrival time (-radius/c cos theta in front of the ear, radius/c (theta - 90 deg) behind it).
Directions: 5-degree azimuth steps on elevation rings from -40 to 90 degrees in 10-degree steps.
Use it as ``head: sofa:PATH`` (docs/how-to/robot-head.md).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from m2h_ros.errors import ConfigError, reports_errors

SPEED_OF_SOUND = 343.0
ALPHA_MIN, THETA_MIN = 0.1, np.deg2rad(150.0)
LENGTH = 256  # taps per impulse response
ONSET = 32  # sample at which the earliest possible arrival (the ear facing the source) falls


def grid() -> np.ndarray:
    """(D, 3) azimuth (deg, counter-clockwise from the front), elevation (deg), distance (m)."""
    rows = []
    for elevation in range(-40, 91, 10):
        step = 360 if elevation == 90 else 5
        rows += [(float(azimuth), float(elevation), 1.2) for azimuth in range(0, 360, step)]
    return np.array(rows)


def sphere_hrirs(positions: np.ndarray, *, radius: float, rate: int) -> np.ndarray:
    """(D, 2, LENGTH) impulse responses of the spherical head for spherical ``positions`` (deg, deg, m)."""
    az, el = np.deg2rad(positions[:, 0]), np.deg2rad(positions[:, 1])
    source = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=-1)
    ears = np.array([[0.0, 1.0, 0.0], [0.0, -1.0, 0.0]])  # left (+y), right
    theta = np.arccos(np.clip(source @ ears.T, -1.0, 1.0))  # (D, 2) source-to-ear angle
    delay = np.where(theta < np.pi / 2, -radius / SPEED_OF_SOUND * np.cos(theta),
                     radius / SPEED_OF_SOUND * (theta - np.pi / 2))  # s, relative to the head centre
    n_fft = 4 * LENGTH
    omega = 2 * np.pi * np.fft.rfftfreq(n_fft, 1.0 / rate)
    w0 = SPEED_OF_SOUND / radius
    alpha = (1 + ALPHA_MIN / 2) + (1 - ALPHA_MIN / 2) * np.cos(theta / THETA_MIN * np.pi)
    shadow = (1 + 1j * alpha[..., None] * omega / (2 * w0)) / (1 + 1j * omega / (2 * w0))
    start = ONSET / rate + radius / SPEED_OF_SOUND  # the nearest ear arrives radius/c early
    spectrum = shadow * np.exp(-1j * omega * (start + delay)[..., None])
    return np.fft.irfft(spectrum, n_fft)[..., :LENGTH] * np.hanning(2 * LENGTH)[LENGTH:]


def write(path: Path, *, radius: float, rate: int) -> Path:
    import sofar

    if not 0.03 <= radius <= 0.5:
        raise ConfigError(f"--radius {radius} m is not a head's (0.03 to 0.5 m)")
    if rate < 16000:
        raise ConfigError(f"--rate {rate} Hz is below the simulation's 16000 Hz")
    positions = grid()
    sofa = sofar.Sofa("SimpleFreeFieldHRIR")
    sofa.GLOBAL_Title = f"Rigid spherical head, radius {radius} m (Brown & Duda model)"
    sofa.GLOBAL_ListenerShortName = "sphere"
    sofa.Data_IR = sphere_hrirs(positions, radius=radius, rate=rate)
    sofa.Data_SamplingRate = float(rate)
    sofa.SourcePosition = positions
    sofa.ReceiverPosition = np.array([[[0.0], [radius], [0.0]], [[0.0], [-radius], [0.0]]])
    path.parent.mkdir(parents=True, exist_ok=True)
    sofar.write_sofa(str(path), sofa)
    return path


@reports_errors("write_head_sofa")
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True, help="SOFA file to write")
    parser.add_argument("--radius", type=float, default=0.0875, help="sphere radius in metres (default 0.0875)")
    parser.add_argument("--rate", type=int, default=48000, help="sample rate in Hz (default 48000)")
    args = parser.parse_args(argv)
    path = write(args.out, radius=args.radius, rate=args.rate)
    print(f"wrote {path} ({path.stat().st_size / 2**20:.1f} MiB): {len(grid())} directions, {args.rate} Hz")
    return 0


if __name__ == "__main__":
    sys.exit(main())
