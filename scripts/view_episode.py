#!/usr/bin/env python3
"""Run one test episode and draw it: top-down path with the sources, an SI-SDR trace per step, and
the camera views along the way (PNGs).

    python scripts/view_episode.py --index 3 --policy toward --out out/episode

SI-SDR per step is the paper's variant (estimate magnitude + the clean target's phase) for the raw
mixture (channel mean) and, when the separator checkpoint exists, for the separator's refined
estimate (f^B -> f^M -> f^R with its memory carried across steps).
"""

import argparse
import sys
from pathlib import Path

import numpy as np

from m2h_ros.core.audio.metrics import si_sdr
from m2h_ros.core.audio.stft import rebuild_ground_truth_phase, stft
from m2h_ros.core.sounds.library import TARGET_CATEGORIES, SoundLibrary
from m2h_ros.core.world.env import EnvConfig, MoveHearEnv
from m2h_ros.core.world.episodes import MOVE_FORWARD, TURN_LEFT, EpisodeConfig, episodes_for
from m2h_ros.core.world.viewer import camera_strip, plot_episode
from m2h_ros.errors import reports_errors
from m2h_ros.models.checkpoint import DEFAULT_SEPARATOR_CHECKPOINT, load_separator
from m2h_ros.models.separator import separate_clip


def toward_target(env: MoveHearEnv, obs) -> int:
    """Follow a shortest path to the target: forward if that gets closer, else turn left."""
    episode, grid = env.episode, env.episode.scene().grid
    ahead = grid.forward[obs["node"], obs["heading"]]
    closer = grid.geodesic[ahead, episode.target_node] < grid.geodesic[obs["node"], episode.target_node]
    return MOVE_FORWARD if closer else TURN_LEFT


@reports_errors("view_episode")
def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="near_target", choices=("near_target", "far_target"))
    parser.add_argument("--sound-split", default="unheard", choices=("heard", "unheard"))
    parser.add_argument("--index", type=int, default=0, help="episode index in the test episode file")
    parser.add_argument("--policy", default="toward", choices=("toward", "random"))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--checkpoint", type=Path, default=DEFAULT_SEPARATOR_CHECKPOINT)
    parser.add_argument("--world", default="", metavar="SPEC",
                        help="an imported world's episodes instead of the test scenes': map:PATH/map.yaml or mesh:PATH")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    library = SoundLibrary.load()
    episodes = episodes_for(EpisodeConfig(task=args.task, sound_split=args.sound_split,
                                          scene_split=args.world or "test"), library)
    env = MoveHearEnv(episodes, library, config=EnvConfig(camera=True))
    separator = load_separator(args.checkpoint) if args.checkpoint.exists() else None
    rng = np.random.default_rng(args.seed)
    obs, info = env.reset(options={"episode": args.index})
    path, views, memory = [], [], None
    terminated = truncated = False
    traces: dict[str, list[float]] = {"mixture": []}
    if separator is not None:
        traces["separator (refined)"] = []
        class_index = separator.class_index(TARGET_CATEGORIES[int(obs["target_class"])])
    while True:
        path.append((int(obs["node"]), int(obs["heading"])))
        views.append((obs["rgb"], obs["depth"][..., 0]))
        target = info["target_monaural"]
        mixture_mag = np.abs(stft(obs["audio"].mean(axis=0)))
        traces["mixture"].append(float(si_sdr(rebuild_ground_truth_phase(mixture_mag, target), target)))
        if separator is not None:
            result = separate_clip(separator.separator, obs["audio"][None], np.array([class_index]),
                                   memory=memory, config=separator.stft)
            memory = result.memory
            estimate = rebuild_ground_truth_phase(result.magnitude[0], target, config=separator.stft)
            traces["separator (refined)"].append(float(si_sdr(estimate, target)))
        if terminated or truncated:
            break  # the episode's last observation is scored too: that is the reported step
        action = toward_target(env, obs) if args.policy == "toward" else int(rng.integers(1, 4))
        obs, _, terminated, truncated, info = env.step(action)
    episode = env.episode
    scene = episode.scene()
    sources = [(scene.grid.positions[n], c, "target" if k == 0 else "distractor")
               for k, (n, c) in enumerate(zip(episode.source_nodes, episode.source_categories))]
    name = episode.episode_id.replace("/", "_")
    top = plot_episode(scene, sources=sources, path=path, si_sdr=traces, out_png=args.out / f"{name}.png")
    every = max(1, len(views) // 6)
    strip = camera_strip(views[::every], titles=[f"step {k}" for k in range(0, len(views), every)],
                         out_png=args.out / f"{name}_views.png")
    env.close()
    print(f"{episode.episode_id}: {episode.target_category} target vs {episode.source_categories[1:]}, "
          f"{len(path)} observations")
    for label, values in traces.items():
        print(f"  SI-SDR {label}: step 0 {values[0]:.2f} dB -> last {values[-1]:.2f} dB")
    print(top)
    print(strip)
    return 0


if __name__ == "__main__":
    sys.exit(main())
