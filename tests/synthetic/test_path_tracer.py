"""Interreflection renderer of the synthetic scans: checked against analytic and independent references."""

import math

import numpy as np
import pytest
import trimesh
from scipy import stats

from torchrefl.capture.cylindrical_rig import CylindricalRig
from torchrefl.config import SyntheticConfig
from torchrefl.core.lobe_sampling import lobe_pdf, sample_lobe
from torchrefl.core.rays import RayTracer
from torchrefl.errors import GeometryError
from torchrefl.synthetic.path_tracer import IndirectRenderer
from torchrefl.synthetic.scan import SyntheticScan

LIGHTS = np.array([[0.0, 0.0, 300.0], [-150.0, 100.0, 300.0]])


def e_cfg(**kw):
    base = dict(
        object="object_e",
        columns=128,
        rows=112,
        angle_step_deg=360 / 128,
        height_step_mm=2.0,
        supersample=1,
        noise_dn=0.0,
        indirect_samples=0,
    )
    base.update(kw)
    return SyntheticConfig(**base)


def plate_geometry(scan, light_head):
    """Independent of the renderer: texel-centre points from range.npy (eq. 2.1), the inside plate each
    lies on (from Object E's defining planes), its normal, the light of its column, an analytic shadow test
    against the other plate's rectangle, and the distance to the fold line."""
    info = scan.object.info
    r = scan.range_image()
    rig = scan.rig
    S, T = np.meshgrid(rig.angles(), rig.heights())
    u, w = CylindricalRig.head_axes(S)
    x = r[..., None] * u
    x[..., 1] = -T
    f0, fd = info["fold_start"], info["fold_dir"]
    plate = np.full(r.shape, -1)
    for k in range(2):
        d = x - f0
        a = d @ info["plate_dirs"][k]
        along = d @ fd
        on = (
            (np.abs(d @ info["inside_normals"][k]) < 1e-3)
            & (a > 0.5)
            & (a < info["width"] - 0.5)
            & (along > 0.5)
            & (along < info["length"] - 0.5)
        )
        plate[on & np.isfinite(r)] = k
    lat, vert, rad = light_head
    light = rad * u + lat * w
    light[..., 1] += vert
    n = np.where((plate == 0)[..., None], info["inside_normals"][0], info["inside_normals"][1])
    to = light - x
    C = np.linalg.norm(to, axis=-1)
    cos = (n * to).sum(-1) / C
    shadow = np.zeros(r.shape, dtype=bool)
    for k in range(2):  # segment x -> light crossing the other plate's inside rectangle
        other = 1 - k
        no, d0 = info["inside_normals"][other], f0
        denom = (to * no).sum(-1)
        t = np.where(np.abs(denom) > 1e-9, ((d0 - x) * no).sum(-1) / np.where(denom == 0, 1, denom), -1)
        q = x + t[..., None] * to - f0
        a = q @ info["plate_dirs"][other]
        along = q @ fd
        hit = (
            (t > 1e-6)
            & (t < 1)
            & (a > -info["thickness"])
            & (a < info["width"])
            & (along > 0)
            & (along < info["length"])
        )
        shadow |= (plate == k) & hit
    rel = x - f0
    dist_fold = np.linalg.norm(rel - (rel @ fd)[..., None] * fd, axis=-1)
    return plate, cos, C, shadow, dist_fold


def local_pd(scan, img, light_head):
    """The local-only estimate Pd = C^2 i / (Y cos) (kappa = pi) on lit, unshadowed inside texels."""
    plate, cos, C, shadow, dist = plate_geometry(scan, light_head)
    ok = (plate >= 0) & ~shadow & (cos > 0.2)
    return np.where(ok, C**2 * img[..., 0] / (scan.cfg.light_intensity * cos), np.nan), dist


def test_zero_paths_is_the_direct_renderer_and_convex_objects_get_no_interreflection():
    # (a) Object E setup 1 without paths: exactly Pd * cos * Y / C^2 (kappa = pi) from independent geometry
    scan = SyntheticScan(e_cfg(), seed=0)
    for head in LIGHTS:
        pd, _ = local_pd(scan, scan.radiance_image(head), head)
        ok = np.isfinite(pd)
        assert ok.sum() > 800
        np.testing.assert_allclose(pd[ok], 0.8, atol=2e-4)
    # a convex ellipsoid sees nothing of itself: paths add exactly nothing
    cfg = SyntheticConfig(
        columns=64,
        rows=48,
        angle_step_deg=360 / 64,
        height_step_mm=4.0,
        size_mm=[40.0, 60.0, 30.0],
        supersample=1,
        noise_dn=0.0,
        mesh_subdivisions=4,
    )
    direct = SyntheticScan(cfg, seed=1).radiance_image(LIGHTS[1])
    cfg.indirect_samples = 16
    assert np.array_equal(SyntheticScan(cfg, seed=1).radiance_image(LIGHTS[1]), direct)


