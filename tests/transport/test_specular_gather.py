"""photon.specular_gather: the receiving texel's specular reflection of the all-diffuse paths' light, gathered
from the radiosity level's radiance instead of the photons. Against the photons' own estimate (the same
expectation), the path tracer (the synthetic renderer's ground truth), a slow per-sample reference of the
entries with co-rotating light maps, and the photons' noise; exactly the flagged photons stay in the
specular entries; clear errors; finite values at the extremes."""

import dataclasses
import math

import numpy as np
import pytest
import torch
from test_photon_trace import LIGHT, away_from_fold, blocks, fold_setup, material

from torchrefl.core import brdf as brdf_mod
from torchrefl.core.rays import RayTracer
from torchrefl.errors import ConfigError
from torchrefl.synthetic.path_tracer import IndirectRenderer
from torchrefl.transport.cache_build import build_cache
from torchrefl.transport.form_factors import form_factors_for_surface
from torchrefl.transport.light_maps import light_sources
from torchrefl.transport.local import local_terms
from torchrefl.transport.photon_cache import indirect_radiance
from torchrefl.transport.photon_material import TexelMaterial
from torchrefl.transport.radiosity_level import PatchMap, direct_irradiance, indirect_irradiance
from torchrefl.transport.specular_gather import SpecularGather

BRDF = "torrance_sparrow"
PD, PS, SIGMA = 0.5, 0.4, 0.15


@pytest.fixture(scope="module")
def glossy_fold():
    """The glossy fold of test_photon_trace with the radiosity level's all-diffuse radiance (one texel per patch,
    4096 rays) and one photon trace (flags recorded)."""
    s, obs, pt = fold_setup(BRDF)
    T = s.num_texels
    pd, ps, sigma = material(T, PD, PS, SIGMA)
    patches, F = form_factors_for_surface(
        s, RayTracer(s.mesh_vertices, s.mesh_faces), patch_size=1, samples_per_patch=4096, seed=3
    )
    pm = PatchMap(patches.texel_patch, s.areas.double(), patches.num_patches)
    terms = local_terms("lambertian", s.normals, obs)
    H_maps = indirect_irradiance(terms, obs.kappa, pd, pm, F.double(), per_map=True)
    radiance = (pd[None, None] * (direct_irradiance(terms, obs.kappa)[:, None] + H_maps) / math.pi).numpy()
    src = light_sources(s, obs, 8)
    mat = TexelMaterial.from_tensors(pd, ps, sigma)
    trace = lambda n, seed: pt.trace(
        src.positions.reshape(-1, 3), np.repeat(src.intensity, src.num_maps, 0), n, mat, seed=seed
    )
    return dict(
        s=s,
        obs=obs,
        pt=pt,
        pd=pd,
        ps=ps,
        sigma=sigma,
        src=src,
        radiance=radiance,
        trace=trace,
        H=indirect_irradiance(terms, obs.kappa, pd, pm, F.double()),
    )


def cache_of(f, hits, **kw):
    T = f["s"].num_texels
    return build_cache(
        hits,
        f["src"],
        f["pt"].areas,
        f["s"].normals,
        f["obs"].view_dir,
        f["obs"].valid,
        BRDF,
        np.full(T, SIGMA),
        0.6,
        0.02,
        **kw,
    )


def gathered(f, samples=64, seed=0, sigma=SIGMA):
    """(entry_obs, theta_h, weight) of the gather on the fold."""
    T = f["s"].num_texels
    g = SpecularGather(f["pt"], f["obs"].view_dir.numpy(), f["obs"].valid.numpy(), BRDF, samples, 0.02, 0.6, seed=seed)
    return g.entries(g.directions(np.full(T, sigma)), f["radiance"], np.ones((1, T)), np.full(T, sigma))


def with_entries(cache, entries, irradiance=None):
    obs, th, w = entries
    return dataclasses.replace(
        cache,
        irradiance=cache.irradiance if irradiance is None else irradiance,
        entry_obs=torch.cat([cache.entry_obs, torch.from_numpy(obs)]),
        entry_theta_h=torch.cat([cache.entry_theta_h, torch.from_numpy(th)]),
        entry_weight=torch.cat([cache.entry_weight, torch.from_numpy(w)]),
    )


def specular(f, cache):
    """(T,) the specular part of the reflected indirect light (first light, red)."""
    return indirect_radiance(cache, f["obs"].kappa, torch.zeros_like(f["pd"]), f["ps"], f["sigma"])[0, :, 0]


