#!/usr/bin/env python3
"""Which binaural cue tells where the target is? ITD (GCC-PHAT) and ILD against the true bearing.

    python scripts/bench/doa_cues.py [--count 160] [--sound-split unheard] [--threads 1]

On the first --count near-target test episodes, at the start pose (step 0): the straight-line bearing
of the target relative to the heading vs each cue, computed from the binaural mixture, from f^B's
separated binaural (shipped separator; magnitude only, so ILD only) and from the target alone as
heard (ground truth: what a perfect separator would give). Reports the correlation of each cue with
sin(bearing) (and with the distractor's), and how often its sign gives the right side for targets
well to one side (|sin| > 0.75). Then the DoA controller itself: how often the heading it steps in
is within 45 deg of the target's bearing (a random heading: about 1 in 4, less 1 in 4 exactly on the
boundary). Test episodes and scenes, full acoustics; RIR banks from the cache.
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402
import torch  # noqa: E402

from m2h_ros.agents.base import EpisodeStart  # noqa: E402
from m2h_ros.agents.baselines import DirectionOfArrival  # noqa: E402
from m2h_ros.agents.rollout import controller_observation  # noqa: E402
from m2h_ros.core.audio.doa import gcc_phat_itd, interaural_level_difference, lateral_sine  # noqa: E402
from m2h_ros.core.audio.stft import stft  # noqa: E402
from m2h_ros.core.sounds.library import SoundLibrary  # noqa: E402
from m2h_ros.core.world.env import BatchEnv, EnvConfig  # noqa: E402
from m2h_ros.core.world.episodes import MOVE_FORWARD, EpisodeConfig, episodes_for  # noqa: E402
from m2h_ros.models.checkpoint import DEFAULT_SEPARATOR_CHECKPOINT, load_separator  # noqa: E402
from m2h_ros.models.runner import SeparatorRunner  # noqa: E402
from m2h_ros.machine import load_average  # noqa: E402

CUES = ("ITD, mixture", "ITD, target alone", "ILD, mixture", "ILD, f^B binaural", "ILD, target alone")


def bearing_sine(grid, node: int, yaw: float, to: int) -> float:
    d = grid.positions[to] - grid.positions[node]
    return float(np.sin(np.arctan2(d[1], d[0]) - yaw))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=160)
    parser.add_argument("--sound-split", default="unheard", choices=("heard", "unheard"))
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    library = SoundLibrary.load()
    episodes = episodes_for(EpisodeConfig(task="near_target", scene_split="test", sound_split=args.sound_split),
                            library)[: args.count]
    loaded = load_separator(DEFAULT_SEPARATOR_CHECKPOINT)
    rows, facing, b = [], [], 16
    for first in range(0, len(episodes), b):
        chunk = episodes[first:first + b]
        n = len(chunk)
        env = BatchEnv(chunk, library, n_envs=n, config=EnvConfig(camera=False, shuffle=False), autoreset=False,
                       threads=args.threads)
        runner = SeparatorRunner(loaded, n)
        classes = runner.class_indices([e.target_category for e in chunk])
        controller = DirectionOfArrival(n)
        for slot, episode in enumerate(chunk):
            controller.reset(slot, EpisodeStart.of(episode))
        obs, info = env.reset()
        grids = [env.scene_of(slot).grid for slot in range(n)]
        separation = runner.step(obs["audio"], classes, np.ones(n, bool))
        mixture, alone = stft(obs["audio"]), stft(info["target_binaural"])
        cues = np.stack([lateral_sine(gcc_phat_itd(mixture)), lateral_sine(gcc_phat_itd(alone)),
                         interaural_level_difference(np.abs(mixture)),
                         interaural_level_difference(separation.binaural),
                         interaural_level_difference(np.abs(alone))], axis=1)
        for slot, episode in enumerate(chunk):
            yaw = float(obs["pose"][slot, 2])
            rows.append((bearing_sine(grids[slot], episode.start_node, yaw, episode.target_node),
                         bearing_sine(grids[slot], episode.start_node, yaw, episode.source_nodes[1]), *cues[slot]))
        stepped = np.zeros(n, bool)
        for step in range(episodes[0].max_steps):
            if step:
                separation = runner.step(obs["audio"], classes, np.zeros(n, bool))
            actions = controller.act(controller_observation(obs, separation))
            for slot in np.flatnonzero((actions == MOVE_FORWARD) & ~stepped):
                d = grids[slot].positions[chunk[slot].target_node] - grids[slot].positions[obs["node"][slot]]
                facing.append(np.cos(np.arctan2(d[1], d[0]) - obs["pose"][slot, 2]) > np.cos(np.pi / 4) - 1e-6)
                stepped[slot] = True
            if stepped.all():
                break
            obs, *_ = env.step(actions)
        env.close()
    table = np.array(rows)
    target, distractor = table[:, 0], table[:, 1]
    lateral = np.abs(target) > 0.75
    print(f"{len(table)} near-target {args.sound_split} test episodes at step 0; {lateral.sum()} targets well to a side")
    print(f"{'cue':<20} {'corr with target sin':>21} {'corr with distractor sin':>25} {'right side (lateral)':>21}")
    for k, name in enumerate(CUES):
        cue = table[:, 2 + k]
        print(f"{name:<20} {np.corrcoef(target, cue)[0, 1]:>21.2f} {np.corrcoef(distractor, cue)[0, 1]:>25.2f} "
              f"{np.mean(np.sign(cue[lateral]) == np.sign(target[lateral])):>21.2f}")
    print(f"DoA controller steps within 45 deg of the target's bearing in {np.mean(facing):.2f} of "
          f"{len(facing)} episodes")
    print(f"load average: {load_average()}")


if __name__ == "__main__":
    main()
