"""radiosity.reconstruction: linear: texel values from a plane through the neighbouring patches' values."""

import numpy as np
import pytest
import torch
from conftest import fold_surface, point_light_observations

from torchrefl.errors import ConfigError
from torchrefl.transport.form_factors import form_factors_for_surface
from torchrefl.transport.local import local_terms
from torchrefl.transport.patch_reconstruction import linear_reconstruction
from torchrefl.transport.patches import texel_patches
from torchrefl.transport.radiosity_level import PatchMap, indirect_irradiance


def operator(s, patches, size=2, angle=30.0):
    return linear_reconstruction(
        s.neighbours,
        s.positions.numpy(),
        s.normals.numpy(),
        patches.texel_patch.numpy(),
        patches.centres.numpy(),
        patches.normals.numpy(),
        size,
        angle,
    )


def test_a_linear_field_on_each_side_of_a_fold_is_reproduced_at_every_texel():
    """A field linear on each plate (another plane on each) sampled at the patch centroids: the operator gives
    its value at every texel, the ones next to the fold and on the outer edges included, where taking the
    patch's value (or averaging patches) leaves an error of the order of the gradient times half a patch."""
    s = fold_surface(12, 24)
    patches = texel_patches(s, 2, 30.0)
    R = operator(s, patches)
    assert R.shape == (s.num_texels, patches.num_patches)
    floor = s.normals[:, 2] > 0.5
    plane = lambda x, f: torch.where(f, 1.0 + 0.02 * x[:, 0] - 0.01 * x[:, 1], 2.0 - 0.03 * x[:, 2] + 0.005 * x[:, 1])
    pfloor = patches.normals[:, 2] > 0.5
    H_q = plane(patches.centres, pfloor)
    truth = plane(s.positions, floor)
    got = torch.sparse.mm(R, H_q[:, None])[:, 0]
    torch.testing.assert_close(got, truth, rtol=0, atol=1e-5)  # the slope ridge: 1e-6 relative
    constant = H_q[patches.texel_patch]
    assert float((constant - truth).abs().max()) > 0.02


def test_rows_sum_to_one_and_stay_finite_where_the_patches_lie_in_a_line():
    """One row of patches: they lie in a line, the slope across it is undetermined; the ridge makes the
    operator a weighted mean there (rows sum to one, a constant stays constant, a linear field along the
    row is still reproduced)."""
    s = fold_surface(2, 16)  # one row of 2 x 2 patches
    patches = texel_patches(s, 2, 30.0)
    R = operator(s, patches).to_dense()
    assert torch.isfinite(R).all()
    torch.testing.assert_close(R.sum(1), torch.ones(s.num_texels, dtype=R.dtype))
    floor = (s.normals[:, 2] > 0.5).numpy()
    pfloor = (patches.normals[:, 2] > 0.5).numpy()
    H_q = patches.centres[:, 0].clone()
    got = (R @ H_q)[floor]
    np.testing.assert_allclose(got.numpy(), s.positions[floor, 0].numpy(), rtol=1e-4)
    assert pfloor.any()


def small_fold_radiosity():
    """A 4 x 8 fold under one point light: (surface, observations, local terms, 2 x 2 patches, their form factors
    from 64 rays each, the patch map)."""
    s = fold_surface(4, 8)
    obs = point_light_observations(
        s.normals, s.positions, torch.tensor([[-40.0, 0.0, 25.0]]), torch.tensor([-150.0, 0.0, 150.0])
    )
    terms = local_terms("lambertian", s.normals, obs)
    patches, F = form_factors_for_surface(s, patch_size=2, samples_per_patch=64, split_angle_deg=30.0)
    pmap = PatchMap(patches.texel_patch, s.areas.double(), patches.num_patches)
    return s, obs, terms, patches, F, pmap


