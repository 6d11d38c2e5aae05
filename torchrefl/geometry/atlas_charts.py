"""Charts of a UV atlas: the groups of faces joined by edges that are continuous in both 3-D and UV."""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from torchrefl.geometry.mesh_file import MeshData
from torchrefl.geometry.mesh_normals import row_ids, welded_vertices

# UVs equal to 1 / UV_CODE (far below a texel) are the same UV.
UV_CODE = float(1 << 30)


def face_charts(mesh: MeshData) -> np.ndarray:
    """(F,) int64 chart of each face, numbered 0.. in order of each chart's first face. Two faces are in one chart
    when they share an edge whose two ends are at the same 3-D positions (vertices at one position are one) with
    the same UVs on both faces; an edge whose UVs differ between its faces is a seam."""
    faces = np.asarray(mesh.faces, dtype=np.int64)
    F = len(faces)
    if mesh.uvs is None or F == 0:
        return np.zeros(F, dtype=np.int64)
    weld = welded_vertices(mesh.vertices)[faces]  # (F, 3)
    a, b = weld, np.roll(weld, -1, axis=1)
    ua, ub = mesh.uvs, np.roll(mesh.uvs, -1, axis=1)
    swap = a > b
    lo, hi = np.where(swap, b, a), np.where(swap, a, b)
    ulo, uhi = np.where(swap[..., None], ub, ua), np.where(swap[..., None], ua, ub)
    code = np.round(np.stack([ulo, uhi]) * UV_CODE).astype(np.int64)  # (2, F, 3, 2) exact for file UVs
    face = np.repeat(np.arange(F), 3)
    proper = (lo != hi).reshape(-1)
    group = row_ids(
        *(c.reshape(-1)[proper] for c in (lo, hi, code[0, ..., 0], code[0, ..., 1], code[1, ..., 0], code[1, ..., 1]))
    )
    face = face[proper]
    order = np.argsort(group, kind="stable")
    g, f = group[order], face[order]
    same = np.flatnonzero(g[1:] == g[:-1])
    graph = coo_matrix((np.ones(len(same)), (f[same], f[same + 1])), shape=(F, F))
    _, labels = connected_components(graph, directed=False)
    _, first = np.unique(labels, return_index=True)
    renumber = np.empty(len(first), dtype=np.int64)
    renumber[labels[np.sort(first)]] = np.arange(len(first))
    return renumber[labels]