def test_gather_plus_flagged_photons_matches_the_photons_and_the_path_tracer(glossy_fold):
    """The hybrid (radiosity H + flagged photons, gathered + flagged specular entries) against (a) the photons
    alone, whose specular entries estimate the same sum, and (b) the synthetic renderer's camera paths, the
    whole reflected indirect light, away from the fold line."""
    f = glossy_fold
    s, obs = f["s"], f["obs"]
    H, W = s.grid_shape
    T = s.num_texels
    keep = away_from_fold(H, W)
    photons = cache_of(f, f["trace"](1_000_000, 2))
    flagged = cache_of(f, f["trace"](400_000, 5), diffuse_paths=False, specular_paths_only=True)
    hybrid = with_entries(flagged, gathered(f), irradiance=flagged.irradiance + f["H"])
    a, b = blocks(specular(f, hybrid), H, W)[keep], blocks(specular(f, photons), H, W)[keep]
    assert float((a - b).norm() / b.norm()) < 0.06
    assert float(a.sum() / b.sum()) == pytest.approx(1.0, abs=0.02)
    # the gathered part is most of it on this fold: the all-diffuse paths dominate the specular reflection too
    gather_only = with_entries(
        dataclasses.replace(
            flagged,
            entry_obs=flagged.entry_obs[:0],
            entry_theta_h=flagged.entry_theta_h[:0],
            entry_weight=flagged.entry_weight[:0],
        ),
        gathered(f),
    )
    assert 0.6 < float(specular(f, gather_only).sum() / specular(f, hybrid).sum()) < 0.95

    ours = indirect_radiance(hybrid, obs.kappa, f["pd"], f["ps"], f["sigma"])[0, :, 0]
    n_np = s.normals.numpy()
    plate = lambda y: np.where((y[:, 2] < -y[:, 0])[:, None], n_np[0], n_np[-1])
    mat = lambda y, tri: {
        "pd": np.full((len(y), 3), PD),
        "ps": np.full((len(y), 3), PS),
        "sigma": np.full(len(y), SIGMA),
    }
    r = IndirectRenderer(
        RayTracer(s.mesh_vertices, s.mesh_faces), lambda y, tri: plate(y), mat, BRDF, offset=1e-3, seed=4
    )
    g = r.render(
        s.positions.numpy(),
        n_np,
        obs.view_dir.numpy(),
        np.full((T, 3), PD),
        np.full((T, 3), PS),
        np.full(T, SIGMA),
        np.broadcast_to(LIGHT[0], (1, T, 3)),
        n_paths=256,
    )
    theirs = torch.as_tensor(g[0, :, 0]) * float(obs.kappa[0]) * 1e4
    a, b = blocks(ours, H, W)[keep], blocks(theirs, H, W)[keep]
    assert float((a - b).norm() / b.norm()) < 0.06
    assert float(a.sum() / b.sum()) == pytest.approx(1.0, abs=0.03)


def test_gathered_entries_are_far_less_noisy_than_the_photons(glossy_fold):
    """Per texel, two seeds of the gather (256 directions) agree far better than two photon traces (400 000 photons
    per light: about 10x the fold's texels) do on the same specular sum: the noise that biases Ps down."""
    f = glossy_fold
    seen = f["obs"].valid[0]
    empty = cache_of(f, f["trace"](1000, 0), specular_paths_only=True)
    empty = dataclasses.replace(
        empty, entry_obs=empty.entry_obs[:0], entry_theta_h=empty.entry_theta_h[:0], entry_weight=empty.entry_weight[:0]
    )
    g0, g1 = (specular(f, with_entries(empty, gathered(f, samples=256, seed=k))) for k in (0, 1))
    p0, p1 = (specular(f, cache_of(f, f["trace"](400_000, k))) for k in (11, 12))
    spread = lambda x, y: float(((x - y) / (0.5 * (x + y)).clamp_min(1e-12))[seen & (x + y > 0)].std())
    gather_noise, photon_noise = spread(g0, g1), spread(p0, p1)
    assert gather_noise < 0.06 and photon_noise > 5 * gather_noise, (gather_noise, photon_noise)


def test_flagged_photons_alone_stay_in_the_specular_entries(glossy_fold):
    """build_cache(specular_paths_only=True) keeps exactly the specular entries of the photons whose path had a
    specular scattering; H is untouched by it."""
    f = glossy_fold
    hits = f["trace"](100_000, 3)
    flagged = hits.specular_path
    assert 0 < flagged.sum() < hits.count
    only = cache_of(f, hits, specular_paths_only=True)
    sub = lambda a: None if a is None else a[flagged]
    subset = dataclasses.replace(
        hits,
        source=sub(hits.source),
        texel=sub(hits.texel),
        direction=sub(hits.direction),
        power=sub(hits.power),
        emitter=sub(hits.emitter),
        diffuse_per_pd=sub(hits.diffuse_per_pd),
        specular_path=sub(flagged),
        density_weight=sub(hits.density_weight),
    )
    torch.testing.assert_close(specular(f, only), specular(f, cache_of(f, subset)))
    torch.testing.assert_close(only.irradiance, cache_of(f, hits).irradiance)
    with pytest.raises(ValueError, match="specular_path"):
        cache_of(f, dataclasses.replace(hits, specular_path=None), specular_paths_only=True)


