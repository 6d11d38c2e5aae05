"""Each transport level's forward model at the TRUE parameters against a reference renderer that shares no
code with torchrefl (tests/reference/path_tracer.py), on a small scan of the glossy non-uniform fold.

The capture is the project's own (synthetic_cylindrical, the 'fold' object, CI-sized as test_train_radiosity's
SMALL_E); the levels are built from it as the fit builds them (fit.pipeline.level_inputs) and evaluated with the
truth maps. The reference renders the same observations: the texel positions and normals of the capture's Surface,
its view directions, each observation's light position (x + l / sqrt(falloff), as the image saw the co-rotating
light), the same kappa and Y, on the capture's texel mesh with each texel's true material. The reference uses the
capture's Surface, not the exact object, on purpose: the levels' forward model is defined on the scanned surface,
so the comparison measures their transport and not the range scan's reconstruction of the fold (a separate error).

Compared where interreflection matters: the fitted and held-out observations of texels within NEAR_MM of the fold
line, in bands of distance from it. Modes: local vs 'direct', radiosity vs 'diffuse', photon vs 'full'
(tests/reference/path_tracer.py says what each models). Noise: the reference's standard error per observation
(independent paths), the levels' from the spread over seeds (radiosity: form-factor rays; photon: photons), whose
mean is compared. A band passes when its mean difference is within TOL_MEAN of the band's interreflected light plus
K standard errors, and at least TEXEL_SHARE of its observations are within K combined standard errors plus
TOL_TEXEL of their own interreflected light, and so are TEXEL_SHARE of its highlight observations (theta_h under 20
degrees) on their own. `pytest -s` prints the table (docs/results/reference_check.md).
"""

import copy
import math

import numpy as np
import pytest
import torch
from reference.path_tracer import ReferenceRenderer, cosine_weighted_brdf, scatter

from torchrefl.capture import cylindrical_scan
from torchrefl.capture.base import Capture
from torchrefl.config import Config
from torchrefl.core.brdf import specular_lobe
from torchrefl.core.params import TexelParams
from torchrefl.core.progress import Stages
from torchrefl.fit.pipeline import level_inputs
from torchrefl.synthetic.capture import synthetic_capture
from torchrefl.synthetic.objects import make_object
from torchrefl.transport.levels.base import IndirectTerms
from torchrefl.transport.levels.local import LocalLevel
from torchrefl.transport.levels.photon import PhotonLevel
from torchrefl.transport.levels.radiosity import RadiosityLevel

SCAN = {
    "object": "fold",
    "columns": 128,
    "rows": 112,
    "angle_step_deg": 2.8,
    "height_step_mm": 2.24,
    "supersample": 1,
    "indirect_samples": 0,  # the images are not compared: only the geometry and the truth are used
    "noise_dn": 0.0,
}
LIGHTS = 6  # selection.max_lights: the selected lights include highlights near the fold (asserted)
NEAR_MM = 12.0
BANDS = ((0.0, 3.0), (3.0, 6.0), (6.0, 12.0))  # mm from the fold line; 0-3 is the texel row next to the fold
SAMPLES = 1024  # reference paths per texel
SEEDS = {"radiosity": 2, "photon": 4, "photon_hybrid": 2}
K = 3.0
TOL_MEAN = 0.05  # of the band's interreflected light
TOL_TEXEL = 0.15  # of the observation's interreflected light
TEXEL_SHARE = 0.95


def fold_capture():
    cfg = Config()
    cfg.seed = 0
    cfg.threads = 1
    cfg.dtype = "float64"
    cfg.capture.kind = "synthetic_cylindrical"
    for key, value in SCAN.items():
        setattr(cfg.synthetic, key, value)
    cfg.selection.max_lights = LIGHTS
    cfg.output.progress = False
    cfg.radiosity.patch_size = 1  # one texel per patch: the transport, not the 2x2 blocks (docs/results)
    cfg.geometry.median_size = 5  # the rounded fold the page measures (auto would skip the median: no range noise)
    return cfg


def level_for(cfg, capture: Capture, name: str, seed: int):
    """The level `name` (local, radiosity, photon: every path from photons, photon.diffuse_paths photons with
    smoothing 1 and specular_smoothing 0; photon_hybrid: the photon.* defaults, diffuse_paths radiosity and
    specular_gather 64, automatic density kernels), prepared."""
    c = copy.deepcopy(cfg)
    c.seed = seed
    if name == "photon":
        c.photon.diffuse_paths, c.photon.specular_gather = "photons", 0
        # pinned: the default kernels (2, 1) bias the photons-only H 3-6 mm from the fold by -4 points (docs/results)
        c.photon.smoothing, c.photon.specular_smoothing = 1.0, 0.0
    inputs, _ = level_inputs(c, capture, lambda *a: None)
    if name == "local":
        return LocalLevel(inputs)
    radiosity = RadiosityLevel(inputs)
    if name != "photon":  # the pure photon level does not use it
        radiosity.prepare()
    if name == "radiosity":
        return radiosity
    level = PhotonLevel(inputs, radiosity)
    level.prepare()
    return level


