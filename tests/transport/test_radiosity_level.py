"""Radiosity level: prediction reduces to local without form factors, inverse radiosity is exact
on exact data, gradients flow into Pd."""

import math

import torch
from conftest import dome_scene, point_light_observations

from torchrefl.transport.local import local_terms, predict
from torchrefl.transport.radiosity import solve_radiosity, sparse_operator
from torchrefl.transport.radiosity_level import (
    PatchMap,
    distinct_emitters,
    indirect_irradiance,
    inverse_radiosity,
    predict_radiosity,
)


def scene(T=24, seed=0):
    nrm, pos, lights, cam = dome_scene(T=T, seed=seed)
    obs = point_light_observations(nrm, pos, lights[::9], cam)
    terms = local_terms("torrance_sparrow", torch.as_tensor(nrm), obs)
    g = torch.Generator().manual_seed(seed)
    areas = 0.5 + torch.rand(T, generator=g, dtype=torch.float64)
    G = torch.rand(T, T, generator=g, dtype=torch.float64)
    G = G + G.t()
    G.fill_diagonal_(0)
    F = G / areas[:, None]
    F = F / F.sum(1).max() * 0.6  # reciprocal, open
    patches = PatchMap(torch.arange(T), areas, T)
    pd = 0.2 + 0.6 * torch.rand(T, 3, generator=g, dtype=torch.float64)
    return obs, terms, patches, F, pd


def test_without_form_factors_it_is_the_local_prediction():
    obs, terms, patches, F, pd = scene()
    ps = torch.full_like(pd, 0.2)
    sigma = torch.full((pd.shape[0],), 0.1, dtype=torch.float64)
    a = predict_radiosity(terms, obs.kappa, pd, ps, sigma, patches, torch.zeros_like(F))
    torch.testing.assert_close(a, predict(terms, pd, ps, sigma))


def test_interreflection_adds_light_and_matches_the_series():
    """H equals the Neumann series F (rho E) + F rho F (rho E) + ... summed by hand."""
    obs, terms, patches, F, pd = scene()
    H = indirect_irradiance(terms, obs.kappa, pd, patches, F)
    E = terms.diffuse * (math.pi / obs.kappa)
    B = pd[None] * E
    total = torch.zeros_like(E)
    for _ in range(200):
        bounce = torch.einsum("uv,pvc->puc", F, B)
        total = total + bounce
        B = pd[None] * bounce
    torch.testing.assert_close(H, total, rtol=1e-9, atol=1e-12)
    assert (H >= 0).all() and H.sum() > 0


def test_inverse_radiosity_is_exact_on_exact_data():
    obs, terms, patches, F, pd = scene()
    zeros = torch.zeros_like(pd)
    sigma = torch.full((pd.shape[0],), 0.1, dtype=torch.float64)
    obs.intensity = predict_radiosity(terms, obs.kappa, pd, zeros, sigma, patches, F)
    rho, det = inverse_radiosity(terms, obs.kappa, obs.intensity, torch.ones_like(obs.valid), patches, F)
    assert det.all()
    torch.testing.assert_close(rho, pd, rtol=1e-9, atol=1e-12)
    # the local closed form is biased upwards by the interreflection
    local = (obs.intensity / terms.diffuse.clamp_min(1e-30))[0]
    assert (local[terms.diffuse[0, :, 0] > 0] > pd[terms.diffuse[0, :, 0] > 0] + 1e-6).all()


def test_gradcheck_through_the_solve():
    obs, terms, patches, F, pd = scene(T=6)
    ps = torch.full((6, 3), 0.2, dtype=torch.float64)
    sigma = torch.full((6,), 0.1, dtype=torch.float64)
    f = lambda p: predict_radiosity(terms, obs.kappa, p, ps, sigma, patches, F)
    assert torch.autograd.gradcheck(f, (pd.clone().requires_grad_(),))


def test_patch_means_are_area_weighted():
    areas = torch.tensor([1.0, 3.0, 2.0], dtype=torch.float64)
    pm = PatchMap(torch.tensor([0, 0, 1]), areas, 2)
    x = torch.tensor([[1.0], [5.0], [7.0]], dtype=torch.float64)
    torch.testing.assert_close(pm.mean(x), torch.tensor([[4.0], [7.0]], dtype=torch.float64))
    torch.testing.assert_close(pm.scatter(pm.mean(x)), torch.tensor([[4.0], [4.0], [7.0]], dtype=torch.float64))


