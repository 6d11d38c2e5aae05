"""The mesh_views objects: closed outward meshes with exact normals, atlases in [0, 1], and material borders on
texel edges of a 16 x 2^k atlas."""

import numpy as np
import pytest
import trimesh

from torchrefl.errors import GeometryError
from torchrefl.synthetic.uv_objects import VIEWS_OBJECTS, ellipsoid, make_views_object


@pytest.mark.parametrize("name", VIEWS_OBJECTS)
def test_objects_are_closed_outward_meshes_whose_exact_normals_agree_with_their_faces(name):
    obj = make_views_object(name)
    m = trimesh.Trimesh(obj.mesh.vertices, obj.mesh.faces)  # merged: seam and pole duplicates join
    assert m.is_watertight and m.is_winding_consistent and m.volume > 0
    raw = trimesh.Trimesh(obj.mesh.vertices, obj.mesh.faces, process=False)
    assert (raw.area_faces > 1e-9).all()
    n = obj.mesh.normal(raw.triangles_center, np.arange(len(raw.faces)))
    assert (np.einsum("ni,ni->n", n, raw.face_normals) > 0.999).all()
    np.testing.assert_allclose(np.linalg.norm(obj.vertex_normals, axis=1), 1.0, atol=1e-12)
    if obj.uv is not None:
        assert obj.uv.min() >= 0 and obj.uv.max() <= 1 and obj.uv.shape == (len(obj.mesh.vertices), 2)
    assert obj.concave == (name == "bowl")


def test_every_texel_of_the_ellipsoids_atlas_holds_one_paper():
    obj = ellipsoid(seed=5)
    a = obj.mesh.info["axes"]
    S = 128
    k = (np.arange(4) + 0.5) / 4  # 4 x 4 points inside each texel
    x = (np.arange(S)[:, None] + k[None]).ravel() / S
    u, v = np.meshgrid(x, 1 - x)  # row-major: rows of the atlas top down
    theta, phi = np.pi * (1 - v.ravel()), 2 * np.pi * u.ravel()
    p = a * np.stack([np.sin(theta) * np.sin(phi), np.cos(theta), np.sin(theta) * np.cos(phi)], -1)
    region = obj.mesh.material(p, np.zeros(len(p), dtype=int))["region"].reshape(S, 4, S, 4)
    per_texel = region.transpose(0, 2, 1, 3).reshape(S, S, 16)
    assert (per_texel == per_texel[..., :1]).all()
    assert len(np.unique(region)) == 5


def test_the_mesh_grid_must_follow_the_material_grid():
    with pytest.raises(GeometryError, match="multiples of 16"):
        ellipsoid(rings=40)
