"""Save a top-down picture of a scene and a few camera views (RGB + depth) as PNGs.

    python scripts/view_scene.py --split test --index 0 --out /tmp/scene_view
    python scripts/view_scene.py --world map:PATH/map.yaml --out /tmp/my_building
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from m2h_ros.core.world.camera import CameraConfig, CameraViews
from m2h_ros.core.world.scene import PRESETS, SCENE_SPLITS, load_split
from m2h_ros.core.world.viewer import camera_strip, plot_episode, save_camera_views
from m2h_ros.core.world.worlds import load_world_with_report
from m2h_ros.errors import reports_errors


@reports_errors("view_scene")
def main(argv: list[str] | None = None) -> int | None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--split", choices=sorted(SCENE_SPLITS), default="test")
    parser.add_argument("--index", type=int, default=0)
    parser.add_argument("--preset", choices=sorted(PRESETS), default="default")
    parser.add_argument("--world", default="", metavar="SPEC",
                        help="an imported world instead: map:PATH/map.yaml or mesh:PATH (glb, gltf, obj, ply)")
    parser.add_argument("--size", type=int, default=128, help="camera width = height, pixels")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)

    if args.world:
        scene, report = load_world_with_report(args.world)
        print(f"{scene.scene_id}: {report.describe()}")
        scenes, args.index = [scene], 0
    else:
        scenes = load_split(args.split, preset=args.preset)
    if not 0 <= args.index < len(scenes):
        parser.error(f"--index must be in [0, {len(scenes)}) for split {args.split}")
    scene = scenes[args.index]
    grid = scene.grid
    # Demo path: a shortest path between the two farthest nodes, facing along each move.
    start, goal = np.unravel_index(np.argmax(grid.geodesic), grid.geodesic.shape)
    nodes = grid.shortest_path(int(start), int(goal))
    headings = [int(np.argmax(grid.forward[a] == b)) for a, b in zip(nodes, nodes[1:])]
    path = list(zip(nodes, headings + headings[-1:]))
    sources = [(grid.positions[goal], "speech", "target"), (grid.positions[nodes[len(nodes) // 2]],
                                                             "music", "distractor")]
    top = plot_episode(scene, sources=sources, path=path, out_png=args.out / f"{scene.scene_id}_top.png")

    views = CameraViews(scene, CameraConfig(width=args.size, height=args.size))
    poses = [(int(start), h) for h in range(4)] + path[1:len(path):max(1, len(path) // 4)]
    named = {f"{scene.scene_id}_n{n:02d}_h{h}": views.view(n, h) for n, h in poses}
    files = save_camera_views(named, args.out, max_depth=views.config.max_depth)
    strip = camera_strip(list(named.values()), titles=[k.split("_", 2)[2] for k in named],
                         max_depth=views.config.max_depth,
                         out_png=args.out / f"{scene.scene_id}_views.png")
    print(f"{scene.scene_id}: {len(scene.rooms)} rooms, {grid.n_nodes} nodes, "
          f"fingerprint {scene.fingerprint()}")
    for path_out in [top, strip, *files]:
        print(path_out)


if __name__ == "__main__":
    sys.exit(main())