def _sphere_renderer(rho_pd, rho_ps=0.0, sigma=0.2, brdf="torrance_sparrow", radius=50.0, seed=0):
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=radius)
    inward = -np.asarray(mesh.face_normals)
    tracer = RayTracer(mesh.vertices, mesh.faces, threads=2)

    def material(points, tri):
        n = len(tri)
        return {"pd": np.full((n, 3), rho_pd), "ps": np.full((n, 3), rho_ps), "sigma": np.full(n, sigma)}

    gi = IndirectRenderer(tracer, lambda p, tri: inward[tri], material, brdf, seed=seed)
    rng = np.random.default_rng(7)
    faces = rng.choice(len(mesh.faces), 300, replace=False)
    pts = np.asarray(mesh.triangles_center)[faces]
    return gi, pts, inward[faces], material(pts, faces)


def test_closed_sphere_interreflection_matches_the_analytic_radiosity():
    # (b) inside a closed sphere with a point light at its centre: B = rho E / (1 - rho), E = Y / R^2,
    # so the multiply-bounced part of the sensor value (kappa = pi) is rho^2 E / (1 - rho)
    R, rho, n_paths = 50.0, 0.7, 64
    gi, pts, nrm, mat = _sphere_renderer(rho, radius=R)
    view = nrm.copy()
    lights = np.zeros((1, len(pts), 3))
    g = gi.render(pts, nrm, view, mat["pd"], mat["ps"], mat["sigma"], lights, n_paths)[0, :, 0] * math.pi * R**2
    expected = rho**2 / (1 - rho)  # 1.633; one bounce only would give 0.49, two 0.833
    err = g.std(ddof=1) / math.sqrt(len(g))
    assert abs(g.mean() - expected) < 4 * err + 0.005 * expected, (g.mean(), expected, err)
    assert err < 0.02 * expected


def test_glossy_path_sampling_is_unbiased_against_cosine_only_sampling():
    # the mixture (cosine + lobe) estimator and a cosine-only estimator of the same integral agree
    gi, pts, nrm, mat = _sphere_renderer(0.3, rho_ps=0.6, sigma=0.15, seed=1)
    view = nrm.copy()
    lights = np.broadcast_to(np.array([20.0, 5.0, -10.0]), (1, len(pts), 3)).copy()
    a = gi.render(pts, nrm, view, mat["pd"], mat["ps"], mat["sigma"], lights, 64)[0, :, 0]
    cos_only = IndirectRenderer(gi.tracer, gi.normal_fn, gi.material_fn, "torrance_sparrow", seed=2)
    cos_only._spec_prob = lambda pd, ps: np.zeros(len(pd))
    b = cos_only.render(pts, nrm, view, mat["pd"], mat["ps"], mat["sigma"], lights, 64)[0, :, 0]
    err = math.sqrt(a.var(ddof=1) / len(a) + b.var(ddof=1) / len(b))
    assert abs(a.mean() - b.mean()) < 4 * err, (a.mean(), b.mean(), err)