def moving_light_fold(H=4, W=10):
    """The fold lit by one light that moves with the column (a co-rotating rig): texel t's image saw the
    light at L_col(t). Returns surface, observations, per-texel light positions (T, 3)."""
    from conftest import fold_surface

    s = fold_surface(H, W)
    col = s.texel_index % W
    angle = (col.double() - W / 2) * 0.08
    L = torch.stack([-60 * torch.sin(angle) - 30, torch.zeros_like(angle), 60 * torch.cos(angle)], -1)
    obs = point_light_observations(s.normals, s.positions, torch.zeros(1, 3), torch.tensor([-150.0, 0.0, 150.0]))
    to = L[None] - s.positions[None]
    dist = to.norm(dim=-1)
    obs.light_dir, obs.falloff = to / dist[..., None], 1.0 / dist**2
    obs.valid = (s.normals[None] * obs.light_dir).sum(-1) > 0
    return s, obs, L


def fold_form_factors(s):
    from torchrefl.core.rays import RayTracer
    from torchrefl.transport.form_factors import form_factors_for_surface

    patches, F = form_factors_for_surface(
        s, RayTracer(s.mesh_vertices, s.mesh_faces), patch_size=1, samples_per_patch=256, seed=0
    )
    return PatchMap(patches.texel_patch, s.areas.double(), patches.num_patches), F.double()