def predict_at(level, truth, ps_scale=1.0):
    pd, ps, sigma = truth
    if isinstance(level, PhotonLevel) and level.cache is None:
        rc = level.inputs.cfg.reflectance
        level.refresh(TexelParams(pd, ps, sigma, rc.sigma_min, rc.sigma_max), 0)  # the cache traced at the truth
    with torch.no_grad():
        return level.predict(pd, ps * ps_scale, sigma).numpy()


def reference_inputs(capture: Capture, truth, hit_normals: str = "face"):
    """The reference renderer's scene (the capture's texel mesh, each vertex a texel with its truth) and the
    observed points' geometry, as numpy arrays."""
    s, obs = capture.surface, capture.obs
    ti = s.texel_index.numpy()
    V = np.asarray(s.mesh_vertices, dtype=np.float64)
    vn, vpd, vps, vsg = np.zeros((len(V), 3)), np.zeros((len(V), 3)), np.zeros((len(V), 3)), np.full(len(V), 0.1)
    vn[ti], vpd[ti], vps[ti], vsg[ti] = s.normals.double().numpy(), *(t.numpy() for t in truth)  # off-scan: unused
    renderer = ReferenceRenderer(V, s.mesh_faces, vn, vpd, vps, vsg, offset=0.01, seed=1, hit_normals=hit_normals)
    x = s.positions.double()
    lights = (x[None] + obs.light_dir.double() / obs.falloff.double().sqrt()[..., None]).numpy()
    geometry = {
        "points": x.numpy(),
        "normals": s.normals.double().numpy(),
        "views": obs.view_dir.double().numpy(),
        "lights": lights,
        "intensity": obs.light_intensity.double().numpy(),
        "kappa": obs.kappa.double().numpy(),
    }
    return renderer, geometry


def render(renderer, geometry, truth, texels, mode, samples=SAMPLES):
    g = geometry
    pd, ps, sigma = (t.numpy()[texels] for t in truth)
    return renderer.render(
        g["points"][texels],
        g["normals"][texels],
        g["views"][texels],
        pd,
        ps,
        sigma,
        g["lights"][:, texels],
        g["intensity"],
        g["kappa"],
        mode,
        samples=samples,
    )


def fold_distance(points: np.ndarray) -> np.ndarray:
    info = make_object("fold").info
    rel = points - info["fold_start"]
    along = rel @ info["fold_dir"]
    return np.linalg.norm(rel - along[:, None] * info["fold_dir"][None], axis=1)


def build(
    folder, patch_size: int = 1, pd_only: bool = False, geometry: dict | None = None, hit_normals: str = "face"
) -> dict:
    """The capture, the reference's images and the levels' predictions at the truth (pd_only: Ps = 0 everywhere;
    patch_size: the radiosity level's; geometry: geometry.* options; hit_normals: the reference's). One torch
    thread (the caller restores its own)."""
    torch.set_num_threads(1)
    cfg = fold_capture()
    cfg.radiosity.patch_size = patch_size
    for key, value in (geometry or {}).items():
        setattr(cfg.geometry, key, value)
    # the transport is compared on the capture's mesh, which the reference renderer shares: keep the rounded fold's
    # texels that the loader leaves out because no range-fitting window describes them (tests/geometry tests that)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(cylindrical_scan, "unfit_windows", lambda rms, valid, *a, **k: np.zeros(np.shape(valid), bool))
        capture, _ = synthetic_capture(cfg, folder, Stages(), lambda *a: None)
    truth = tuple(capture.truth[k].double() for k in ("pd", "ps", "sigma"))
    if pd_only:
        truth = (truth[0], torch.zeros_like(truth[1]), truth[2])
    dist = fold_distance(capture.surface.positions.double().numpy())
    near = np.flatnonzero(dist < NEAR_MM)
    base = level_for(cfg, capture, "local", cfg.seed)
    keep = (base.inputs.fit_mask | base.inputs.eval_mask).numpy()[:, near]
    renderer, geometry = reference_inputs(capture, truth, hit_normals)
    ref = {mode: render(renderer, geometry, truth, near, mode) for mode in ("direct", "diffuse", "full")}
    levels = {"local": (predict_at(base, truth)[:, near], 0.0)}
    for name, n in SEEDS.items():
        runs = np.stack([predict_at(level_for(cfg, capture, name, seed), truth)[:, near] for seed in range(n)])
        levels[name] = (runs.mean(0), runs.std(0, ddof=1) / math.sqrt(n))
    return {
        "cfg": cfg,
        "capture": capture,
        "truth": truth,
        "near": near,
        "dist": dist[near],
        "keep": keep,
        "theta_h": base.inputs.terms.theta_h.numpy()[:, near],
        "ref": ref,
        "levels": levels,
    }


