"""Photon tracing: one scattering against the directional albedo by quadrature, energy balance in a
closed sphere, convergence to the radiosity solution like 1/sqrt(N) on a diffuse fold, agreement with
the path tracer on a glossy fold, determinism."""

import numpy as np
import pytest
import torch
import trimesh
from conftest import fold_surface, point_light_observations

from torchrefl.core import brdf as brdf_mod
from torchrefl.core.rays import RayTracer
from torchrefl.core.surface import Surface
from torchrefl.synthetic.path_tracer import IndirectRenderer
from torchrefl.transport.cache_build import build_cache
from torchrefl.transport.form_factors import form_factors_for_surface
from torchrefl.transport.light_maps import light_sources
from torchrefl.transport.local import local_terms
from torchrefl.transport.photon_cache import indirect_radiance
from torchrefl.transport.photon_material import ScatterTables, TexelMaterial
from torchrefl.transport.photon_trace import PhotonTracer
from torchrefl.transport.radiosity_level import PatchMap, indirect_irradiance

LIGHT = np.array([[-40.0, 5.0, 50.0]])
CAMERA = np.array([-150.0, 0.0, 150.0])


def fold_setup(brdf="lambertian", threads=2, H=24, W=48):
    s = fold_surface(H, W)
    obs = point_light_observations(s.normals, s.positions, LIGHT, CAMERA, intensity=1e4)
    tracer = RayTracer(s.mesh_vertices, s.mesh_faces, threads=threads)
    pt = PhotonTracer(tracer, s.texel_index.numpy(), s.positions.numpy(), s.normals.numpy(), brdf, offset=1e-3)
    return s, obs, pt


def material(T, pd=0.6, ps=0.0, sigma=0.1):
    full = lambda v, shape: torch.full(shape, float(v), dtype=torch.float64)
    return full(pd, (T, 3)), full(ps, (T, 3)), full(sigma, (T,))


def photon_irradiance(s, obs, pt, n, seed=0, brdf="lambertian", pd=0.6, ps=0.0, sigma=0.1):
    T = s.num_texels
    src = light_sources(s, obs, 8)
    mat = TexelMaterial.from_tensors(*material(T, pd, ps, sigma))
    hits = pt.trace(src.positions.reshape(-1, 3), np.repeat(src.intensity, src.num_maps, 0), n, mat, seed=seed)
    return build_cache(
        hits, src, pt.areas, s.normals, obs.view_dir, obs.valid, brdf, np.full(T, sigma), 0.6, 0.02
    ), hits


def radiosity_irradiance(s, obs, pd: float):
    """(T,) the radiosity level's indirect irradiance (first light, red) for a uniform Pd, with form factors from
    4096 rays per texel (one texel per patch)."""
    pdt = torch.full((s.num_texels, 3), pd, dtype=torch.float64)
    patches, F = form_factors_for_surface(
        s, RayTracer(s.mesh_vertices, s.mesh_faces), patch_size=1, samples_per_patch=4096, seed=3
    )
    pm = PatchMap(patches.texel_patch, s.areas.double(), patches.num_patches)
    return indirect_irradiance(local_terms("lambertian", s.normals, obs), obs.kappa, pdt, pm, F.double())[0, :, 0]


