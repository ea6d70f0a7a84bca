"""Export a generated scene as a triangle mesh (glb, obj or ply, by the suffix of --out) in the camera's colours.

    python scripts/export_scene_mesh.py --split test --index 0 --out scene.glb
    python scripts/export_scene_mesh.py --split test --index 0 --yaw 30 --out turned.glb   # walls off the axes

Coordinates are metres; glb is y-up as glTF specifies (the scene's z is glTF's y), obj and ply keep z up.

glb and obj hold one node (obj: one object and group) per part, named as the part ("wall:brickwork",
"floor:carpet_thin", ...), with the face colours as vertex colours (each quad has vertices of its own, so
nothing blends). ply holds one mesh with face colours and each face's part index as the face property
"part" (ply cannot name groups; the names are listed on stdout in index order).
"""

from __future__ import annotations

import argparse
import os
import re
import sys
from pathlib import Path

import numpy as np
import trimesh

from m2h_ros.core.world.mesh_camera import scene_mesh
from m2h_ros.core.world.raycast import TriangleMesh
from m2h_ros.core.world.scene import PRESETS, SCENE_SPLITS, load_split
from m2h_ros.errors import reports_errors

FORMATS = ("glb", "obj", "ply")


def part_scene(mesh: TriangleMesh) -> trimesh.Scene:
    """One trimesh geometry and node per part, named as the part, with RGBA face colours."""
    rgba = _rgba(mesh.face_colors)
    scene = trimesh.Scene()
    for index, name in enumerate(mesh.parts):
        faces = np.nonzero(mesh.face_part == index)[0]
        used, corners = np.unique(mesh.faces[faces], return_inverse=True)
        part = trimesh.Trimesh(vertices=mesh.vertices[used], faces=corners.reshape(-1, 3),
                               face_colors=rgba[faces], process=False, metadata={"name": name})
        scene.add_geometry(part, node_name=name, geom_name=name)
    return scene


def single_mesh(mesh: TriangleMesh) -> trimesh.Trimesh:
    """The whole mesh as one trimesh with RGBA face colours and the part index as a face attribute."""
    return trimesh.Trimesh(vertices=mesh.vertices, faces=mesh.faces, face_colors=_rgba(mesh.face_colors),
                           face_attributes={"part": mesh.face_part.astype(np.int32)}, process=False)


def turned(mesh: TriangleMesh, yaw_deg: float) -> TriangleMesh:
    """The mesh turned by ``yaw_deg`` about the vertical through the origin."""
    c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
    vertices = mesh.vertices @ np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    return TriangleMesh(vertices, mesh.faces, mesh.face_colors, mesh.face_part, mesh.parts)


def export_bytes(mesh: TriangleMesh, file_type: str) -> bytes:
    """The mesh encoded as ``file_type`` (one of FORMATS); glb turned to glTF's y-up."""
    if file_type == "glb":  # z-up (x, y, z) is glTF's (x, z, -y)
        vertices = mesh.vertices[:, [0, 2, 1]] * [1.0, 1.0, -1.0]
        mesh = TriangleMesh(vertices, mesh.faces, mesh.face_colors, mesh.face_part, mesh.parts)
    data = (single_mesh(mesh) if file_type == "ply" else part_scene(mesh)).export(file_type=file_type)
    if file_type == "obj":   # trimesh names objects ("o"); readers that split by group ("g") get the names too
        data = re.sub(r"^o (.*)$", r"o \1\ng \1", data, flags=re.MULTILINE)
    return data.encode() if isinstance(data, str) else data


def _rgba(colors: np.ndarray) -> np.ndarray:
    rgb = np.round(np.clip(colors, 0.0, 1.0) * 255.0).astype(np.uint8)
    return np.column_stack([rgb, np.full(len(rgb), 255, np.uint8)])


@reports_errors("export_scene_mesh")
def main(argv: list[str] | None = None) -> int | None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--split", choices=sorted(SCENE_SPLITS), default="test")
    parser.add_argument("--index", type=int, default=0)
    parser.add_argument("--preset", choices=sorted(PRESETS), default="default")
    parser.add_argument("--yaw", type=float, default=0.0, help="turn the scene by this many degrees about z")
    parser.add_argument("--out", type=Path, required=True, help="file to write: .glb, .obj or .ply")
    args = parser.parse_args(argv)

    file_type = args.out.suffix.lower().lstrip(".")
    if file_type not in FORMATS:
        parser.error(f"--out {args.out} must end in one of {', '.join('.' + f for f in FORMATS)}")
    scenes = load_split(args.split, preset=args.preset)
    if not 0 <= args.index < len(scenes):
        parser.error(f"--index must be in [0, {len(scenes)}) for split {args.split}")
    scene = scenes[args.index]
    mesh = turned(scene_mesh(scene), args.yaw) if args.yaw else scene_mesh(scene)
    data = export_bytes(mesh, file_type)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.out.with_name(f".{args.out.name}.{os.getpid()}.tmp")   # renamed whole: never half a file
    tmp.write_bytes(data)
    os.replace(tmp, args.out)
    print(f"{scene.scene_id}: {mesh.n_faces} triangles in {len(mesh.parts)} parts -> {args.out}")
    for index, name in enumerate(mesh.parts):
        print(f"  part {index}: {name}")


if __name__ == "__main__":
    sys.exit(main())
