"""The Surface of a mesh's texture atlas: texels with position, normal and area, and their surface neighbours."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from torchrefl.core.surface import Surface
from torchrefl.geometry.atlas import AtlasTexels, rasterise_atlas, uv_to_texel_xy
from torchrefl.geometry.atlas_hits import AtlasHits
from torchrefl.geometry.atlas_neighbours import AtlasNeighbours, face_jacobians
from torchrefl.geometry.atlas_parametrise import parametrise
from torchrefl.geometry.mesh_file import MeshData, read_mesh
from torchrefl.geometry.mesh_normals import DEFAULT_CREASE_ANGLE_DEG, corner_normals
from torchrefl.geometry.mesh_normals import face_normals as mesh_face_normals


@dataclass
class AtlasGeometry:
    """A mesh on its atlas.

    mesh: the mesh the maps belong to (with the atlas xatlas made when the file had no UVs). parametrised: True
    when the atlas was made here, so the mesh must be written into the run folder (mesh_file.write_obj).
    texels: the rasterised atlas. surface: the Surface (grid (S, S), positions and normals in the world frame,
    mm; extras 'face' (T,) int64, 'barycentric' (T, 3) float64, 'chart' (T,) int64; its `neighbours` are these; its
    `hits` map a point of the mesh to its texel by uv, geometry/atlas_hits.py).
    neighbours: the texels' surface neighbours (atlas_neighbours)."""

    mesh: MeshData
    parametrised: bool
    texels: AtlasTexels
    surface: Surface
    neighbours: AtlasNeighbours


def texel_geometry(mesh: MeshData, texels: AtlasTexels, face_normals: bool = False, crease_angle_deg=None):
    """(positions (T, 3), normals (T, 3)) of texels on mesh: the barycentric blend of the face's corners, and of
    its corner normals (mesh_normals.corner_normals, normalised) or, with face_normals, the face's own normal.
    A texel on a face of zero 3-D area (a UV sphere's pole) takes the blend of its corner normals either way."""
    faces = mesh.faces[texels.face]
    positions = np.einsum("tk,tki->ti", texels.barycentric, mesh.vertices[faces])
    flat = mesh_face_normals(mesh.vertices, mesh.faces)[texels.face]
    degenerate = ~flat.any(axis=1)
    if face_normals and not degenerate.any():
        return positions, flat
    crease = DEFAULT_CREASE_ANGLE_DEG if crease_angle_deg is None else crease_angle_deg
    corner = corner_normals(mesh.vertices, mesh.faces, crease)[texels.face]
    n = np.einsum("tk,tki->ti", texels.barycentric, corner)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    smooth = np.where(length > 1e-9, n / np.maximum(length, 1e-300), flat)
    return positions, np.where(degenerate[:, None] | (not face_normals), smooth, flat)


def atlas_geometry(
    mesh: MeshData,
    texture_size: int,
    face_normals: bool = False,
    conservative: bool = True,
    crease_angle_deg=None,
    dtype: torch.dtype = torch.float64,
) -> AtlasGeometry:
    """mesh's atlas at texture_size x texture_size (xatlas makes one when the mesh has no UVs) as an
    AtlasGeometry. face_normals: texel normals are the faces' own instead of interpolated vertex normals;
    conservative: atlas.rasterise_atlas; crease_angle_deg: mesh_normals.corner_normals (None: its default)."""
    parametrised = mesh.uvs is None
    if parametrised:
        mesh = parametrise(mesh, texture_size)
    texels = rasterise_atlas(mesh, texture_size, conservative=conservative)
    positions, normals = texel_geometry(mesh, texels, face_normals, crease_angle_deg)
    S = int(texture_size)
    jac = face_jacobians(mesh.vertices, mesh.faces, uv_to_texel_xy(mesh.uvs, S))[texels.face]
    neighbours = AtlasNeighbours(texels.texel_index, (S, S), texels.chart, positions, normals, jac)
    hits = AtlasHits(mesh, texels, positions, normals)
    surface = Surface(
        grid_shape=(S, S),
        texel_index=torch.from_numpy(texels.texel_index),
        positions=torch.from_numpy(positions).to(dtype),
        normals=torch.from_numpy(normals).to(dtype),
        areas=torch.from_numpy(texels.areas).to(dtype),
        mesh_vertices=mesh.vertices,
        mesh_faces=mesh.faces,
        units="mm",
        source=mesh.source,
        extras={"face": texels.face, "barycentric": texels.barycentric, "chart": texels.chart},
        neighbours=neighbours,
        hits=hits,
    )
    return AtlasGeometry(mesh, parametrised, texels, surface, neighbours)


def load_atlas_geometry(path, texture_size: int, units: str = "mm", **options) -> AtlasGeometry:
    """read_mesh(path, units) then atlas_geometry(mesh, texture_size, **options)."""
    return atlas_geometry(read_mesh(path, units), texture_size, **options)