def test_entries_with_moving_lights_match_a_per_sample_reference(glossy_fold):
    """entries() on two lights and three emitter maps with tent weights: the merged entries' sum of
    D(theta; sigma') * weight per observation equals the per-sample sum of D G / (N pdf) times the tent-weighted
    radiance of the texel hit, at a roughness sigma' other than the one sampled; only the observations kept for
    a light get its entries."""
    f = glossy_fold
    s = f["s"]
    T = s.num_texels
    P, K = 2, 3
    rng = np.random.default_rng(0)
    # one colour (merging shares one mean theta_h between the channels): the paper's case
    radiance = rng.uniform(0.1, 1.0, (P, K, T, 1)) * np.array([1.0, 0.8, 0.6])
    col = (s.texel_index.numpy() % s.grid_shape[1]) / (s.grid_shape[1] - 1) * (K - 1)
    k0 = np.minimum(np.floor(col).astype(int), K - 2)
    weights = np.zeros((K, T))
    weights[k0, np.arange(T)] = 1 - (col - k0)
    weights[k0 + 1, np.arange(T)] = col - k0
    keep = np.stack([f["obs"].valid[0].numpy(), f["obs"].valid[0].numpy() & (np.arange(T) % 2 == 0)])
    g = SpecularGather(f["pt"], f["obs"].view_dir.numpy(), keep, BRDF, 8, 0.02, 0.6, seed=1)
    smp = g.directions(np.full(T, SIGMA))
    obs, theta, w = g.entries(smp, radiance, weights, np.full(T, SIGMA))
    sigma2 = 0.8 * SIGMA
    D = lambda th: brdf_mod.specular_lobe(BRDF, torch.as_tensor(th), torch.tensor(sigma2)).numpy()
    got = np.zeros((P * T, 3))
    np.add.at(got, obs, D(theta)[:, None] * w)
    want = np.zeros((P * T, 3))
    for i in range(len(smp.texel)):
        t, u = smp.texel[i], smp.hit[i]
        for p in range(P):
            if keep[p, t]:
                L = sum(weights[k, t] * radiance[p, k, u] for k in range(K))
                want[p * T + t] += D(smp.theta_h[i]) * smp.weight[i] * L
    # merging is second order in the theta_h spread within a bin: a few % only in the far tail, where D is small
    np.testing.assert_allclose(got, want, rtol=1e-2, atol=2e-3 * want.max())
    assert got.sum() == pytest.approx(want.sum(), rel=2e-3)
    assert (got[T:][~keep[1]] == 0).all() and want.max() > 0


@pytest.mark.parametrize(
    "tilts, view_of",
    [
        ([[0.0, 0.15, 0.0], [0.1, 0.0, 0.0], [0.0, 0.0, 0.0]], [0, 1, 2]),  # three cameras
        ([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.1, 0.0, 0.0]], [0, 0, 1]),  # one camera under two lights, and another
    ],
)
def test_each_image_reads_its_own_views_samples_with_its_own_light(glossy_fold, tilts, view_of):
    """Per-image views (P, T, 3), as the mesh_views kind has them: directions are drawn once per distinct view (images
    whose views are equal bit for bit, a camera's under several lights, share them: the rays of two views, not three
    images'), and each image's entries are the per-sample sum over its own view's samples with its own radiance, at
    its own predicted observations only (the merge's tolerance), never another view's; entries() reads each view's
    samples alone (it once read every sample for every image)."""
    f = glossy_fold
    s = f["s"]
    T, P = s.num_texels, 3
    rng = np.random.default_rng(2)
    radiance = rng.uniform(0.1, 1.0, (P, 1, T, 1)) * np.array([1.0, 0.8, 0.6])
    v0 = f["obs"].view_dir.numpy().reshape(-1, T, 3)[0]
    views = np.stack([v0 + np.array(d) for d in tilts])
    views /= np.linalg.norm(views, axis=-1, keepdims=True)
    keep = np.stack([f["obs"].valid[0].numpy()] * P) & (np.arange(T) % P != np.arange(P)[:, None])
    g = SpecularGather(f["pt"], views, keep, BRDF, 8, 0.02, 0.6, seed=3)
    assert g.view_of.tolist() == view_of
    smp = g.directions(np.full(T, SIGMA))
    V = max(view_of) + 1
    assert set(np.unique(smp.view)) == set(range(V))
    wanted = [keep[np.array(view_of) == v].any(0).sum() for v in range(V)]
    assert 4 * sum(wanted) < smp.rays <= 8 * sum(wanted)
    obs, theta, w = g.entries(smp, radiance, np.ones((1, T)), np.full(T, SIGMA))
    D = lambda th: brdf_mod.specular_lobe(BRDF, torch.as_tensor(th), torch.tensor(SIGMA)).numpy()
    got = np.zeros((P * T, 3))
    np.add.at(got, obs, D(theta)[:, None] * w)
    want = np.zeros((P * T, 3))
    for i in range(len(smp.texel)):
        t = smp.texel[i]
        for p in np.flatnonzero(g.view_of == smp.view[i]):
            if keep[p, t]:
                want[p * T + t] += D(smp.theta_h[i]) * smp.weight[i] * radiance[p, 0, smp.hit[i]]
    np.testing.assert_allclose(got, want, rtol=1e-2, atol=2e-3 * want.max())
    assert (got[~keep.reshape(-1)] == 0).all() and all(want[p * T : (p + 1) * T].max() > 0 for p in range(P))


