"""Rasterising a UV atlas: the texel convention, centre sampling, overlapping charts, thin charts."""

import numpy as np
import pytest
from atlas_meshes import cube_atlas

from torchrefl.errors import GeometryError
from torchrefl.geometry.atlas import rasterise_atlas, texel_uv
from torchrefl.geometry.mesh_file import MeshData


def quad(corners_3d, uv_lo, uv_hi, base=0):
    """Two faces of the rectangle corners_3d (4, 3) mapped to the UV box [uv_lo, uv_hi], counter-clockwise."""
    (u0, v0), (u1, v1) = uv_lo, uv_hi
    uv = np.array([[u0, v0], [u1, v0], [u1, v1], [u0, v1]], dtype=np.float64)
    faces = np.array([[0, 1, 2], [0, 2, 3]]) + base
    return np.asarray(corners_3d, dtype=np.float64), faces, uv[[[0, 1, 2], [0, 2, 3]]]


def square(size=1.0, z=0.0):
    return np.array([[0, 0, z], [size, 0, z], [size, size, z], [0, size, z]], dtype=np.float64)


def test_texel_centres_follow_the_image_convention():
    # Row 0 is the top of the image (v near 1), column 0 the left (u near 0).
    assert np.allclose(
        texel_uv(np.array([0, 3, 12, 15]), 4), [[0.125, 0.875], [0.875, 0.875], [0.125, 0.125], [0.875, 0.125]]
    )


def test_a_small_chart_lands_on_the_texels_whose_centres_it_covers():
    # UV box u in [0.25, 0.75], v in [0.5, 1] of an 8 x 8 atlas: columns 2..5, rows 0..3.
    v, f, uv = quad(square(4.0), (0.25, 0.5), (0.75, 1.0))
    atlas = rasterise_atlas(MeshData(v, f, uv, source="box.obj"), 8)
    rows, cols = np.divmod(atlas.texel_index, 8)
    assert sorted(set(rows.tolist())) == [0, 1, 2, 3] and sorted(set(cols.tolist())) == [2, 3, 4, 5]
    assert atlas.num_texels == 16 and not atlas.conservative.any()
    assert np.allclose(atlas.areas, 1.0)  # 16 mm^2 over 16 texels
    assert np.allclose(atlas.barycentric.sum(axis=1), 1.0) and (atlas.barycentric >= -1e-12).all()


def test_overlapping_charts_are_refused_with_counts():
    v1, f1, uv1 = quad(square(), (0.0, 0.0), (0.5, 0.5))
    # Texel box x 2..6, y 5..7 over the first's x 0..4, y 4..8: 2 x 2 texel centres in both, one of them on the
    # first's diagonal (inside the second only: still an overlap).
    v2, f2, uv2 = quad(square(z=5.0), (0.25, 0.125), (0.75, 0.375), base=4)
    mesh = MeshData(np.concatenate([v1, v2]), np.concatenate([f1, f2]), np.concatenate([uv1, uv2]), source="m.obj")
    with pytest.raises(GeometryError, match="overlapping charts") as err:
        rasterise_atlas(mesh, 8)
    assert "m.obj" in str(err.value) and "4 texel centres" in str(err.value)


def test_mirrored_copy_of_a_chart_is_an_overlap():
    v, f, uv = quad(square(), (0.0, 0.0), (0.5, 0.5))
    mirrored = uv.copy()
    mirrored[..., 0] = 0.5 - mirrored[..., 0]
    mesh = MeshData(np.concatenate([v, v + [0, 0, 3]]), np.concatenate([f, f + 4]), np.concatenate([uv, mirrored]))
    with pytest.raises(GeometryError, match="mirrored or tiled"):
        rasterise_atlas(mesh, 8)


def test_charts_touching_along_an_edge_do_not_overlap():
    atlas = rasterise_atlas(cube_atlas(side_texels=4, texture_size=16, gap=1), 16)
    assert atlas.num_texels == 6 * 16
    assert np.allclose(atlas.areas.sum(), 6 * 16.0)


def test_a_chart_thinner_than_a_texel_is_kept_by_conservative_texels():
    main_v, main_f, main_uv = quad(square(4.0), (0.0, 0.0), (0.5, 0.5))
    # A 6 mm x 0.5 mm strip whose UV box spans rows y = 3.6..3.9 of an 8 x 8 atlas: between the centres of rows
    # 3 (y = 3.5) and 4 (y = 4.5), closer to row 3's, from x = 0.5 to 7.5 (covering columns 0..7's centres in x).
    strip = np.array([[0, 10, 0], [6, 10, 0], [6, 10.5, 0], [0, 10.5, 0]], dtype=np.float64)
    s_v, s_f, s_uv = quad(strip, (0.5 / 8, 1 - 3.9 / 8), (7.5 / 8, 1 - 3.6 / 8), base=4)
    mesh = MeshData(np.concatenate([main_v, s_v]), np.concatenate([main_f, s_f]), np.concatenate([main_uv, s_uv]))
    plain = rasterise_atlas(mesh, 8, conservative=False)
    assert not np.isin(plain.face, [2, 3]).any()
    atlas = rasterise_atlas(mesh, 8)
    thin = np.isin(atlas.face, [2, 3])
    assert (thin == atlas.conservative).all()
    assert sorted(atlas.texel_index[thin].tolist()) == [3 * 8 + c for c in range(8)]
    assert atlas.areas[thin].sum() == pytest.approx(3.0)
    assert atlas.areas[~thin].sum() == pytest.approx(16.0)
    # Each conservative texel sits on the strip, at its point nearest the texel centre.
    corners = mesh.vertices[mesh.faces[atlas.face[thin]]]
    p = np.einsum("tk,tki->ti", atlas.barycentric[thin], corners)
    assert (p[:, 1] >= 10 - 1e-12).all() and (p[:, 1] <= 10.5 + 1e-12).all()


def test_mesh_without_uvs_is_refused():
    with pytest.raises(GeometryError, match="no UVs"):
        rasterise_atlas(MeshData(square(), np.array([[0, 1, 2]]), source="plain.ply"), 8)