@pytest.fixture(scope="module")
def fold(tmp_path_factory):
    threads = torch.get_num_threads()
    try:
        out = build(tmp_path_factory.mktemp("fold"))
    finally:
        torch.set_num_threads(threads)
    print_table(out)
    return out


def agreement(fold, level, level_se, mode, band):
    """Band statistics of level - reference in `mode` over the kept observations of the band: bias (the mean
    difference over the mean interreflected light), its standard error on that scale, the share of
    observations within K combined standard errors + TOL_TEXEL of their interreflected light (all, and the
    highlights: theta_h under 20 degrees), and the band's interreflected light relative to its direct light."""
    value, se = fold["ref"][mode]
    direct = fold["ref"]["direct"][0]
    lo, hi = band
    m = fold["keep"] & ((fold["dist"] >= lo) & (fold["dist"] < hi))[None]
    m3 = np.broadcast_to(m[..., None], value.shape)
    d, ind = (level - value)[m3], (value - direct)[m3]
    comb = np.sqrt(se**2 + np.broadcast_to(level_se, value.shape) ** 2)[m3]
    ok = np.abs(d) <= K * comb + TOL_TEXEL * np.abs(ind)
    spec = np.broadcast_to((fold["theta_h"] < math.radians(20.0))[..., None], value.shape)[m3]
    return {
        "n": int(m.sum()),
        "bias": float(d.sum() / ind.sum()),
        "bias_se": float(np.sqrt((comb**2).sum()) / ind.sum()),
        "within": float(ok.mean()),
        "highlights": int(spec.sum() // 3),
        "highlights_within": float(ok[spec].mean()) if spec.any() else 1.0,
        "indirect_over_direct": float(ind.sum() / direct[m3].sum()),
        "rms": float(np.sqrt((d**2).mean()) / ind.mean()),
    }


def passes(a) -> bool:
    return (
        abs(a["bias"]) <= TOL_MEAN + K * a["bias_se"]
        and a["within"] >= TEXEL_SHARE
        and a["highlights_within"] >= TEXEL_SHARE
    )


def direct_agreement(fold) -> dict:
    """Method I against 'direct': the observations whose shadow rays disagree, the largest relative difference
    where both see the light."""
    local, _ = fold["levels"]["local"]
    direct = fold["ref"]["direct"][0]
    keep = fold["keep"]
    lit_l, lit_r = local.max(-1) > 0, direct.max(-1) > 0
    both = keep & lit_l & lit_r
    rel = np.abs(local - direct).max(-1) / np.where(lit_r, direct.max(-1), 1.0)
    return {
        "observations": int(keep.sum()),
        "lit_by_both": int(both.sum()),
        "shadow_disagreements": int((keep & (lit_l != lit_r)).sum()),
        "max_relative": float(rel[both].max()),
    }


def print_table(fold, bands=BANDS, pairs=(("radiosity", "diffuse"), ("photon", "full"), ("photon_hybrid", "full"))):
    print("\nlocal vs direct:", direct_agreement(fold))
    print(
        "level vs reference (mode) on the fold: band | obs | interreflected/direct | bias +- se | rms | within "
        "| highlights within"
    )
    for name, mode in pairs:
        for band in tuple(bands) + ((0.0, NEAR_MM),):
            a = agreement(fold, *fold["levels"][name], mode, band)
            print(
                f"{name:13s} vs {mode:7s} {band[0]:4.1f}-{band[1]:4.1f} mm | {a['n']:4d} | "
                f"{a['indirect_over_direct']:5.3f} | {a['bias']:+.3f} +- {a['bias_se']:.3f} | {a['rms']:.3f} | "
                f"{a['within']:.3f} | {a['highlights']} {a['highlights_within']:.3f}"
            )


# ---------------------------------------------------------------------------- the reference itself


def test_reference_sampler_integrates_the_brdf():
    """The reference's one-sample estimator of the directional albedo (mean of g / pdf over its own samples)
    equals a quadrature of its own g over the hemisphere, for a glossy and a diffuse direction."""
    rng = np.random.default_rng(0)
    n = np.array([[0.0, 0.0, 1.0]])
    for view_deg, pd, ps, sigma in ((20.0, 0.4, 0.45, 0.1), (65.0, 0.3, 0.3, 0.3)):
        v = np.array([[math.sin(math.radians(view_deg)), 0.0, math.cos(math.radians(view_deg))]])
        N = 400_000
        rows = lambda a: np.repeat(np.asarray(a, dtype=np.float64)[None], N, 0)
        _, w = scatter(rows(n[0]), rows(v[0]), rows([pd] * 3), rows([ps] * 3), np.full(N, sigma), False, rng)
        mc, mc_se = w[:, 0].mean(), w[:, 0].std() / math.sqrt(N)
        th, ph = np.meshgrid(np.linspace(0, math.pi / 2, 1201)[1:-1], np.linspace(0, 2 * math.pi, 1201)[:-1])
        th, ph = th.ravel(), ph.ravel()
        l = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], 1)
        M = len(l)
        g = cosine_weighted_brdf(
            np.repeat(n, M, 0), l, np.repeat(v, M, 0), np.full((M, 3), pd), np.full((M, 3), ps), np.full(M, sigma)
        )
        quad = float((g[:, 0] * np.sin(th)).sum() * (math.pi / 2 / 1200) * (2 * math.pi / 1200))
        assert abs(mc - quad) < 4 * mc_se + 2e-3 * quad, (mc, mc_se, quad)