def test_emitter_maps_give_each_texel_the_radiosity_lit_from_its_own_column():
    """With one map per column, the maps' E in a texel's own column is the local direct irradiance, and H at
    every texel equals a brute-force solve with all emitters lit from that texel's column light."""
    from torchrefl.core.rays import RayTracer
    from torchrefl.transport.light_maps import light_sources
    from torchrefl.transport.radiosity_level import direct_irradiance, emitter_maps

    s, obs, L = moving_light_fold()
    H, W = s.grid_shape
    terms = local_terms("lambertian", s.normals, obs)
    pm, F = fold_form_factors(s)
    src = light_sources(s, obs, W)
    maps = emitter_maps(src, s.positions, s.normals, RayTracer(s.mesh_vertices, s.mesh_faces), 0.05)
    col = (s.texel_index % W).numpy()
    own = maps.irradiance[0, col, torch.arange(s.num_texels)]
    torch.testing.assert_close(own, direct_irradiance(terms, obs.kappa)[0], rtol=1e-9, atol=1e-12)
    pd = 0.3 + 0.5 * torch.rand(s.num_texels, 3, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    got = indirect_irradiance(terms, obs.kappa, pd, pm, F, maps)[0]
    ref = torch.zeros_like(got)
    x, n = s.positions, s.normals
    for c in range(W):  # all emitters lit from column c's light, no shadows here
        to = L[col == c][0][None] - x
        d2 = (to * to).sum(-1)
        E = (n * to).sum(-1).clamp_min(0) / d2.sqrt() / d2
        E = E[:, None] * obs.light_intensity[0][None]
        B = solve_radiosity(pm.mean(pd[None])[0], pm.mean(E[None]), F)[0]
        Hc = pm.scatter(F @ B)
        ref[col == c] = Hc[col == c]
    torch.testing.assert_close(got, ref, rtol=1e-9, atol=1e-12)
    # lit as in each emitter's own column instead (no maps), H differs: the maps matter on a moving rig
    plain = indirect_irradiance(terms, obs.kappa, pd, pm, F)[0]
    assert float((plain - ref).abs().max() / ref.abs().max()) > 0.02


def test_one_emitter_map_of_static_lights_is_the_plain_level_and_gradcheck_with_maps():
    from torchrefl.core.rays import RayTracer
    from torchrefl.transport.light_maps import light_sources
    from torchrefl.transport.radiosity_level import emitter_maps

    s, obs, L = moving_light_fold(3, 6)
    light = L[0]
    to = light[None, None] - s.positions[None]
    dist = to.norm(dim=-1)
    obs.light_dir, obs.falloff = to / dist[..., None], 1.0 / dist**2  # a static light now
    obs.light_positions = light[None]
    terms = local_terms("lambertian", s.normals, obs)
    pm, F = fold_form_factors(s)
    src = light_sources(s, obs, 8)
    assert src.num_maps == 1
    maps = emitter_maps(src, s.positions, s.normals, RayTracer(s.mesh_vertices, s.mesh_faces), 0.05)
    pd = torch.full((s.num_texels, 3), 0.6, dtype=torch.float64)
    torch.testing.assert_close(
        indirect_irradiance(terms, obs.kappa, pd, pm, F, maps),
        indirect_irradiance(terms, obs.kappa, pd, pm, F),
        rtol=1e-9,
        atol=1e-12,
    )
    s2, obs2, _ = moving_light_fold(2, 4)
    terms2 = local_terms("lambertian", s2.normals, obs2)
    pm2, F2 = fold_form_factors(s2)
    maps2 = emitter_maps(
        light_sources(s2, obs2, 3), s2.positions, s2.normals, RayTracer(s2.mesh_vertices, s2.mesh_faces), 0.05
    )
    f = lambda p: indirect_irradiance(terms2, obs2.kappa, p, pm2, F2, maps2)
    assert torch.autograd.gradcheck(f, (torch.full((s2.num_texels, 3), 0.5, dtype=torch.float64, requires_grad=True),))


def test_fold_texels_get_their_own_irradiance_when_patches_split_at_the_fold():
    """A 2x2-texel patch that straddles a fold gives the texels of both plates one irradiance: too high on
    the side that sees the other plate less. Split at the fold (radiosity.patch_split_angle_deg), the fold
    columns' H (smoothed over the texels like the pipeline does) matches a one-texel-per-patch reference."""
    from conftest import fold_surface

    from torchrefl.transport.form_factors import form_factors_for_surface
    from torchrefl.transport.photon_density import apply_on_grid, smoothing_matrix

    s = fold_surface(16, 66)  # 33 columns per plate: blocks of columns 32-33 straddle the fold
    H, W = s.grid_shape
    obs = point_light_observations(
        s.normals, s.positions, torch.tensor([[-40.0, 0.0, 25.0]]), torch.tensor([-150.0, 0.0, 150.0])
    )
    terms = local_terms("lambertian", s.normals, obs)
    pd = torch.full((s.num_texels, 3), 0.7, dtype=torch.float64)
    M = smoothing_matrix(s.neighbours, 1.0, s.normals.numpy(), 0.1)

    def column_h(patch_size, angle, samples):
        P, F = form_factors_for_surface(
            s, None, patch_size=patch_size, samples_per_patch=samples, seed=0, split_angle_deg=angle
        )
        h = indirect_irradiance(terms, obs.kappa, pd, PatchMap(P.texel_patch, s.areas.double(), P.num_patches), F)
        if patch_size > 1:
            h = apply_on_grid(M, h)
        return h[0, :, 0].reshape(H, W).mean(0)

    ref = column_h(1, 180.0, 2048)
    fold = [W // 2 - 1, W // 2]  # the floor's and the wall's texel column at the fold
    split = column_h(2, 30.0, 1024)[fold] / ref[fold] - 1
    plain = column_h(2, 180.0, 1024)[fold] / ref[fold] - 1
    assert float(split.abs().max()) < 0.025
    assert float(plain.abs().max()) > 0.05  # the unsplit patch is off there (measured +8 % on the wall)


def test_a_separate_solve_matrix_solves_with_it_and_gathers_with_f():
    """F_solve (radiosity.solve_samples): B from F_solve, H = F B, against a dense solve by hand; F_solve = F is
    the one-matrix level exactly; gradcheck through both matrices."""
    obs, terms, patches, F, pd = scene()
    _, _, _, F2, _ = scene(seed=3)  # another reciprocal, open F for the same patches
    E = terms.diffuse * (math.pi / obs.kappa)
    got = indirect_irradiance(terms, obs.kappa, pd, patches, F, F_solve=F2)
    ref = torch.zeros_like(got)
    eye = torch.eye(F.shape[0], dtype=torch.float64)
    for p in range(E.shape[0]):
        for c in range(3):
            B = torch.linalg.solve(eye - pd[:, c, None] * F2, pd[:, c] * E[p, :, c])
            ref[p, :, c] = F @ B
    torch.testing.assert_close(got, ref, rtol=1e-9, atol=1e-12)
    torch.testing.assert_close(
        indirect_irradiance(terms, obs.kappa, pd, patches, F, F_solve=F),
        indirect_irradiance(terms, obs.kappa, pd, patches, F),
        rtol=0,
        atol=0,
    )
    assert float((got - indirect_irradiance(terms, obs.kappa, pd, patches, F)).abs().max()) > 1e-6 * float(
        got.abs().max()
    )
    small = scene(T=6)
    o6, t6, p6, F6, pd6 = small
    G6 = scene(T=6, seed=4)[3]
    assert torch.autograd.gradcheck(
        lambda p: indirect_irradiance(t6, o6.kappa, p, p6, F6, F_solve=G6), (pd6.clone().requires_grad_(),)
    )


def test_operators_kept_as_csr_give_the_dense_results_and_gradients():
    """The levels keep F, F_solve and the reconstruction as CSR operators in the fit's dtype
    (radiosity.sparse_operator): H equals the dense matrices' in float64, a float32 fit's (float32 operators) to
    float32's precision, and gradcheck passes."""
    obs, terms, patches, F, pd = scene()
    F2 = scene(seed=3)[3]
    csr = lambda M, dtype=torch.float64: sparse_operator(M.to_sparse(), dtype)  # noqa: E731
    dense = indirect_irradiance(terms, obs.kappa, pd, patches, F, F_solve=F2)
    torch.testing.assert_close(
        indirect_irradiance(terms, obs.kappa, pd, patches, csr(F), F_solve=csr(F2)), dense, rtol=1e-10, atol=1e-13
    )
    t32 = type(terms)(
        terms.brdf, *(getattr(terms, k).float() for k in ("theta_h", "cos_l", "cos_v", "diffuse", "specular"))
    )
    low = indirect_irradiance(
        t32, obs.kappa.float(), pd.float(), patches, csr(F, torch.float32), F_solve=csr(F2, torch.float32)
    )
    assert low.dtype == torch.float32
    torch.testing.assert_close(low.double(), dense, rtol=1e-5, atol=1e-7)
    o6, t6, p6, F6, pd6 = scene(T=6)
    G6 = scene(T=6, seed=4)[3]
    assert torch.autograd.gradcheck(
        lambda p: indirect_irradiance(t6, o6.kappa, p, p6, csr(F6), F_solve=csr(G6)), (pd6.clone().requires_grad_(),)
    )


def test_images_that_share_a_light_are_solved_once_each():
    """Images of one light from several cameras (the mesh_views kind) have the same direct irradiance: they are
    grouped (distinct_emitters) and solved once per group, with the same H as one solve per image; the cameras do
    not matter (the images here differ in their view directions)."""
    nrm, pos, lights, cam = dome_scene(T=24, seed=0)
    L = lights[[0, 9, 0, 18, 9]]  # images 0 and 2 share a light, 1 and 4 another
    obs = point_light_observations(nrm, pos, L, cam)
    g = torch.Generator().manual_seed(1)
    obs.view_dir = torch.nn.functional.normalize(
        obs.view_dir[None] + 0.2 * torch.randn(5, 24, 3, generator=g, dtype=torch.float64), dim=-1
    )
    terms = local_terms("torrance_sparrow", torch.as_tensor(nrm), obs)
    _, _, patches, F, pd = scene()
    groups = distinct_emitters(terms, obs.kappa)
    assert groups.first.tolist() == [0, 1, 3] and groups.inverse.tolist() == [0, 1, 0, 2, 1] and groups.shared
    H = indirect_irradiance(terms, obs.kappa, pd, patches, F, emitters=groups)
    torch.testing.assert_close(H, indirect_irradiance(terms, obs.kappa, pd, patches, F), rtol=1e-12, atol=1e-15)
    assert torch.equal(H[0], H[2]) and torch.equal(H[1], H[4]) and not torch.equal(H[0], H[1])
    grouped = lambda x: indirect_irradiance(terms, obs.kappa, x, patches, F, emitters=groups)  # noqa: E731
    assert torch.autograd.gradcheck(grouped, (pd.clone().requires_grad_(),))
    # lights in an order torch.unique does not keep: the groups follow the images' order
    obs2 = point_light_observations(nrm, pos, lights[[18, 9, 0, 9, 18, 0]], cam)
    terms2 = local_terms("torrance_sparrow", torch.as_tensor(nrm), obs2)
    groups2 = distinct_emitters(terms2, obs2.kappa)
    assert groups2.first.tolist() == [0, 1, 2] and groups2.inverse.tolist() == [0, 1, 2, 1, 0, 2]
    torch.testing.assert_close(
        indirect_irradiance(terms2, obs2.kappa, pd, patches, F, emitters=groups2),
        indirect_irradiance(terms2, obs2.kappa, pd, patches, F),
        rtol=1e-12,
        atol=1e-15,
    )
    distinct = point_light_observations(nrm, pos, lights[[0, 9, 18]], cam)
    assert not distinct_emitters(local_terms("torrance_sparrow", torch.as_tensor(nrm), distinct), obs.kappa).shared
