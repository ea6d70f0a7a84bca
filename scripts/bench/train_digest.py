"""Digest of the numbers PPO training produces over short fixed runs on the test scenes, to check that
a speed change changes no number (bit for bit) against another version of the code.

    python scripts/bench/train_digest.py OUT.json [--compare OTHER.json]
    PYTHONPATH=/path/to/other/checkout python scripts/bench/train_digest.py OTHER.json   # the reference

Four runs (pi^Q with f^R frozen and trained, pi^N, AV Navigator; camera on and off, 1 and 2 minibatches,
4-16 slots, 2 torch threads); per run one SHA-256 over the policy's and f^R's final weights and every
update's logged losses and episode figures (the rollout's actions and rewards feed both).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import tempfile
from pathlib import Path

import numpy as np

import m2h_ros
from m2h_ros.core.sounds.library import SoundLibrary
from m2h_ros.core.world.env import EnvConfig
from m2h_ros.core.world.episodes import EpisodeConfig
from m2h_ros.training.ppo import PPOTrainer
from m2h_ros.training.ppo_config import KINDS, PPOConfig

# (kind, train_refiner, camera, n_envs, n_minibatches, updates)
RUNS = [("quality", False, True, 16, 1, 3), ("quality", True, False, 4, 2, 2), ("navigation", False, True, 8, 2, 2),
        ("av_navigator", False, True, 4, 1, 2)]
LOGGED = ("episodes", "return_window", "final_nmse_window", "success_window", "value_loss", "action_loss", "entropy",
          "refiner_l1")


def run_digests(library: SoundLibrary) -> dict[str, str]:
    digests = {}
    for kind, refiner, camera, n_envs, minibatches, updates in RUNS:
        episodes = EpisodeConfig(task=KINDS[kind].task, scene_split="test", sound_split="heard", count=50)
        config = PPOConfig(kind=kind, episodes=episodes, env=EnvConfig(camera=camera), n_envs=n_envs,
                           n_minibatches=minibatches, updates=updates, train_refiner=refiner, threads=2,
                           checkpoint_every=updates + 1)
        name = f"{kind} refiner={refiner} camera={camera} n_envs={n_envs} minibatches={minibatches}"
        with tempfile.TemporaryDirectory() as out:
            trainer = PPOTrainer(config, library, out_dir=Path(out), progress=False)
            try:
                history = trainer.run().history
            finally:
                trainer.env.close()
        digest = hashlib.sha256()
        for module in (trainer.net, trainer.separator.refiner):
            for key, tensor in module.state_dict().items():
                digest.update(key.encode())
                digest.update(tensor.detach().cpu().numpy().tobytes())
        digest.update(np.array([[row[k] for k in LOGGED] for row in history], np.float64).tobytes())
        digests[name] = digest.hexdigest()
        print(f"{name}: {digests[name][:16]}")
    return digests


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--compare", type=Path, help="a digest file of another checkout")
    args = parser.parse_args()
    print(f"m2h_ros from {Path(m2h_ros.__file__).parent}")
    digests = run_digests(SoundLibrary.load())
    args.out.write_text(json.dumps(digests, indent=1) + "\n")
    if args.compare:
        other = json.loads(args.compare.read_text())
        differ = [name for name in digests if other.get(name) != digests[name]]
        print("identical" if not differ and set(other) == set(digests) else f"DIFFERENT: {differ or 'run sets'}")


if __name__ == "__main__":
    main()
