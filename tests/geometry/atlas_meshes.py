"""Meshes with known UV atlases for the atlas tests (built here from their definitions, not by the code under test)."""

import numpy as np

from torchrefl.geometry.mesh_file import MeshData

# The six faces of the cube [0, L]^3: outward normal n and in-face axes a, b with a x b = n.
CUBE_FACES = [
    ((1, 0, 0), (0, 1, 0), (0, 0, 1)),
    ((-1, 0, 0), (0, 0, 1), (0, 1, 0)),
    ((0, 1, 0), (0, 0, 1), (1, 0, 0)),
    ((0, -1, 0), (1, 0, 0), (0, 0, 1)),
    ((0, 0, 1), (1, 0, 0), (0, 1, 0)),
    ((0, 0, -1), (0, 1, 0), (1, 0, 0)),
]
# Each face's chart orientation in the atlas: (quarter turns, mirrored), so seams turn and mirror the grid.
CUBE_ORIENTATIONS = [(0, False), (1, False), (2, False), (3, True), (0, True), (1, True)]


def cube_atlas(side_texels: int = 16, texture_size: int = 64, gap: int = 4, texel_mm: float = 1.0) -> MeshData:
    """A cube of side side_texels * texel_mm mm, each face a chart of exactly side_texels x side_texels texels
    (aligned with the texel grid) in a 3 x 2 layout with `gap` gutter texels, turned and mirrored per face."""
    L = side_texels * texel_mm
    verts, faces, uvs = [], [], []
    st = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=np.float64)
    for k, (n, a, b) in enumerate(CUBE_FACES):
        n, a, b = (np.array(x, dtype=np.float64) for x in (n, a, b))
        centre = np.full(3, L / 2) + n * L / 2
        corners = centre + (st[:, :1] - 0.5) * a * L + (st[:, 1:] - 0.5) * b * L
        turns, mirror = CUBE_ORIENTATIONS[k]
        local = st.copy()
        for _ in range(turns):
            local = np.stack([1 - local[:, 1], local[:, 0]], axis=1)
        if mirror:
            local[:, 0] = 1 - local[:, 0]
        col0, row0 = gap + (k % 3) * (side_texels + gap), gap + (k // 3) * (side_texels + gap)
        x = col0 + side_texels * local[:, 0]
        y = row0 + side_texels * (1 - local[:, 1])
        uv = np.stack([x / texture_size, 1 - y / texture_size], axis=1)
        base = 4 * k
        verts.append(corners)
        for tri in ((0, 1, 2), (0, 2, 3)):
            faces.append([base + i for i in tri])
            uvs.append(uv[list(tri)])
    return MeshData(np.concatenate(verts), np.array(faces, dtype=np.int64), np.array(uvs), source="cube")


def latlong_grid(n_rows: int, n_cols: int, point) -> MeshData:
    """A grid mesh with uv = (j / n_cols, 1 - i / n_rows) at grid vertex (i, j), placed at point(i / n_rows,
    j / n_cols) -> (3,); the last column is a separate copy of the first (a UV seam)."""
    i, j = np.meshgrid(np.arange(n_rows + 1), np.arange(n_cols + 1), indexing="ij")
    v = np.array([point(a, b) for a, b in zip((i / n_rows).ravel(), (j / n_cols).ravel())], dtype=np.float64)
    uv = np.stack([(j / n_cols).ravel(), 1 - (i / n_rows).ravel()], -1)
    a = (i[:-1, :-1] * (n_cols + 1) + j[:-1, :-1]).ravel()
    f = np.concatenate([np.stack([a, a + n_cols + 1, a + 1], 1), np.stack([a + 1, a + n_cols + 1, a + n_cols + 2], 1)])
    return MeshData(v, f, uv[f], source="latlong")


def uv_sphere(radius: float, n_rows: int = 48, n_cols: int = 96) -> MeshData:
    """A sphere with latitude-longitude UVs (outward winding)."""

    def point(s, t):
        th, ph = np.pi * s, 2 * np.pi * t
        return radius * np.array([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)])

    return latlong_grid(n_rows, n_cols, point)


def open_cylinder(radius: float, height: float, n_rows: int = 8, n_cols: int = 96) -> MeshData:
    """The side of a cylinder about z (no caps), u around, v along z (outward winding)."""

    def point(s, t):
        ph = 2 * np.pi * t
        return np.array([radius * np.cos(ph), radius * np.sin(ph), height * (1 - s)])

    return latlong_grid(n_rows, n_cols, point)