@pytest.mark.parametrize("sigma", [0.01, 0.6])
def test_extreme_roughness_and_a_lobe_that_leaves_the_scene_stay_finite(glossy_fold, sigma):
    """sigma at the fit's bounds: finite, non-negative entries. Seen along its normal, each plate's mirror
    direction leaves the scene (straight up from the floor, parallel to the floor from the wall): a mirror-sharp
    lobe gathers nothing there but beside the fold line; the widest one gathers some light."""
    f = glossy_fold
    T = f["s"].num_texels
    obs, theta, w = gathered(f, samples=16, sigma=sigma)
    assert np.isfinite(w).all() and (w >= 0).all() and np.isfinite(theta).all() and len(obs) > 0
    g = SpecularGather(f["pt"], f["s"].normals.numpy(), f["obs"].valid.numpy(), BRDF, 16, 0.02, 0.6)
    obs, theta, w = g.entries(g.directions(np.full(T, sigma)), f["radiance"], np.ones((1, T)), np.full(T, sigma))
    assert np.isfinite(w).all() and len(obs) > 0
    if sigma == 0.01:  # only the texels beside the fold line see the mesh's chamfer face across the fold
        W = f["s"].grid_shape[1]
        col = f["s"].texel_index.numpy()[obs % T] % W
        assert (np.abs(col - (W - 1) / 2) < 2).all()


def test_bad_settings_give_clear_errors(glossy_fold):
    f = glossy_fold
    T = f["s"].num_texels
    with pytest.raises(ConfigError, match="photon.specular_gather"):
        SpecularGather(f["pt"], f["obs"].view_dir.numpy(), f["obs"].valid.numpy(), BRDF, 0, 0.02, 0.6)
    _, _, pt_lambert = fold_setup("lambertian")
    with pytest.raises(ConfigError, match="no specular lobe"):
        SpecularGather(pt_lambert, f["obs"].view_dir.numpy(), f["obs"].valid.numpy(), "lambertian", 8, 0.02, 0.6)
    g = SpecularGather(f["pt"], f["obs"].view_dir.numpy(), f["obs"].valid.numpy(), BRDF, 4, 0.02, 0.6)
    with pytest.raises(ValueError, match="map weights"):
        g.entries(g.directions(np.full(T, SIGMA)), f["radiance"], np.ones((2, T)), np.full(T, SIGMA))


def test_gathered_entries_keep_the_prediction_differentiable(glossy_fold):
    """float64 gradcheck of the photon level's prediction with gathered entries, in Pd, Ps and sigma."""
    f = glossy_fold
    s = f["s"]
    T = s.num_texels
    flagged = cache_of(f, f["trace"](20_000, 6), diffuse_paths=False, specular_paths_only=True)
    cache = with_entries(flagged, gathered(f, samples=8), irradiance=flagged.irradiance + f["H"])
    sel = torch.arange(0, T, 97)
    base = [x.clone() for x in (f["pd"], f["ps"], f["sigma"])]

    def fn(pd_s, ps_s, sg_s):
        pd, ps, sg = (b.clone() for b in base)
        pd[sel], ps[sel], sg[sel] = pd_s, ps_s, sg_s
        return indirect_radiance(cache, f["obs"].kappa, pd, ps, sg)[:, sel]

    args = tuple(b[sel].clone().requires_grad_(True) for b in base)
    assert torch.autograd.gradcheck(fn, args)
