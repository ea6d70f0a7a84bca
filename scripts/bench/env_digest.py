"""Digest of every number BatchEnv returns over fixed runs on the test scenes, to check that a
speed change changes no number (bit for bit) against another version of the code.

    python scripts/bench/env_digest.py OUT.json [--compare OTHER.json] [--stored-rir-spectra]
    PYTHONPATH=/path/to/other/checkout python scripts/bench/env_digest.py OTHER.json   # the reference

Five runs (near- and far-target, with and without microphone noise and camera, 1-3 threads, pose
cache on and off, 4-16 slots, full and partial auto-resets); one SHA-256 per step over every array
of the observation, reward, flags and info (final observation and info included).
``--stored-rir-spectra`` runs them with ``BatchEnv(stored_rir_spectra=True)``, to compare against a
reference made without it (the digests do not record the option).
"""

from __future__ import annotations

import argparse
import hashlib
import json
from pathlib import Path

import numpy as np

import m2h_ros
from m2h_ros.core.sounds.library import SoundLibrary
from m2h_ros.core.world.env import BatchEnv, EnvConfig
from m2h_ros.core.world.episodes import EpisodeConfig, episodes_for

# (task, mic_noise, threads, pose_cache, n_envs, steps, camera)
RUNS = [("near_target", 0.0, 2, 32, 16, 45, True), ("near_target", 0.05, 1, 32, 5, 45, True),
        ("far_target", 0.05, 2, 32, 7, 60, True), ("far_target", 0.0, 3, 0, 4, 40, True),
        ("near_target", 0.0, 2, 32, 16, 25, False)]


def _update(digest, tree) -> None:
    if isinstance(tree, dict):
        for key in sorted(tree):
            digest.update(key.encode())
            _update(digest, tree[key])
    else:
        array = np.ascontiguousarray(tree)
        digest.update(f"{array.dtype}{array.shape}".encode())
        digest.update(array.tobytes())


def run(library: SoundLibrary, task: str, noise: float, threads: int, pose_cache: int, n_envs: int,
        steps: int, camera: bool, *, stored_rir_spectra: bool) -> list[str]:
    episodes = episodes_for(EpisodeConfig(task=task, scene_split="test", sound_split="unheard", count=200),
                            library)
    env = BatchEnv(episodes, library, n_envs=n_envs, threads=threads, pose_cache=pose_cache,
                   stored_rir_spectra=stored_rir_spectra, config=EnvConfig(camera=camera, mic_noise=noise))
    digests = []
    trees = env.reset()
    rng = np.random.default_rng(11)
    for _ in range(steps + 1):
        digest = hashlib.sha256()
        for tree in trees:
            _update(digest, tree if isinstance(tree, dict) else {"": tree})
        digests.append(digest.hexdigest()[:16])
        trees = env.step(rng.integers(4, size=n_envs))
    env.close()
    return digests


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="JSON file for the digests")
    parser.add_argument("--compare", type=Path, help="digests of another version: report the first difference")
    parser.add_argument("--stored-rir-spectra", action="store_true",
                        help="BatchEnv(stored_rir_spectra=True) (RIR spectra read from files, not transformed)")
    args = parser.parse_args()
    library = SoundLibrary.load()
    print(f"m2h_ros from {Path(m2h_ros.__file__).parent}")
    digests = {repr(case): run(library, *case, stored_rir_spectra=args.stored_rir_spectra) for case in RUNS}
    args.out.write_text(json.dumps(digests, indent=1))
    if args.compare is None:
        return
    other = json.loads(args.compare.read_text())
    for case, steps in digests.items():
        theirs = other.get(case)
        first = next((i for i, (a, b) in enumerate(zip(steps, theirs or [])) if a != b), None)
        same = theirs is not None and len(theirs) == len(steps) and first is None
        print(f"  {case}: {'identical' if same else f'DIFFERS (first at step {first})'}")
    if any(other.get(case) != steps for case, steps in digests.items()):
        raise SystemExit(1)


if __name__ == "__main__":
    main()
