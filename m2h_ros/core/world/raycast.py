"""Triangle meshes and ray casting against them (Intel Embree through ``embreex``).

What the world's camera, the mesh importer's floor search and the material lookup of imported walls
cast their rays with. Embree builds its BVH once per mesh (about 0.1 s for 300,000 triangles) and then
answers a 128 x 128 image's rays in about 1-5 ms on one core.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from m2h_ros.errors import ConfigError


@dataclass(frozen=True, eq=False)
class TriangleMesh:
    """Triangles in the world frame (metres, z up) with a colour and a part index per triangle.

    ``parts`` names the mesh parts (a glTF node or material, an OBJ group); ``face_part[i]`` is the
    index of triangle i's part, which a material mapping turns into an acoustic material.
    """
    vertices: np.ndarray                 # (V, 3) float64
    faces: np.ndarray                    # (F, 3) int64 vertex indices
    face_colors: np.ndarray              # (F, 3) float32 RGB in [0, 1]
    face_part: np.ndarray | None = None  # (F,) int64 index into ``parts``
    parts: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        vertices = np.asarray(self.vertices, np.float64)
        faces = np.asarray(self.faces, np.int64)
        if vertices.ndim != 2 or vertices.shape[1] != 3 or faces.ndim != 2 or faces.shape[1] != 3:
            raise ConfigError(f"a triangle mesh needs (V, 3) vertices and (F, 3) faces, got "
                              f"{vertices.shape} and {faces.shape}")
        if len(faces) and (faces.min() < 0 or faces.max() >= len(vertices)):
            raise ConfigError("a triangle mesh's faces index vertices it does not have")
        colors = np.asarray(self.face_colors, np.float32)
        if colors.shape != (len(faces), 3):
            raise ConfigError(f"face_colors must be ({len(faces)}, 3), got {colors.shape}")
        part = np.zeros(len(faces), np.int64) if self.face_part is None else np.asarray(self.face_part, np.int64)
        if part.shape != (len(faces),):
            raise ConfigError(f"face_part must be ({len(faces)},), got {part.shape}")
        for name, value in (("vertices", vertices), ("faces", faces), ("face_colors", colors), ("face_part", part)):
            value.setflags(write=False)
            object.__setattr__(self, name, value)

    @property
    def n_faces(self) -> int:
        return len(self.faces)

    @cached_property
    def triangles(self) -> np.ndarray:
        """(F, 3, 3) float32 corner coordinates."""
        return self.vertices[self.faces].astype(np.float32)

    @cached_property
    def normals(self) -> np.ndarray:
        """(F, 3) unit normals by the right-hand rule of each triangle's corner order."""
        tri = self.vertices[self.faces]
        normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        length = np.linalg.norm(normal, axis=1, keepdims=True)
        return (normal / np.where(length > 0, length, 1.0)).astype(np.float32)

    @cached_property
    def bounds(self) -> np.ndarray:
        """(2, 3) lowest and highest corner."""
        return np.stack([self.vertices.min(axis=0), self.vertices.max(axis=0)])


class RayCaster:
    """Nearest hits of rays on one mesh. Build once per mesh; ``cast`` is thread-compatible per instance."""

    def __init__(self, mesh: TriangleMesh) -> None:
        try:
            from embreex import rtcore_scene
            from embreex.mesh_construction import TriangleMesh as EmbreeMesh
        except ImportError as err:  # pragma: no cover - a pinned dependency
            raise ConfigError("ray casting needs the 'embreex' package (scripts/setup.sh installs it)") from err
        if mesh.n_faces == 0:
            raise ConfigError("cannot cast rays on a mesh without triangles")
        self.mesh = mesh
        self._scene = rtcore_scene.EmbreeScene()
        EmbreeMesh(self._scene, mesh.triangles)

    def cast(self, origins, directions) -> tuple[np.ndarray, np.ndarray]:
        """Distance along each ray (in units of its direction's length; inf = no hit) and the index of
        the triangle hit (-1 = none), for (R, 3) origins and directions (or one origin for all)."""
        directions = np.ascontiguousarray(np.asarray(directions, np.float32).reshape(-1, 3))
        origins = np.asarray(origins, np.float32).reshape(-1, 3)
        if len(origins) == 1 and len(directions) != 1:
            origins = np.broadcast_to(origins, directions.shape)
        origins = np.ascontiguousarray(origins)
        if origins.shape != directions.shape:
            raise ConfigError(f"origins {origins.shape} and directions {directions.shape} differ in shape")
        result = self._scene.run(origins, directions, output=1)
        face = np.asarray(result["primID"], np.int64)
        hit = np.asarray(result["geomID"]) >= 0
        face = np.where(hit, face, -1)
        distance = np.where(hit, np.asarray(result["tfar"], np.float64), np.inf)
        return distance, face
