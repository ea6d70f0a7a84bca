"""Mesh camera render cost on one core: a generated scene's mesh with every surface tessellated to ~240,000
triangles (the density of a scanned room), frames at random lattice poses, beside the exact camera and the
mesh camera on the untessellated mesh (same scene, same poses, same run), and the load.

    python scripts/bench/mesh_camera.py [--size 128] [--max-edge 0.085] [--frames 200] [--repeats 5]
"""

from __future__ import annotations

import os

# One core: numpy's thread pools are sized at import. Embree casts single rays on the calling thread.
for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_name] = "1"

import argparse  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
import trimesh  # noqa: E402

from m2h_ros.core.world.camera import CameraConfig, SceneRenderer  # noqa: E402
from m2h_ros.core.world.mesh_camera import MeshRenderer, scene_mesh  # noqa: E402
from m2h_ros.core.world.navgrid import heading_angle  # noqa: E402
from m2h_ros.core.world.raycast import TriangleMesh  # noqa: E402
from m2h_ros.core.world.scene import load_split  # noqa: E402
from m2h_ros.machine import availability_line, load_average  # noqa: E402


def tessellated(mesh: TriangleMesh, max_edge: float) -> TriangleMesh:
    """The same surfaces split until no edge is longer than ``max_edge`` (colours and parts kept)."""
    vertices, faces, source = trimesh.remesh.subdivide_to_size(mesh.vertices, mesh.faces, max_edge=max_edge,
                                                               max_iter=20, return_index=True)
    return TriangleMesh(vertices, faces, mesh.face_colors[source], mesh.face_part[source], mesh.parts)


def frame_ms(render, poses) -> float:
    """Mean milliseconds per frame over ``poses``."""
    start = time.perf_counter()
    for xy, angle in poses:
        render(xy, angle)
    return 1e3 * (time.perf_counter() - start) / len(poses)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=128, help="width = height, pixels")
    parser.add_argument("--split", default="test", help="scene split")
    parser.add_argument("--index", type=int, default=0, help="scene of the split")
    parser.add_argument("--max-edge", type=float, default=0.085, help="longest triangle edge, metres")
    parser.add_argument("--frames", type=int, default=200, help="frames per repeat")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    config = CameraConfig(width=args.size, height=args.size)
    print(f"load average before: {load_average()}")
    print(availability_line())
    scene = load_split(args.split)[args.index]
    plain = scene_mesh(scene)
    start = time.perf_counter()
    mesh = tessellated(plain, args.max_edge)
    tessellate_s = time.perf_counter() - start
    start = time.perf_counter()
    renderers = {"mesh camera": MeshRenderer(mesh, config), "plain mesh": MeshRenderer(plain, config),
                 "exact camera": SceneRenderer(scene, config)}
    for renderer in renderers.values():
        renderer.render(scene.grid.positions[0], 0.0)              # Embree builds its BVH on the first cast
    build_s = time.perf_counter() - start
    rng = np.random.default_rng(0)
    nodes = rng.integers(scene.grid.n_nodes, size=args.frames)
    poses = [(scene.grid.positions[n], float(heading_angle(h)))
             for n, h in zip(nodes, rng.integers(4, size=args.frames))]
    times: dict[str, list[float]] = {name: [] for name in renderers}
    for _ in range(args.repeats):                                  # interleaved: all see the same load
        for name, renderer in renderers.items():
            times[name].append(frame_ms(renderer.render, poses))
    ratios = np.array(times["mesh camera"]) / np.array(times["exact camera"])
    print(f"scene {scene.scene_id}: {mesh.n_faces} triangles (longest edge {args.max_edge} m, "
          f"tessellated in {tessellate_s:.2f} s; plain mesh {plain.n_faces}), renderers built in {build_s:.2f} s")
    print(f"camera {args.size}x{args.size}, {args.frames} frames at random lattice poses x {args.repeats} repeats, "
          "one thread")
    for name, values in times.items():
        print(f"{name + ':':14s} min {min(values):6.3f}  median {np.median(values):6.3f}  "
              f"max {max(values):6.3f} ms/frame")
    print(f"mesh / exact:  min {ratios.min():.2f}  median {np.median(ratios):.2f}  max {ratios.max():.2f}")
    print(f"load average after: {load_average()}")


if __name__ == "__main__":
    main()
