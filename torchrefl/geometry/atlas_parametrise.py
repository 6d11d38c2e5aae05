"""A texture atlas for a mesh given without UVs, made by xatlas (charts cut, flattened and packed)."""

from __future__ import annotations

import numpy as np

from torchrefl.errors import GeometryError
from torchrefl.geometry.mesh_file import MeshData

# Gutter between packed charts, in texels of xatlas' own packing (at least this times the final scale, below).
ATLAS_PADDING_TEXELS = 3


def parametrise(mesh: MeshData, texture_size: int) -> MeshData:
    """mesh with a new atlas: xatlas cuts it into charts and packs them for a texture_size x texture_size texture.

    Returns the parametrised mesh (xatlas splits vertices along chart seams, so vertices and faces are new; the
    faces keep their order and each new vertex sits where its source vertex was) with uvs (F, 3, 2) in [0, 1].
    xatlas sizes its atlas to its own estimate of the texel density, which can exceed texture_size: the UVs are
    scaled uniformly so the atlas fits (square texels kept). The same input gives the same atlas."""
    import xatlas

    if texture_size < 8:
        raise GeometryError(f"mesh {mesh.source}: texture_size must be at least 8 texels, got {texture_size}")
    atlas = xatlas.Atlas()
    atlas.add_mesh(np.ascontiguousarray(mesh.vertices, dtype=np.float32), np.ascontiguousarray(mesh.faces, np.uint32))
    pack = xatlas.PackOptions()
    pack.resolution = int(texture_size)
    pack.padding = ATLAS_PADDING_TEXELS
    atlas.generate(pack_options=pack)
    if atlas.atlas_count != 1:
        raise GeometryError(
            f"mesh {mesh.source}: xatlas packed the charts into {atlas.atlas_count} atlases, expected one "
            f"(texture_size {texture_size} is too small for the mesh's charts)"
        )
    vmapping, indices, uv = atlas[0]
    if len(indices) != len(mesh.faces):
        raise GeometryError(f"mesh {mesh.source}: xatlas returned {len(indices)} faces for {len(mesh.faces)}")
    size = np.array([atlas.width, atlas.height], dtype=np.float64)
    uv = uv.astype(np.float64) * size / max(size.max(), texture_size)
    faces = indices.astype(np.int64)
    return MeshData(
        vertices=mesh.vertices[vmapping.astype(np.int64)],
        faces=faces,
        uvs=np.clip(uv[faces], 0.0, 1.0),
        source=mesh.source,
    )
