"""Navigation lattice: one node per free lattice cell, 4 headings, MoveForward transitions, geodesics.

Generated scenes use 1 m cells from the origin (Move2Hear's Matterport grid); an imported world lays
the lattice at its own spacing (1 m by default, 0.5 m as Replica's) from its own corner, so a node sits
at ``origin + (cell + 0.5) * spacing`` and geodesics are in metres either way.

Headings: h in {0, 1, 2, 3} faces h * 90 degrees counter-clockwise from +x (0: +x, 1: +y, 2: -x,
3: -y). TurnLeft is (h + 1) % 4, TurnRight is (h - 1) % 4.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components, shortest_path

N_HEADINGS = 4
# Cell offset of one MoveForward step for each heading.
HEADING_STEPS = np.array([[1, 0], [0, 1], [-1, 0], [0, -1]], dtype=np.int64)
HEADING_STEPS.setflags(write=False)


def heading_angle(heading: int | np.ndarray) -> float | np.ndarray:
    """Facing angle in radians (counter-clockwise from +x) of heading index ``heading``."""
    return np.asarray(heading) * (np.pi / 2)


def heading_index(yaw: float) -> int:
    """The heading index nearest to a facing angle (radians, counter-clockwise from +x)."""
    return int(np.round(yaw / (np.pi / 2))) % N_HEADINGS


def turn_left(heading: int | np.ndarray) -> int | np.ndarray:
    return (heading + 1) % N_HEADINGS


def turn_right(heading: int | np.ndarray) -> int | np.ndarray:
    return (heading - 1) % N_HEADINGS


class NavGrid:
    """Nodes at the centres of free cells; ``forward[n, h]`` is the node reached by MoveForward.

    ``can_cross(cell_a, cell_b)`` says whether a move between two 4-adjacent free cells is open (no
    wall between them, or a door). Moves into cells without a node (obstacles, outside) are blocked.
    """

    def __init__(self, cells: np.ndarray, room_of: np.ndarray,
                 can_cross: Callable[[tuple[int, int], tuple[int, int]], bool], *,
                 spacing: float = 1.0, origin: tuple[float, float] = (0.0, 0.0)) -> None:
        cells = np.asarray(cells, dtype=np.int64).reshape(-1, 2)
        self.spacing, self.origin = float(spacing), (float(origin[0]), float(origin[1]))
        self.cells = _readonly(cells)                                   # (N, 2) int cell (ix, iy)
        positions = cells.astype(np.float64) + 0.5
        if self.spacing != 1.0 or self.origin != (0.0, 0.0):
            positions = np.asarray(self.origin) + positions * self.spacing
        self.positions = _readonly(positions)                           # (N, 2) metres
        self.room_of = _readonly(np.asarray(room_of, dtype=np.int64))   # (N,)
        self._node_of_cell = {(int(x), int(y)): n for n, (x, y) in enumerate(cells)}
        forward = np.repeat(np.arange(len(cells))[:, None], N_HEADINGS, axis=1)
        for n, cell in enumerate(self._node_of_cell):
            for h, (dx, dy) in enumerate(HEADING_STEPS):
                target = (cell[0] + int(dx), cell[1] + int(dy))
                m = self._node_of_cell.get(target)
                if m is not None and can_cross(cell, target):
                    forward[n, h] = m
        self.forward = _readonly(forward)                               # (N, 4) int
        adjacency = self._adjacency()
        self.n_components = int(connected_components(adjacency, directed=False)[0])
        # Unweighted shortest paths = BFS; every edge is one spacing long.
        hops = shortest_path(adjacency, unweighted=True, directed=False)
        self.geodesic = _readonly((hops * self.spacing if self.spacing != 1.0 else hops).astype(np.float32))

    @property
    def n_nodes(self) -> int:
        return len(self.cells)

    def node_at_cell(self, ix: int, iy: int) -> int:
        """Node index of cell (ix, iy), or -1 where that cell has no node."""
        return self._node_of_cell.get((int(ix), int(iy)), -1)

    def nearest_node(self, xy) -> int | np.ndarray:
        """Index of the node nearest to ``xy`` (shape (2,) -> int, shape (M, 2) -> (M,) array)."""
        points = np.asarray(xy, dtype=np.float64)
        d2 = ((points[..., None, :] - self.positions) ** 2).sum(-1)
        nearest = d2.argmin(-1)
        return int(nearest) if points.ndim == 1 else nearest

    def shortest_path(self, start: int, goal: int) -> list[int]:
        """Nodes of one shortest path from ``start`` to ``goal`` (both included)."""
        path = [int(start)]
        while path[-1] != goal:
            options = self.forward[path[-1]]
            path.append(int(options[np.argmin(self.geodesic[options, goal])]))
        return path

    def _adjacency(self) -> csr_matrix:
        n = self.n_nodes
        src = np.repeat(np.arange(n), N_HEADINGS)
        dst = self.forward.ravel()
        moved = src != dst
        return csr_matrix((np.ones(int(moved.sum())), (src[moved], dst[moved])), shape=(n, n))


def _readonly(array: np.ndarray) -> np.ndarray:
    array.setflags(write=False)
    return array
