"""The atlas's texel mesh for the interreflection levels: grid point k is vertex k, no triangle bridges charts."""

import numpy as np
from atlas_meshes import cube_atlas

from torchrefl.geometry.atlas_surface import atlas_geometry
from torchrefl.geometry.atlas_texel_mesh import texel_grid_mesh


def test_charts_side_by_side_in_uv_are_not_joined():
    # six 16 x 16 charts in a 3 x 2 block with no gutter: neighbours in the atlas, far apart on the cube
    geom = atlas_geometry(cube_atlas(side_texels=16, texture_size=48, gap=0, texel_mm=0.5), texture_size=48)
    s = geom.surface
    verts, faces = texel_grid_mesh(s.texel_index.numpy(), geom.texels.chart, s.positions.numpy(), s.grid_shape)
    assert verts.shape == (48 * 48, 3)
    np.testing.assert_array_equal(verts[s.texel_index.numpy()], s.positions.numpy())
    assert len(faces) == 6 * 15 * 15 * 2  # every quad inside a chart, none across
    edges = np.linalg.norm(verts[faces] - verts[np.roll(faces, 1, axis=1)], axis=-1)
    assert edges.max() <= 0.5 * np.sqrt(2) + 1e-9  # a texel's diagonal: no triangle spans the cube
