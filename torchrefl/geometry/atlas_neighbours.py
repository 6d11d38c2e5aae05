"""Neighbours on an atlas: "the texel next to this one" on the surface, within charts and across chart seams.

On a scan's grid the texel next to (row, col) is the texel at (row + dy, col + dx) (core/texel_grid.py). On a
texture atlas that holds inside a chart only: the gutter around a chart is not surface, a chart packed beside
another in UV is not beside it on the object, and the texel across a chart seam (the other side of the shared
3-D edge) sits elsewhere in the atlas, possibly turned or mirrored. AtlasNeighbours answers the same questions as
TexelGrid (`neighbour(texels, dy, dx)`, `pairs()`, `at(rows, cols)`, `rows`, `cols`, `slot`, `grid_shape`) with
these rules:

- one grid step in direction d (right, down, left, up: DIRECTIONS) from texel t reaches the texel in the grid
  cell there when that texel is of t's chart and lies within STEP_REACH times the step's expected 3-D length of
  t; otherwise (the step leaves the chart) it reaches the seam neighbour: the border texel (one that misses a
  within-chart step) nearest to the landing point p_t + J_f (dx, dy) in 3-D (J_f: the 3-D displacement per texel
  step on t's face), within SEAM_REACH step lengths |J_f (dx, dy)| of it and STEP_REACH step lengths of t, not
  of t's own chart within SEAM_SKIP_CELLS grid cells of t, and facing no more than SEAM_MAX_TURN_DEG away from
  t; none: -1 (a mesh boundary);
- a seam step changes the frame: `turn` records the rotation or mirror (a signed permutation of the grid axes)
  that takes t's grid directions to the neighbour's, so a walk keeps its heading across the seam;
- neighbour(t, dy, dx) is the grid cell's texel when it is of t's chart and within STEP_REACH times the offset's
  expected 3-D length; otherwise the end of a walk of |dy| vertical then |dx| horizontal unit steps (turning at
  seams); -1 where the walk leaves the surface.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from torchrefl.core.texel_grid import grid_flat, offset_pairs

# Unit grid steps (dy, dx): right, down, left, up; the column of AtlasNeighbours.step.
DIRECTIONS = ((0, 1), (1, 0), (0, -1), (-1, 0))
# A within-chart step is accepted up to this multiple of its expected 3-D length (J_f times the step).
STEP_REACH = 2.0
# Seam neighbours: within this many unit-step lengths (|J_f step|) of the landing point.
SEAM_REACH = 1.5
# Seam candidates of t's own chart closer than this (grid cells, Chebyshev) to t are not across a seam.
SEAM_SKIP_CELLS = 2
# Surfaces turning by more than this (degrees) across a seam are two sides of a thin sheet, not neighbours.
SEAM_MAX_TURN_DEG = 120.0

# The eight signed permutations of the grid axes (x = column, y = row), as 2x2 integer matrices; index 0 is the
# identity.
_DIHEDRAL = np.array(
    [
        [[1, 0], [0, 1]],
        [[0, -1], [1, 0]],
        [[-1, 0], [0, -1]],
        [[0, 1], [-1, 0]],
        [[-1, 0], [0, 1]],
        [[1, 0], [0, -1]],
        [[0, 1], [1, 0]],
        [[0, -1], [-1, 0]],
    ],
    dtype=np.int64,
)


def _dihedral_code(m: np.ndarray) -> np.ndarray:
    return (m[..., 0, 0] + 1) * 27 + (m[..., 0, 1] + 1) * 9 + (m[..., 1, 0] + 1) * 3 + (m[..., 1, 1] + 1)


_DIHEDRAL_INDEX = np.full(81, -1, dtype=np.int64)
_DIHEDRAL_INDEX[_dihedral_code(_DIHEDRAL)] = np.arange(8)
# _COMPOSE[a, b]: the index of _DIHEDRAL[a] @ _DIHEDRAL[b].
_COMPOSE = _DIHEDRAL_INDEX[_dihedral_code(np.einsum("aij,bjk->abik", _DIHEDRAL, _DIHEDRAL))]
_XY_STEPS = np.array([(dx, dy) for dy, dx in DIRECTIONS], dtype=np.int64)


def _direction_of(xy: np.ndarray) -> np.ndarray:
    """(M,) index into DIRECTIONS of unit xy steps (M, 2)."""
    return np.select([xy[:, 0] == 1, xy[:, 1] == 1, xy[:, 0] == -1], [0, 1, 2], 3)


def face_jacobians(vertices: np.ndarray, faces: np.ndarray, texel_xy: np.ndarray) -> np.ndarray:
    """(F, 3, 2) 3-D displacement per unit step of texel x (column) and y (row) on each face: the face's 3-D
    edges times the inverse of its texel-coordinate edges texel_xy (F, 3, 2); zeros where the UV triangle is
    degenerate."""
    v = np.asarray(vertices, dtype=np.float64)[np.asarray(faces, dtype=np.int64)]
    E = np.stack([v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]], axis=2)  # (F, 3, 2)
    U = np.stack([texel_xy[:, 1] - texel_xy[:, 0], texel_xy[:, 2] - texel_xy[:, 0]], axis=2)  # (F, 2, 2)
    det = U[:, 0, 0] * U[:, 1, 1] - U[:, 0, 1] * U[:, 1, 0]
    ok = np.abs(det) > 1e-12
    inv = np.zeros_like(U)
    inv[ok] = np.linalg.inv(U[ok])
    return E @ inv


def _rotate_onto(vectors: np.ndarray, n_from: np.ndarray, n_to: np.ndarray) -> np.ndarray:
    """vectors (M, 3, k) turned by the smallest rotation taking unit n_from (M, 3) to n_to (M, 3) (Rodrigues);
    unturned where the normals are parallel or opposite."""
    axis = np.cross(n_from, n_to)
    s = np.linalg.norm(axis, axis=1)
    c = np.einsum("mi,mi->m", n_from, n_to)
    k = np.where(s[:, None] > 1e-12, axis / np.maximum(s, 1e-300)[:, None], 0.0)[:, :, None]
    kxv = np.cross(k, vectors, axis=1)
    kdv = np.einsum("mik,mij->mj", k, vectors)[:, None, :]
    ss, cc = np.where(s > 1e-12, s, 0.0)[:, None, None], np.where(s > 1e-12, c, 1.0)[:, None, None]
    return vectors * cc + kxv * ss + k * kdv * (1 - cc)


def _turn(J_from: np.ndarray, J_to: np.ndarray, n_from: np.ndarray, n_to: np.ndarray) -> np.ndarray:
    """(M,) _DIHEDRAL index nearest the map from texel steps on the first faces (J_from (M, 3, 2)) to texel steps on
    the second (J_to), with the second surface unfolded onto the first about their shared edge."""
    A = _rotate_onto(J_to, n_to, n_from)
    gram = np.einsum("mki,mkj->mij", A, A)
    ok = np.abs(np.linalg.det(gram)) > 1e-24
    m = np.zeros((len(A), 2, 2))
    m[ok] = np.linalg.solve(gram[ok], np.einsum("mki,mkj->mij", A[ok], J_from[ok]))
    diagonal = np.abs(m[:, 0, 0]) + np.abs(m[:, 1, 1]) >= np.abs(m[:, 0, 1]) + np.abs(m[:, 1, 0])
    sign = np.where(m >= 0, 1, -1)
    out = np.zeros((len(A), 2, 2), dtype=np.int64)
    out[:, 0, 0] = np.where(diagonal, sign[:, 0, 0], 0)
    out[:, 1, 1] = np.where(diagonal, sign[:, 1, 1], 0)
    out[:, 0, 1] = np.where(diagonal, 0, sign[:, 0, 1])
    out[:, 1, 0] = np.where(diagonal, 0, sign[:, 1, 0])
    return np.where(ok, _DIHEDRAL_INDEX[_dihedral_code(out)], 0)


class AtlasNeighbours:
    """Surface neighbours of T atlas texels (module docstring).

    grid_shape (S, S); index (T,) flat texel index; rows, cols (T,); slot (S S,) texel at each cell, -1 in the
    gutter; chart (T,); step (T, 4) int64 neighbour of each texel in each of DIRECTIONS, -1 where none; turn
    (T, 4) int64 index of the frame change of that step (0: none); step_length (T, 4) expected 3-D length of a
    unit step (|J_f step|); edges (E, 2) int64 every adjacent pair (t < t') once, seams included; region (T,) the
    chart (core/texel_neighbours.TexelNeighbours: a patch block never joins two charts)."""

    def __init__(self, texel_index, grid_shape, chart, positions, normals, jacobians):
        self.grid_shape = (int(grid_shape[0]), int(grid_shape[1]))
        H, W = self.grid_shape
        self.index = np.asarray(texel_index, dtype=np.int64)
        self.rows, self.cols = self.index // W, self.index % W
        self.slot = np.full(H * W, -1, dtype=np.int64)
        self.slot[self.index] = np.arange(len(self.index))
        self.chart = np.asarray(chart, dtype=np.int64)
        self.region = self.chart  # TexelNeighbours: patches never join two charts
        self.positions = np.asarray(positions, dtype=np.float64)
        self.normals = np.asarray(normals, dtype=np.float64)
        self.jacobians = np.asarray(jacobians, dtype=np.float64)  # (T, 3, 2)
        self.step_length = np.linalg.norm(np.einsum("tij,dj->tdi", self.jacobians, _XY_STEPS), axis=2)
        self.step = np.stack([self._within_chart(np.arange(len(self.index)), dy, dx) for dy, dx in DIRECTIONS], 1)
        self.turn = np.zeros_like(self.step)
        self._add_seams()
        e = np.stack([np.repeat(np.arange(len(self.index)), 4), self.step.ravel()], 1)
        e = np.sort(e[e[:, 1] >= 0], axis=1)
        key = np.sort(e[:, 0] * len(self.index) + e[:, 1])
        key = key[np.r_[True, key[1:] != key[:-1]]] if len(key) else key
        self.edges = np.stack(np.divmod(key, len(self.index)), axis=1)
        self.edges = self.edges[self.edges[:, 0] != self.edges[:, 1]]

    @property
    def num_texels(self) -> int:
        return int(len(self.index))

    def at(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """(M,) int64 texel in grid cells (rows, cols) (M,), -1 outside the grid or in the gutter. A raw cell
        lookup: it does not cross seams and does not check charts (use neighbour for that)."""
        cell = grid_flat(rows, cols, self.grid_shape)
        return np.where(cell >= 0, np.take(self.slot, np.maximum(cell, 0)), -1)

    def _within_chart(self, texels: np.ndarray, dy: int, dx: int) -> np.ndarray:
        """The grid cell's texel at (dy, dx) from texels when it is of their chart and within STEP_REACH times
        the offset's expected 3-D length, else -1."""
        other = self.at(np.take(self.rows, texels) + dy, np.take(self.cols, texels) + dx)
        o = np.maximum(other, 0)
        expected = np.linalg.norm(self.jacobians[texels] @ np.array([dx, dy], dtype=np.float64), axis=1)
        dist = np.linalg.norm(self.positions[o] - self.positions[texels], axis=1)
        ok = (other >= 0) & (self.chart[o] == self.chart[texels]) & (dist <= STEP_REACH * expected)
        return np.where(ok, other, -1)

    def _add_seams(self) -> None:
        """Fill the steps that leave a chart with seam neighbours (module docstring)."""
        border = np.flatnonzero((self.step < 0).any(axis=1))
        if not len(border):
            return
        tree = cKDTree(self.positions[border])
        t, d = np.nonzero(self.step < 0)
        landing = self.positions[t] + np.einsum("mij,mj->mi", self.jacobians[t], _XY_STEPS[d])
        size = np.maximum(self.step_length[t, d], 1e-300)
        k = min(8, len(border))
        dist, hit = tree.query(landing, k=k, distance_upper_bound=SEAM_REACH * float(size.max()))
        dist, hit = dist.reshape(len(t), k), hit.reshape(len(t), k)
        cand = np.where(hit < len(border), border[np.minimum(hit, len(border) - 1)], -1)
        c = np.maximum(cand, 0)
        near_in_chart = (self.chart[c] == self.chart[t][:, None]) & (
            np.maximum(np.abs(self.rows[c] - self.rows[t][:, None]), np.abs(self.cols[c] - self.cols[t][:, None]))
            <= SEAM_SKIP_CELLS
        )
        facing = np.einsum("mi,mki->mk", self.normals[t], self.normals[c]) > np.cos(np.radians(SEAM_MAX_TURN_DEG))
        apart = np.linalg.norm(self.positions[c] - self.positions[t][:, None], axis=2)
        ok = (cand >= 0) & ~near_in_chart & facing & (dist <= SEAM_REACH * size[:, None])
        ok &= apart <= STEP_REACH * size[:, None]
        first = np.argmax(ok, axis=1)
        found = ok[np.arange(len(t)), first]
        t, d, other = t[found], d[found], cand[found, first[found]]
        self.step[t, d] = other
        self.turn[t, d] = _turn(self.jacobians[t], self.jacobians[other], self.normals[t], self.normals[other])

    def neighbour(self, texels: np.ndarray, dy: int, dx: int) -> np.ndarray:
        """(M,) int64 texel dy rows and dx columns away from each of texels (M,) on the surface, -1 where there is
        none (module docstring: the grid cell within the chart, else a walk across seams)."""
        texels = np.asarray(texels, dtype=np.int64)
        if dy == 0 and dx == 0:
            return texels.copy()
        direct = self._within_chart(texels, dy, dx)
        todo = np.flatnonzero(direct < 0)
        if len(todo):
            direct[todo] = self._walk(texels[todo], dy, dx)
        return direct

    def _walk(self, texels: np.ndarray, dy: int, dx: int) -> np.ndarray:
        cur = texels.copy()
        frame = np.zeros(len(cur), dtype=np.int64)
        unit = [(0, int(np.sign(dy)))] * abs(dy) + [(int(np.sign(dx)), 0)] * abs(dx)  # xy steps
        for xy in unit:
            alive = np.flatnonzero(cur >= 0)
            local = _DIHEDRAL[frame[alive]] @ np.array(xy, dtype=np.int64)
            d = _direction_of(local)
            nxt = self.step[cur[alive], d]
            frame[alive] = _COMPOSE[self.turn[cur[alive], d], frame[alive]]
            cur[alive] = nxt
        return cur

    def pairs(self, offsets=((0, 1), (1, 0))) -> np.ndarray:
        """(E, 2) int64 pairs of neighbouring texels. Default offsets (right and down, TexelGrid's every adjacent
        pair once): `edges`, every 4-neighbour pair once (t < t'), seam pairs included. Other offsets: (t,
        neighbour(t, dy, dx)) for each offset in turn, texels in order, where the neighbour exists."""
        if tuple(map(tuple, offsets)) == ((0, 1), (1, 0)):
            return self.edges
        return offset_pairs(self, self.num_texels, offsets)