def blocks(x, H, W, b=4):
    """(H*W,) -> block means (H/b, W/b) over the grid."""
    return x.reshape(H // b, b, W // b, b).mean((1, 3))


def away_from_fold(H, W, b=4):
    keep = np.ones((H // b, W // b), bool)
    keep[:, (W // 2 - 1) // b : W // 2 // b + 1] = False
    return torch.as_tensor(keep)


def directional_albedo(model, n, wi, pd, ps, sigma, nc=1500, nphi=1500):
    """The share of incident flux one scattering reflects: the integral of f(wi, wo) cos_o = g(n, l=wi, v=wo)
    cos_o / cos_i over the hemisphere of wo (torchrefl.core.brdf, float64), by the midpoint rule in (cos_o, phi)."""
    c = (np.arange(nc) + 0.5) / nc
    ph = (np.arange(nphi) + 0.5) * 2 * np.pi / nphi
    C, PH = np.meshgrid(c, ph, indexing="ij")
    sn = np.sqrt(1 - C**2)
    t1 = np.cross(n, [0.0, 1.0, 0.0]) if abs(n[1]) < 0.9 else np.cross(n, [1.0, 0.0, 0.0])
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(n, t1)
    wo = (sn * np.cos(PH))[..., None] * t1 + (sn * np.sin(PH))[..., None] * t2 + C[..., None] * n
    wo = torch.from_numpy(wo.reshape(-1, 3))
    M = len(wo)
    g = brdf_mod.cosine_weighted_brdf(
        model,
        torch.from_numpy(np.tile(n, (M, 1))),
        torch.from_numpy(np.tile(wi, (M, 1))),
        wo,
        torch.full((M, 3), pd, dtype=torch.float64),
        torch.full((M, 3), ps, dtype=torch.float64),
        torch.full((M,), sigma, dtype=torch.float64),
    )[:, 0].numpy()
    cos_i = float(np.dot(n, wi))
    return float((g * C.reshape(-1)).sum() * (1 / nc) * (2 * np.pi / nphi) / cos_i)


@pytest.mark.parametrize(
    "model,ps,sigma",
    [
        ("torrance_sparrow", 0.4, 0.2),
        ("torrance_sparrow", 0.4, 0.05),
        ("ward", 0.4, 0.15),
        ("ward_normalised", 0.4, 0.15),
        ("lambertian", 0.0, 0.1),
    ],
)
@pytest.mark.parametrize("roulette", [False, True])
def test_one_scattering_carries_the_directional_albedo(model, ps, sigma, roulette):
    """The mean weight of one scattering (one-sample component selection, with or without Russian roulette)
    is the directional albedo of the BRDF, by quadrature of torchrefl.core.brdf; the part linear in Pd is
    exactly one per unit Pd; directions are unit and above the surface."""
    s, _, pt = fold_setup(model)
    T = s.num_texels
    pd = 0.5
    tables = ScatterTables.build(pt.lobe, TexelMaterial.from_tensors(*material(T, pd, ps, sigma)))
    t0 = 5 * 48 + 10  # on the floor, normal +z, away from the fold
    n = s.normals[t0].numpy()
    wi = np.array([np.sin(0.6), 0.0, np.cos(0.6)])
    N = 400_000
    col = lambda v: np.repeat(np.asarray(v, dtype=np.float32)[:, None], N, 1)
    u = np.random.default_rng(1).random((4, N), dtype=np.float32)
    origin, d, power, per_pd, emitter, path = pt.scatter(
        np.full(N, t0, np.int32),
        col(s.positions[t0].numpy()),
        col(wi),
        col(n),
        np.full(N, np.dot(n, wi), np.float32),
        None,
        np.ones((3, N), np.float32),
        tables,
        u,
        roulette,
    )
    assert power.dtype == np.float32 and np.isfinite(power).all() and (emitter == t0).all()
    # a survivor is flagged exactly when it took the lobe (the lobe's photons carry no Pd-linear flux)
    assert np.array_equal(path, (per_pd == 0).all(0)) and (path.any() == (ps > 0))
    np.testing.assert_allclose(np.linalg.norm(d, axis=0), 1, atol=1e-5)
    w = np.zeros(N)
    w[: power.shape[1]] = power[0]  # dead photons carry zero
    expected = directional_albedo(model, n, wi, pd, ps, sigma)
    err = w.std() / np.sqrt(N)
    assert abs(w.mean() - expected) < 4 * err + 1e-3 * expected, (w.mean(), expected, err)
    k = np.zeros(N)
    k[: per_pd.shape[1]] = per_pd[0]
    assert abs(k.mean() - 1.0) <= 4 * k.std() / np.sqrt(N) + 1e-6, k.mean()


def test_component_probabilities_at_the_extremes_stay_finite():
    """A texel with a vanishing but positive Ps is still sampled specularly with a probability the float32
    uniforms can realise (>= 2^-24, never a denormal): even the smallest uniform (0) gives a finite weight;
    Pd = 0 or Ps = 0 texels scatter finitely too."""
    s, _, pt = fold_setup("torrance_sparrow")
    T = s.num_texels
    t0 = 5 * 48 + 10
    n, wi = s.normals[t0].numpy(), np.array([np.sin(0.6), 0.0, np.cos(0.6)])
    N = 1000
    col = lambda v: np.repeat(np.asarray(v, dtype=np.float32)[:, None], N, 1)
    for pd, ps in ((0.5, 1e-40), (0.5, 1e-30), (1e-12, 0.5), (0.0, 0.5), (0.5, 0.0), (0.0, 0.0)):
        tables = ScatterTables.build(pt.lobe, TexelMaterial.from_tensors(*material(T, pd, ps, 0.1)))
        assert np.float64(tables.q[t0]) * 2**24 == np.ceil(np.float64(tables.q[t0]) * 2**24)  # on the uniforms' grid
        u = np.random.default_rng(0).random((4, N), dtype=np.float32)
        u[2] = 0.0  # the smallest uniform: specular wherever q > 0
        out = pt.scatter(
            np.full(N, t0, np.int32),
            col(s.positions[t0].numpy()),
            col(wi),
            col(n),
            np.full(N, np.dot(n, wi), np.float32),
            None,
            np.ones((3, N), np.float32),
            tables,
            u,
            True,
        )
        assert all(np.isfinite(x).all() for x in out[:4]), (pd, ps)


def test_closed_sphere_energy_balance():
    """Inside a closed diffuse sphere every photon is eventually absorbed: the stored indirect flux is
    rho / (1 - rho) times the direct flux, with Russian roulette and for rho near 1."""
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=50.0)
    V = len(mesh.vertices)
    normals = -mesh.vertex_normals  # the inside
    s = Surface(
        (1, V),
        torch.arange(V),
        torch.tensor(mesh.vertices),
        torch.tensor(normals),
        torch.ones(V, dtype=torch.float64),
        mesh.vertices,
        mesh.faces[:, ::-1].copy(),
    )
    pt = PhotonTracer(
        RayTracer(s.mesh_vertices, s.mesh_faces),
        s.texel_index.numpy(),
        s.positions.numpy(),
        s.normals.numpy(),
        "lambertian",
        offset=1e-3,
        max_bounces=400,
    )
    source = np.array([[10.0, -5.0, 3.0]])
    direct = pt.landing(source[0]).sum()
    for rho in (0.5, 0.95):
        mat = TexelMaterial.from_tensors(*material(V, rho))
        hits = pt.trace(source, np.ones((1, 3)), 200_000, mat, seed=1)
        stored = hits.power[:, 0].sum()
        expected = direct * rho / (1 - rho)
        # standard error: roughly sqrt(mean bounces) / sqrt(N) of the total
        assert stored == pytest.approx(expected, rel=0.02 if rho == 0.5 else 0.05)
        assert np.isfinite(hits.power).all()


def test_converges_to_the_radiosity_solution_like_one_over_sqrt_n():
    s, obs, pt = fold_setup()
    H, W = s.grid_shape
    H_rad = radiosity_irradiance(s, obs, 0.6)
    H_ref = photon_irradiance(s, obs, pt, 2_560_000, seed=99)[0].irradiance[0, :, 0]
    keep = away_from_fold(H, W)
    rel = lambda a, b: float((blocks(a, H, W) - blocks(b, H, W))[keep].norm() / blocks(b, H, W)[keep].norm())
    errors = {
        n: rel(photon_irradiance(s, obs, pt, n, seed=5)[0].irradiance[0, :, 0], H_ref)
        for n in (10_000, 40_000, 160_000)
    }
    # statistical error falls like 1/sqrt(N): a factor ~2 per 4x photons
    for a, b in ((10_000, 40_000), (40_000, 160_000)):
        assert 1.4 < errors[a] / errors[b] < 2.9, errors
    # and the estimate converges to the radiosity solution (form factors by 4096 rays per texel)
    assert rel(H_ref, H_rad) < 0.03


def test_glossy_indirect_light_matches_the_path_tracer():
    """The photon level's reflected indirect light (cache + differentiable gather) against the
    synthetic renderer's camera paths on a glossy fold, away from the fold line."""
    brdf = "torrance_sparrow"
    s, obs, pt = fold_setup(brdf)
    H, W = s.grid_shape
    T = s.num_texels
    pd, ps, sigma = material(T, 0.5, 0.4, 0.15)
    cache, _ = photon_irradiance(s, obs, pt, 1_000_000, seed=2, brdf=brdf, pd=0.5, ps=0.4, sigma=0.15)
    ours = indirect_radiance(cache, obs.kappa, pd, ps, sigma)[0, :, 0]

    n_np = s.normals.numpy()
    plate = lambda y: np.where((y[:, 2] < -y[:, 0])[:, None], n_np[0], n_np[-1])
    mat = lambda y, tri: {
        "pd": np.full((len(y), 3), 0.5),
        "ps": np.full((len(y), 3), 0.4),
        "sigma": np.full(len(y), 0.15),
    }
    r = IndirectRenderer(
        RayTracer(s.mesh_vertices, s.mesh_faces), lambda y, tri: plate(y), mat, brdf, offset=1e-3, seed=4
    )
    g = r.render(
        s.positions.numpy(),
        n_np,
        obs.view_dir.numpy(),
        np.full((T, 3), 0.5),
        np.full((T, 3), 0.4),
        np.full(T, 0.15),
        np.broadcast_to(LIGHT[0], (1, T, 3)),
        n_paths=256,
    )
    theirs = torch.as_tensor(g[0, :, 0]) * float(obs.kappa[0]) * 1e4
    keep = away_from_fold(H, W)
    a, b = blocks(ours, H, W)[keep], blocks(theirs, H, W)[keep]
    assert float((a - b).norm() / b.norm()) < 0.06
    assert float(a.sum() / b.sum()) == pytest.approx(1.0, abs=0.03)


def test_same_seed_same_result_whatever_the_threads():
    s, obs, pt1 = fold_setup(threads=1)
    _, _, pt2 = fold_setup(threads=2)
    c1, h1 = photon_irradiance(s, obs, pt1, 300_000, seed=7)
    c2, h2 = photon_irradiance(s, obs, pt2, 300_000, seed=7)
    c3, _ = photon_irradiance(s, obs, pt2, 300_000, seed=8)
    assert np.array_equal(h1.texel, h2.texel) and np.array_equal(h1.power, h2.power)
    torch.testing.assert_close(c1.irradiance, c2.irradiance, rtol=0, atol=0)
    assert not torch.equal(c1.irradiance, c3.irradiance)


def test_a_light_almost_touching_the_surface_stays_finite():
    s, _, pt = fold_setup()
    source = s.positions[100].numpy() + 1e-4 * s.normals[100].numpy()
    a = pt.landing(source)
    assert np.isfinite(a).all() and a.sum() > 0
    mat = TexelMaterial.from_tensors(*material(s.num_texels, 1.0, 0.5, 0.01))
    hits = pt.trace(source[None], np.ones((1, 3)), 50_000, mat, seed=0)
    assert np.isfinite(hits.power).all() and np.isfinite(hits.direction).all()


def test_a_mesh_that_is_not_the_texel_grid_is_refused():
    s = fold_surface(8, 8)
    faces = np.vstack([s.mesh_faces, [[0, 1, 70]]])
    verts = np.vstack([s.mesh_vertices, np.zeros((8, 3))])
    with pytest.raises(Exception, match="not a mesh vertex|not texels"):
        PhotonTracer(
            RayTracer(verts, faces),
            s.texel_index.numpy()[:60],
            s.positions.numpy()[:60],
            s.normals.numpy()[:60],
            "lambertian",
        )


def test_rays_that_reach_the_back_of_the_scanned_surface_are_counted():
    """Two parallel sheets scanned from above (normals +z), lit between them: photons scattered up from the
    lower sheet meet the underside of the upper one, which the scan never saw: absorbed and counted in
    back_hits. On the open fold (every surface seen from the front) none are."""
    from torchrefl.geometry.range_mesh import grid_triangulation, texel_areas

    H, W = 20, 20
    x = np.linspace(-30, 30, W)
    y = np.tile(np.linspace(-30, 30, H // 2), 2)
    X, Y = np.meshgrid(x, y)
    Z = np.where(np.arange(H)[:, None] < H // 2, 0.0, 10.0) * np.ones((1, W))
    pts = np.stack([X, Y, Z], -1)
    valid = np.ones((H, W), bool)
    verts, faces = grid_triangulation(pts, valid)
    nrm = np.broadcast_to(np.array([0.0, 0.0, 1.0]), (H * W, 3)).copy()
    s = Surface(
        (H, W),
        torch.arange(H * W),
        torch.tensor(pts.reshape(-1, 3)),
        torch.tensor(nrm),
        torch.tensor(texel_areas(pts, valid).reshape(-1)),
        verts,
        faces,
    )
    pt = PhotonTracer(
        RayTracer(s.mesh_vertices, s.mesh_faces),
        s.texel_index.numpy(),
        s.positions.numpy(),
        s.normals.numpy(),
        "lambertian",
        offset=1e-3,
    )
    mat = TexelMaterial.from_tensors(*material(s.num_texels, 0.8))
    hits = pt.trace(np.array([[0.0, 0.0, 5.0]]), np.ones((1, 3)), 50_000, mat, seed=0)
    assert hits.back_hits > 0.5 * hits.rays
    s2, obs, pt2 = fold_setup()
    src = light_sources(s2, obs, 1)
    open_hits = pt2.trace(
        src.positions.reshape(-1, 3),
        src.intensity,
        50_000,
        TexelMaterial.from_tensors(*material(s2.num_texels, 0.8)),
        seed=0,
    )
    assert open_hits.back_hits < 0.01 * open_hits.rays and open_hits.rays > 10_000


def test_paths_are_flagged_specular_exactly_when_a_scattering_took_the_lobe():
    """PhotonHits.specular_path: never on a Lambertian surface, always where there is no diffuse part,
    both on a surface with both (one-sample component selection)."""
    s, obs, pt = fold_setup("lambertian")
    _, hits = photon_irradiance(s, obs, pt, 20_000)
    assert hits.count > 0 and not hits.specular_path.any()
    s, obs, pt = fold_setup("torrance_sparrow")
    _, hits = photon_irradiance(s, obs, pt, 20_000, brdf="torrance_sparrow", pd=0.0, ps=0.8, sigma=0.2)
    assert hits.count > 0 and hits.specular_path.all()
    _, hits = photon_irradiance(s, obs, pt, 20_000, brdf="torrance_sparrow", pd=0.5, ps=0.4, sigma=0.15)
    assert 0.05 < hits.specular_path.mean() < 0.95
    assert len(hits.specular_path) == hits.count


def test_all_diffuse_paths_of_a_glossy_surface_converge_to_the_radiosity_solution():
    """The premise of photon.diffuse_paths=radiosity: on a glossy fold the photons whose every scattering was
    diffuse carry, in expectation, exactly the radiosity level's irradiance for rho = Pd (the diffuse choice
    weighs Pd / (1 - q) with probability 1 - q), so the radiosity solution may replace them; the paths with a
    specular scattering are what remains for the photons."""
    brdf = "torrance_sparrow"
    s, obs, pt = fold_setup(brdf)
    H, W = s.grid_shape
    T = s.num_texels
    H_rad = radiosity_irradiance(s, obs, 0.5)
    cache, hits = photon_irradiance(s, obs, pt, 1_500_000, seed=7, brdf=brdf, pd=0.5, ps=0.4, sigma=0.15)
    src = light_sources(s, obs, 8)
    spec_only = build_cache(
        hits, src, pt.areas, s.normals, obs.view_dir, obs.valid, brdf, np.full(T, 0.15), 0.6, 0.02, diffuse_paths=False
    )
    H_all = cache.irradiance[0, :, 0]
    H_spec = spec_only.irradiance[0, :, 0]
    H_diffuse_paths = H_all - H_spec
    keep = away_from_fold(H, W)
    rel = lambda a, b: float((blocks(a, H, W) - blocks(b, H, W))[keep].norm() / blocks(b, H, W)[keep].norm())
    assert float(H_spec.sum() / H_all.sum()) > 0.1  # the glossy fold has specular paths to leave to photons
    assert rel(H_diffuse_paths, H_rad) < 0.04
    # the hybrid total is the photon total (up to the photons' own noise)
    assert rel(H_spec + H_rad, H_all) < 0.04
    # and the specular entries (the receiver's lobe) still come from every photon
    torch.testing.assert_close(spec_only.entry_weight, cache.entry_weight)


def test_a_ray_that_lands_on_the_strip_across_the_fold_goes_to_the_side_that_faces_it():
    """The mesh cuts the fold's corner with faces from the floor's last texel column to the wall's first. A ray
    from the floor that lands on such a face next to a floor corner would, on the real object, reach the wall:
    with its direction hit_texels hands it to the wall texel of that face (and a ray from the wall to the
    floor texel), without it to the nearest corner; on flat faces the direction changes nothing."""
    s, obs, pt = fold_setup(H=4, W=8)
    H, W = s.grid_shape
    col = s.texel_index.numpy() % W
    faces = pt.faces
    fcol = col[pt.vertex_texel[faces]]  # (F, 3) corner columns
    bridge = np.flatnonzero((fcol.min(1) == W // 2 - 1) & (fcol.max(1) == W // 2))
    flat = np.flatnonzero(fcol.max(1) < W // 2 - 1)
    assert bridge.size and flat.size
    for side, d in (("floor", np.array([1.0, 0.0, 0.2])), ("wall", np.array([-0.2, 0.0, -1.0]))):
        # the ray leaves the floor (+z) towards the wall (+x), or the wall (-x) towards the floor (-z)
        d = d / np.linalg.norm(d)
        tri = bridge.repeat(3)
        k = np.tile(np.arange(3), bridge.size)
        bary = np.full((tri.size, 3), 0.1)
        bary[np.arange(tri.size), k] = 0.8  # next to each corner in turn
        u, v = bary[:, 1], bary[:, 2]
        plain, _ = pt.hit_texels(tri, u, v)
        ruled, _ = pt.hit_texels(tri, u, v, np.repeat(d[:, None], tri.size, 1))
        nearest = pt.vertex_texel[faces[tri, k]]
        assert np.array_equal(plain, nearest)
        facing = s.normals.numpy()[ruled] @ d
        assert bool((facing < 0).all()), side  # every hit on the side facing the ray
        own = s.normals.numpy()[nearest] @ d < 0
        assert np.array_equal(ruled[own], nearest[own]) and bool((ruled[~own] != nearest[~own]).all())
    u = np.full(flat.size, 0.2)
    a, _ = pt.hit_texels(flat, u, u)
    b, _ = pt.hit_texels(flat, u, u, np.repeat(np.array([[0.3], [0.0], [-1.0]]), flat.size, 1))
    assert np.array_equal(a, b)