# ---------------------------------------------------------------------------- the levels


def test_the_scene_has_highlights_and_strong_interreflection(fold):
    keep = fold["keep"]
    assert int((keep & (fold["theta_h"] < math.radians(20))).sum()) >= 20  # T_spec observations near the fold
    a = agreement(fold, *fold["levels"]["local"], "full", (0.0, NEAR_MM))
    assert a["indirect_over_direct"] > 0.2
    d = agreement(fold, *fold["levels"]["local"], "diffuse", (0.0, NEAR_MM))
    assert a["indirect_over_direct"] > 1.3 * d["indirect_over_direct"]  # specular interreflection matters


def test_local_level_is_the_direct_reference(fold):
    """Method I against 'direct' (no Monte Carlo): equal to 1e-3 relative wherever both see the light; the shadow
    rays (their own offsets) disagree on at most 0.5 % of the observations."""
    a = direct_agreement(fold)
    assert a["shadow_disagreements"] <= 0.005 * a["observations"], a
    assert a["lit_by_both"] > 1000 and a["max_relative"] < 1e-3, a


@pytest.mark.parametrize("band", BANDS, ids=lambda b: f"{b[0]:g}-{b[1]:g}mm")
def test_radiosity_level_is_the_diffuse_reference(fold, band):
    a = agreement(fold, *fold["levels"]["radiosity"], "diffuse", band)
    assert passes(a), a


@pytest.mark.parametrize("band", BANDS, ids=lambda b: f"{b[0]:g}-{b[1]:g}mm")
def test_photon_level_is_the_full_reference(fold, band):
    a = agreement(fold, *fold["levels"]["photon"], "full", band)
    assert passes(a), a


@pytest.mark.parametrize("band", BANDS, ids=lambda b: f"{b[0]:g}-{b[1]:g}mm")
def test_hybrid_photon_level_is_the_full_reference(fold, band):
    a = agreement(fold, *fold["levels"]["photon_hybrid"], "full", band)
    assert passes(a), a


# ---------------------------------------------------------------------------- the test can fail


def test_negative_controls_fail(fold):
    """The comparison catches real mistakes: direct light alone against 'full', diffuse interreflection alone
    against 'full', interreflection 15 % too strong, and Ps scaled by 1.2 (each where the level itself passes).
    The Ps control is checked in the band with the most compared highlights (at least 20), where a Ps error shows
    by construction: a band without highlights (the mixed-footprint texels are not compared) cannot catch it."""
    every = (0.0, NEAR_MM)
    local, _ = fold["levels"]["local"]
    rad, rad_se = fold["levels"]["radiosity"]
    assert passes(agreement(fold, rad, rad_se, "diffuse", every))
    assert not passes(agreement(fold, local, 0.0, "full", every))
    assert not passes(agreement(fold, rad, rad_se, "full", every))
    assert not passes(agreement(fold, local + 1.15 * (rad - local), rad_se, "diffuse", every))
    hybrid, hybrid_se = fold["levels"]["photon_hybrid"]
    band = max(BANDS, key=lambda b: agreement(fold, hybrid, hybrid_se, "full", b)["highlights"])
    a = agreement(fold, hybrid, hybrid_se, "full", band)
    assert a["highlights"] >= 20 and passes(a), (band, a)
    level = level_for(fold["cfg"], fold["capture"], "photon_hybrid", 0)
    scaled = predict_at(level, fold["truth"], ps_scale=1.2)[:, fold["near"]]
    assert not passes(agreement(fold, scaled, hybrid_se, "full", band))