@pytest.mark.parametrize("model,sigma", [("torrance_sparrow", 0.15), ("torrance_sparrow", 0.4), ("ward", 0.12)])
def test_lobe_sampler_pdf_is_normalised_and_matches_its_histogram(model, sigma):
    # (c) quadrature of the pdf over the whole sphere, then a chi-square test of samples in (cos theta, phi) bins
    n = np.array([[0.0, 0.0, 1.0]])
    v = np.array([[math.sin(0.7), 0.0, math.cos(0.7)]])
    nc, nphi = 1200, 1200
    c = -1 + (np.arange(nc) + 0.5) * 2 / nc
    ph = (np.arange(nphi) + 0.5) * 2 * math.pi / nphi
    C, PH = np.meshgrid(c, ph, indexing="ij")
    s = np.sqrt(1 - C**2)
    L = np.stack([s * np.cos(PH), s * np.sin(PH), C], -1).reshape(-1, 3)
    N = len(L)
    p = lobe_pdf(model, np.repeat(n, N, 0), np.repeat(v, N, 0), L, np.full(N, sigma)).reshape(nc, nphi)
    total = p.sum() * (2 / nc) * (2 * math.pi / nphi)
    assert abs(total - 1) < 2e-3, total
    rng = np.random.default_rng(3)
    M = 200_000
    smp = sample_lobe(model, np.repeat(n, M, 0), np.repeat(v, M, 0), np.full(M, sigma), rng.random(M), rng.random(M))
    np.testing.assert_allclose(np.linalg.norm(smp, axis=-1), 1, atol=1e-9)
    bc, bp = 24, 24  # coarse bins = sums of quadrature cells
    expected = p.reshape(bc, nc // bc, bp, nphi // bp).sum((1, 3)) * (2 / nc) * (2 * math.pi / nphi) * M
    ic = np.clip(((smp[:, 2] + 1) / 2 * bc).astype(int), 0, bc - 1)
    ip = np.clip((np.mod(np.arctan2(smp[:, 1], smp[:, 0]), 2 * math.pi) / (2 * math.pi) * bp).astype(int), 0, bp - 1)
    observed = np.bincount(ic * bp + ip, minlength=bc * bp).reshape(bc, bp)
    big = expected > 20
    assert observed[~big].sum() < 0.01 * M
    chi2 = (((observed - expected) ** 2)[big] / expected[big]).sum()
    assert stats.chi2.sf(chi2, big.sum() - 1) > 1e-3, (chi2, big.sum())


@pytest.fixture(scope="module")
def object_e_renders():
    cfg = e_cfg(indirect_samples=128)
    scan = SyntheticScan(cfg, seed=0)
    direct = SyntheticScan(e_cfg(), seed=0)
    return scan, scan.radiance_images(LIGHTS), np.stack([direct.radiance_image(h) for h in LIGHTS])


def test_object_e_interreflection_is_strong_at_the_fold_and_biases_the_local_estimate(object_e_renders):
    # (d) the seed's Fig. 3.14 effect
    scan, full, direct = object_e_renders
    for i, head in enumerate(LIGHTS):
        pd, dist = local_pd(scan, full[i], head)
        pd0, _ = local_pd(scan, direct[i], head)
        ok = np.isfinite(pd)
        near, far = ok & (dist < 10), ok & (dist > 50)
        assert near.sum() > 50 and far.sum() > 50
        ratio = pd / pd0 - 1  # indirect / direct
        assert np.median(ratio[near]) > 0.25  # tens of percent near the fold
        assert np.median(ratio[far]) < 0.5 * np.median(ratio[near])
        assert np.median(pd[near]) > 1.1 * 0.8  # local-only Pd overestimated by >= 10 %
        assert np.all(ratio[ok] > -1e-9)


def test_same_seed_same_images_and_paths_do_not_depend_on_the_light_batch(object_e_renders):
    # (e)
    scan, full, _ = object_e_renders
    again = SyntheticScan(e_cfg(indirect_samples=128), seed=0)
    assert np.array_equal(again.radiance_image(LIGHTS[1]), full[1])
    other = SyntheticScan(e_cfg(indirect_samples=128), seed=1).radiance_image(LIGHTS[1])
    assert not np.array_equal(other, full[1])
    assert np.abs(other - full[1]).max() * 255 < 40  # only the Monte Carlo noise differs


def test_a_texels_sub_samples_share_one_stratified_set_unbiased_and_less_noisy():
    # texel values average their sub-samples; grouping their first bounces stratifies the texel's paths
    # (fewer than ungrouped: a test that fails if grouping is dropped) without moving the mean
    scan = SyntheticScan(e_cfg(supersample=2, indirect_samples=16), seed=0)
    smp = scan._subsamples()
    full = np.flatnonzero(np.bincount(smp["texel"])[smp["texel"]] == 4)
    sel = full[np.isin(smp["texel"][full], np.unique(smp["texel"][full])[::4][:400])]
    tex = smp["texel"][sel]
    H, W = scan.rig.rows, scan.rig.columns
    mat = {k: scan.truth[k].reshape((H * W,) + scan.truth[k].shape[2:])[tex] for k in ("pd", "ps", "sigma")}
    lights = scan._light_world(LIGHTS[1])[sel][None]

    def texel_means(seed, grouped, n_paths=16):
        gi = IndirectRenderer(scan.tracer, scan._normal_at, scan._material_at, scan.cfg.brdf, seed=seed)
        g = gi.render(
            smp["points"][sel],
            smp["normals"][sel],
            smp["view"][sel],
            mat["pd"],
            mat["ps"],
            mat["sigma"],
            lights,
            n_paths,
            groups=tex if grouped else None,
        )[0].mean(-1)
        return g.reshape(-1, 4).mean(1)

    noise = {}
    for grouped in (False, True):
        a, b = texel_means(1, grouped), texel_means(2, grouped)
        ok = (a + b) > 0
        noise[grouped] = np.std((a - b)[ok] / (a + b)[ok])
    assert noise[True] < 0.8 * noise[False], noise
    reference = texel_means(3, False, n_paths=256)
    grouped = np.mean([texel_means(s, True) for s in (4, 5, 6, 7)], axis=0)
    assert abs(grouped.sum() / reference.sum() - 1) < 0.01
    gi = IndirectRenderer(scan.tracer, scan._normal_at, scan._material_at, scan.cfg.brdf, seed=0)
    with pytest.raises(GeometryError, match=r"groups has shape \(3,\), expected \(4,\)"):
        gi.render(
            smp["points"][sel[:4]],
            smp["normals"][sel[:4]],
            smp["view"][sel[:4]],
            mat["pd"][:4],
            mat["ps"][:4],
            mat["sigma"][:4],
            lights[:, :4],
            4,
            groups=tex[:3],
        )


def test_mesh_objects_scan_only_in_front_of_the_axis_and_have_texel_truth():
    for name in ("object_e_glossy", "bowl"):
        scan = SyntheticScan(e_cfg(object=name), seed=0)
        r = scan.range_image()
        hit = np.isfinite(r)
        assert hit.sum() > 500 and (r[hit] > 0).all()
        assert np.array_equal(scan.truth["region"] >= 0, hit)
        assert np.isfinite(scan.truth["pd"]).all()
    assert len(np.unique(scan.truth["region"][hit])) >= 4  # the bowl's inside is non-uniform
    sd = scan.truth["sigma"][hit]
    assert sd.std() > 0.01
