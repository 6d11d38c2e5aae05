"""Triangle meshes and texel areas from a grid of 3-D points (a range image)."""

from __future__ import annotations

import numpy as np

from torchrefl.errors import GeometryError


def grid_triangulation(
    points: np.ndarray, valid: np.ndarray, wrap: bool = False, max_edge_ratio: float = 6.0
) -> tuple[np.ndarray, np.ndarray]:
    """Two triangles per grid quad whose four corners are valid.

    points: (H, W, 3) float; valid: (H, W) bool. Quads spanning a depth discontinuity
    (an edge longer than max_edge_ratio times the median edge length) are left out.
    wrap=True also joins the last column to the first (a full turn).
    Returns vertices (H*W, 3) float64 (invalid grid points set to 0, unused) and faces (F, 3) int64.
    """
    H, W = valid.shape
    verts = np.where(valid[..., None], points, 0.0).reshape(-1, 3).astype(np.float64)
    cols = np.arange(W if wrap else W - 1)
    rows = np.arange(H - 1)
    R, C = np.meshgrid(rows, cols, indexing="ij")
    C1 = (C + 1) % W
    a = R * W + C
    b = R * W + C1
    c = (R + 1) * W + C
    d = (R + 1) * W + C1
    vflat = valid.ravel()
    ok = vflat[a] & vflat[b] & vflat[c] & vflat[d]
    a, b, c, d = a[ok], b[ok], c[ok], d[ok]
    if a.size == 0:
        return verts, np.zeros((0, 3), dtype=np.int64)
    edges = np.stack(
        [
            np.linalg.norm(verts[a] - verts[b], axis=-1),
            np.linalg.norm(verts[a] - verts[c], axis=-1),
            np.linalg.norm(verts[d] - verts[b], axis=-1),
            np.linalg.norm(verts[d] - verts[c], axis=-1),
            np.linalg.norm(verts[a] - verts[d], axis=-1) / np.sqrt(2.0),
        ]
    )
    scale = np.median(edges[:4])
    keep = edges.max(axis=0) <= max_edge_ratio * max(scale, 1e-12)
    a, b, c, d = a[keep], b[keep], c[keep], d[keep]
    faces = np.concatenate([np.stack([a, c, b], -1), np.stack([b, c, d], -1)])
    return verts, faces.astype(np.int64)


def texel_areas(points: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """(H, W) area of each texel, |dS/drow x dS/dcol| from central differences (one-sided at borders).

    Texels whose neighbours are invalid use the valid side; isolated texels get the median area.
    """
    p = np.where(valid[..., None], points, np.nan)
    d_row = np.gradient(p, axis=0)
    d_col = np.gradient(p, axis=1)
    area = np.linalg.norm(np.cross(d_row, d_col), axis=-1)
    good = np.isfinite(area) & valid
    fill = float(np.median(area[good])) if good.any() else 1.0
    return np.where(good, area, np.where(valid, fill, 0.0))


def boundary_texels(
    faces: np.ndarray, grid_shape: tuple[int, int], texel_index: np.ndarray, width: int = 1
) -> np.ndarray:
    """(T,) bool: texels within `width` texels of the triangulated surface's boundary (the silhouette,
    holes, depth discontinuities that grid_triangulation left open).

    A grid vertex with all four quads around it triangulated belongs to six triangles; fewer means
    its footprint straddles an edge, where a texel's colour mixes surfaces (a "mixed pixel").
    width = 0: none.
    """
    T = len(texel_index)
    if width <= 0:
        return np.zeros(T, dtype=bool)
    H, W = grid_shape
    count = np.bincount(np.asarray(faces, dtype=np.int64).ravel(), minlength=H * W)
    edge = np.zeros(H * W, dtype=bool)
    edge[texel_index] = count[texel_index] < 6
    if width > 1:
        from scipy.ndimage import binary_dilation

        edge = binary_dilation(edge.reshape(H, W), iterations=width - 1).ravel()
    return edge[texel_index]


def oriented_face_normals(vertices: np.ndarray, faces: np.ndarray, corner_normals: np.ndarray) -> np.ndarray:
    """(F, 3) unit geometric normals of the faces (F, 3) of vertices (V, 3), each turned to the side that the sum
    of its corners' normals corner_normals (F, 3, 3) points to (zeros for a corner without one): the grid's
    winding may face either way. A face whose corners' normals sum perpendicular to it keeps its winding's
    normal; a degenerate face gets zeros."""
    v = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if not len(faces):
        return np.zeros((0, 3))
    fn = np.cross(v[faces[:, 1]] - v[faces[:, 0]], v[faces[:, 2]] - v[faces[:, 0]])
    fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-300)
    side = np.einsum("fi,fi->f", fn, np.asarray(corner_normals, dtype=np.float64).sum(1))
    return fn * np.where(side < 0, -1.0, 1.0)[:, None]


def crease_texels(
    vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray, texel_index: np.ndarray, angle_deg: float | None
) -> np.ndarray:
    """(T,) bool: texels on a crease, whose footprint spans two faces of the object (mixed pixels, like those at
    boundary_texels' edges): some mesh face around the texel's grid point is more than angle_deg from the
    texel's normal. On a 90-degree fold the texels whose grid point lies on the fold line meet faces of both
    sides (85-93 degrees); their neighbours half a texel or more away meet only the faces that bridge the fold
    (about 45 degrees). vertices (V, 3), faces (F, 3): the texel grid's triangulation (grid point v is
    vertex v); normals (T, 3) unit; texel_index (T,) grid point of each texel; angle_deg None: none.
    """
    T = len(texel_index)
    if angle_deg is None:
        return np.zeros(T, dtype=bool)
    if not 0.0 < float(angle_deg) < 180.0:
        raise GeometryError(
            f"argument 'angle_deg' (geometry.crease_angle_deg): expected degrees in (0, 180), got {angle_deg!r}"
        )
    faces = np.asarray(faces, dtype=np.int64)
    if not faces.size:
        return np.zeros(T, dtype=bool)
    slot = np.full(len(vertices), -1, dtype=np.int64)
    slot[np.asarray(texel_index, dtype=np.int64)] = np.arange(T)
    v = np.asarray(vertices, dtype=np.float64)
    n = np.asarray(normals, dtype=np.float64)
    corner = slot[faces]  # (F, 3) texel of each corner, -1 if none
    fn = oriented_face_normals(v, faces, np.where(corner[..., None] >= 0, n[np.maximum(corner, 0)], 0.0))
    worst = np.ones(T)
    for c in range(3):
        t = corner[:, c]
        ok = t >= 0
        np.minimum.at(worst, t[ok], np.einsum("fi,fi->f", fn[ok], n[t[ok]]))
    return worst < np.cos(np.radians(float(angle_deg)))
