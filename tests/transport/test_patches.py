"""texel_patches on an atlas: blocks split by chart, so no patch joins texels of charts that only sit side by
side in the atlas."""

import numpy as np
import torch
from conftest import atlas_cube

from torchrefl.core.surface import Surface
from torchrefl.transport.patches import texel_patches


def test_no_patch_straddles_two_charts_of_an_atlas():
    """The cube's 8-texel charts start at atlas columns 1, 10 and 19 (one gutter texel apart), so 4 x 4 blocks of
    the grid hold texels of two charts; split by chart, every patch lies on one face, and the patches cover each
    face with 9 blocks (a chart starting at 1 meets blocks 0-2). The same texels without their neighbours (the
    plain grid) do join charts."""
    g = atlas_cube(side=8, gap=1)
    s = g.surface
    chart = s.extras["chart"]
    patches = texel_patches(s, 4)
    tp = patches.texel_patch.numpy()
    per_patch = [np.unique(chart[tp == q]) for q in range(patches.num_patches)]
    assert all(len(c) == 1 for c in per_patch)
    assert patches.num_patches == 6 * 9
    assert len(torch.unique(patches.block[:, 0] * 1000 + patches.block[:, 1])) == patches.num_patches
    normals = patches.normals.numpy()
    assert np.allclose(np.abs(normals).max(1), 1.0)  # each patch's mean normal is its face's
    plain = Surface(s.grid_shape, s.texel_index, s.positions, s.normals, s.areas)
    tp = texel_patches(plain, 4).texel_patch.numpy()
    assert any(len(np.unique(chart[tp == q])) > 1 for q in np.unique(tp))