if __name__ == "__main__":  # docs/results/reference_check.md: PYTHONPATH=.:tests python <this file>
    import tempfile
    from pathlib import Path

    fine = ((0.0, 3.0), (3.0, 4.5), (4.5, 6.0), (6.0, 9.0), (9.0, 12.0))
    for title, options in (
        ("glossy fold, radiosity patch_size 1", {}),
        ("Ps = 0 everywhere (diffuse transport only), radiosity patch_size 1", {"pd_only": True}),
        ("glossy fold, radiosity patch_size 2 (the default)", {"patch_size": 2}),
        ("glossy fold, the reference with the texels' normals at its hits", {"hit_normals": "vertex"}),
        (
            "glossy fold, geometry.median_size 1, crease_angle_deg 60 (a sharp fold, as the bundled Object E configs)",
            {"geometry": {"median_size": 1, "crease_angle_deg": 60.0}},
        ),
    ):
        print(f"\n== {title}")
        pairs = (("radiosity", "diffuse"), ("photon", "full"), ("photon_hybrid", "full"))
        print_table(build(Path(tempfile.mkdtemp()), **options), fine, pairs)


@pytest.mark.parametrize("name", ["local", "radiosity", "photon_hybrid"])
def test_texel_model_is_predict_with_the_indirect_light_held(fold, name):
    """TransportLevel.texel_model(pd0): at pd0 it equals predict; changing one texel's parameters changes that
    texel's images only (the per-texel solver's premise), while the radiosity level's predict also changes its
    neighbours' through the interreflection (the photon level's cache holds it between refreshes)."""
    level = level_for(fold["cfg"], fold["capture"], name, 0)
    pd, ps, sigma = fold["truth"]
    predict_at(level, fold["truth"])  # the photon level's cache traced at the truth
    pd0 = pd * 0.8
    with torch.no_grad():
        model = level.texel_model(pd0)
        torch.testing.assert_close(model(pd0, ps, sigma), level.predict(pd0, ps, sigma), rtol=1e-9, atol=1e-12)
        t = int(fold["near"][len(fold["near"]) // 2])
        pd1, ps1, sigma1 = pd0.clone(), ps.clone(), sigma.clone()
        pd1[t] *= 1.5
        ps1[t] *= 2.0
        sigma1[t] *= 0.7
        changed = (model(pd1, ps1, sigma1) - model(pd0, ps, sigma)).abs().amax((0, 2)) > 0
        assert changed.nonzero().flatten().tolist() == [t]
        if name == "radiosity":
            moved = (level.predict(pd1, ps1, sigma1) - level.predict(pd0, ps, sigma)).abs().amax((0, 2)) > 1e-9
            assert int(moved.sum()) > 1
        # texel_model(pd0, texels): the model of some texels alone gives their rows of the whole model's images
        index = torch.as_tensor(fold["near"][::3], dtype=torch.long)
        part = level.texel_model(pd0, index)(pd1[index], ps1[index], sigma1[index])
        torch.testing.assert_close(part, model(pd1, ps1, sigma1)[:, index], rtol=1e-9, atol=1e-12)
        terms = level.indirect_terms(pd0)
        if terms is not None:  # restricted by the level (specular_of) and by slicing the whole factor
            for restricted in (terms.texels(index), IndirectTerms(terms.diffuse, terms.specular).texels(index)):
                torch.testing.assert_close(restricted.specular(sigma1[index]), terms.specular(sigma1)[:, index])
            # the same factor as entries (what the LM's closed form sums), through the restriction
            e = terms.texels(index).entries_of(torch.arange(len(index)))
            n = len(index)
            lobe = specular_lobe(level.inputs.terms.brdf, e.theta_h, sigma1[index][e.obs % n])
            summed = e.weight.new_zeros(terms.diffuse.shape[0] * n, 3).index_add(0, e.obs, lobe[:, None] * e.weight)
            torch.testing.assert_close(summed.view(-1, n, 3), terms.specular(sigma1)[:, index])
