"""xatlas atlases for meshes without UVs."""

import numpy as np
import trimesh

from torchrefl.geometry.atlas import rasterise_atlas
from torchrefl.geometry.atlas_charts import face_charts
from torchrefl.geometry.atlas_parametrise import parametrise
from torchrefl.geometry.mesh_file import MeshData, read_mesh, write_obj


def torus():
    tm = trimesh.creation.torus(10.0, 3.0, major_sections=24, minor_sections=12)
    return MeshData(np.asarray(tm.vertices, float), np.asarray(tm.faces), source="torus.ply"), tm


def test_every_face_gets_texels_without_overlaps_and_the_same_atlas_twice(tmp_path):
    mesh, tm = torus()
    atlas_mesh = parametrise(mesh, 256)
    # Faces keep their order and their corners' positions.
    assert np.allclose(atlas_mesh.vertices[atlas_mesh.faces], mesh.vertices[mesh.faces])
    assert atlas_mesh.uvs.min() >= 0 and atlas_mesh.uvs.max() <= 1
    atlas = rasterise_atlas(atlas_mesh, 256)  # raises on overlapping charts
    assert np.unique(atlas.face).size == len(mesh.faces)
    assert atlas.areas.sum() / tm.area > 0.97 and atlas.areas.sum() / tm.area < 1.03
    assert face_charts(atlas_mesh).max() >= 1
    again = parametrise(mesh, 256)
    assert np.array_equal(again.uvs, atlas_mesh.uvs) and np.array_equal(again.faces, atlas_mesh.faces)
    write_obj(tmp_path / "mesh.obj", atlas_mesh)
    back = read_mesh(tmp_path / "mesh.obj")
    assert np.allclose(back.uvs, atlas_mesh.uvs, atol=1e-8)
    assert np.allclose(back.vertices[back.faces], atlas_mesh.vertices[atlas_mesh.faces])