def test_the_radiosity_level_with_the_linear_reconstruction_has_float64_gradients():
    s, obs, terms, patches, F, pmap = small_fold_radiosity()
    R = operator(s, patches)
    pd = torch.full((s.num_texels, 3), 0.6, dtype=torch.float64, requires_grad=True)
    f = lambda x: indirect_irradiance(terms, obs.kappa, x, pmap, F, reconstruct=R)
    assert torch.autograd.gradcheck(lambda x: f(x)[0, :, 0], (pd,), eps=1e-6, atol=1e-7)
    const = indirect_irradiance(terms, obs.kappa, pd.detach(), pmap, F)
    lin = f(pd.detach())
    assert not torch.equal(const, lin)
    # both estimate the same light: the plate totals agree within a few per cent
    assert abs(float(lin.sum() / const.sum()) - 1) < 0.05


def test_a_bad_patch_size_is_refused():
    s = fold_surface(4, 8)
    patches = texel_patches(s, 2, 30.0)
    with pytest.raises(ConfigError, match="radiosity.patch_size"):
        operator(s, patches, size=0)


def test_on_an_atlas_the_neighbouring_patches_are_on_the_surface():
    """On the cube's atlas (charts one gutter texel apart, opposite faces side by side) a texel's plane takes
    patches of its own face and of the faces across the cube's edges, never of the opposite face that only sits
    beside its own in the atlas (no normal test here: max_angle_deg 180)."""
    from conftest import atlas_cube

    s = atlas_cube(side=8, gap=1).surface
    patches = texel_patches(s, 4)
    t, q = operator(s, patches, size=4, angle=180.0).coalesce().indices().numpy()
    facing = np.einsum("mi,mi->m", s.normals.numpy()[t], patches.normals.numpy()[q])
    assert facing.min() > -0.5  # no opposite face
    assert (facing < 0.5).any()  # the faces across the edges


def test_a_texel_whose_plane_goes_below_zero_takes_its_patch_value():
    """A plane through noisy patches can extrapolate below zero (few form-factor rays, a chart's edge); irradiance
    is never negative, so such a texel takes its own patch's value, the others keep their planes, and the gradients
    stay float64-exact on both sides."""
    s, obs, terms, patches, F, pmap = small_fold_radiosity()
    T, Q = s.num_texels, patches.num_patches
    own = patches.texel_patch
    # an operator whose even texels extrapolate far past their patch (2 x own - 3 x the next patch), odd texels exact
    rows, cols, vals = [], [], []
    for t in range(T):
        q = int(own[t])
        if t % 2 == 0:
            rows += [t, t]
            cols += [q, (q + 1) % Q]
            vals += [2.0, -3.0]
        else:
            rows.append(t), cols.append(q), vals.append(1.0)
    R = torch.sparse_coo_tensor(torch.tensor([rows, cols]), torch.tensor(vals, dtype=torch.float64), (T, Q))
    pd = torch.full((T, 3), 0.6, dtype=torch.float64, requires_grad=True)
    patch_H = indirect_irradiance(terms, obs.kappa, pd.detach(), pmap, F)[0]
    H = indirect_irradiance(terms, obs.kappa, pd.detach(), pmap, F, reconstruct=R)[0]
    assert (H >= 0).all()
    H_q = torch.zeros(Q, 3, dtype=torch.float64).index_copy(0, own, patch_H)  # each patch's value
    planes = 2.0 * H_q[own] - 3.0 * H_q[(own + 1) % Q]
    even = torch.arange(T) % 2 == 0
    below = even[:, None] & (planes < 0)
    assert bool(below.any()) and bool((even[:, None] & (planes > 0)).any())
    torch.testing.assert_close(H[below], patch_H[below])  # the fallback: the texel's own patch
    above = even[:, None] & ~below
    torch.testing.assert_close(H[above], planes[above])  # a plane at or above zero is kept
    torch.testing.assert_close(H[~even], patch_H[~even])  # odd texels: their plane is their patch
    f = lambda x: indirect_irradiance(terms, obs.kappa, x, pmap, F, reconstruct=R)[0, :, 0]
    assert torch.autograd.gradcheck(f, (pd,), eps=1e-6, atol=1e-7)
