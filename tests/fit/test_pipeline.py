"""The fit pipeline's choices that only show end to end."""

import math

import torch
from conftest import dome_scene, point_light_observations

from torchrefl.capture.base import Capture
from torchrefl.config import Config
from torchrefl.core.progress import Stages
from torchrefl.core.surface import Surface
from torchrefl.fit.initialise import COVER_FULL, COVER_PD_BOUND, COVER_PD_ONLY, COVER_SHARED, COVER_UNTRUSTED
from torchrefl.fit.pipeline import fit_capture, level_inputs
from torchrefl.transport.levels.photon import PhotonLevel
from torchrefl.transport.levels.radiosity import RadiosityLevel
from torchrefl.transport.local import local_terms, predict


def glossy_dome(T: int = 400, ps_true: float = 0.3, sigma_true: float = 0.08):
    """One glossy material (Pd 0.5) on a dome under lights that show highlights at only some texels: the
    Surface and the Observations."""
    nrm, pos, lights, cam = dome_scene(T=T, seed=2)
    lights = lights[[0, 4, 8, 36, 40, 44, 72, 76, 80]]
    obs = point_light_observations(nrm, pos, lights, cam, dtype=torch.float32)
    n = torch.as_tensor(nrm, dtype=torch.float32)
    terms = local_terms("torrance_sparrow", n, obs)
    pd = torch.full((T, 3), 0.5)
    obs.intensity = predict(terms, pd, torch.full((T, 3), ps_true), torch.full((T,), sigma_true))
    surface = Surface((20, 20), torch.arange(T), torch.as_tensor(pos, dtype=torch.float32), n, torch.ones(T))
    return surface, obs


def local_config(specular: str) -> Config:
    cfg = Config()
    cfg.fit.specular = specular
    cfg.fit.model = "local"
    cfg.output.progress = False
    return cfg


def test_a_shared_lobe_is_not_pulled_to_the_floor_by_texels_without_highlights():
    """One glossy material, lights that show highlights at only some texels: the shared lobe must come out
    near the truth (a per-texel prior towards the unknown texels' floor values once collapsed it to Ps ~ 0)."""
    T, ps_true, sigma_true = 400, 0.3, 0.08
    surface, obs = glossy_dome(T, ps_true, sigma_true)
    res = fit_capture(local_config("shared"), Capture(surface, obs), Stages(), lambda *a: None, torch.device("cpu"))
    assert res.init_counts["spec_known"] < T  # some texel has no specular evidence of its own
    ps = float(res.ps[0].mean())
    sigma = float(res.sigma[0])
    assert abs(ps / ps_true - 1) < 0.1 and abs(sigma / sigma_true - 1) < 0.1, (ps, sigma)


def test_coverage_says_where_ps_and_sigma_come_from_and_marks_untrusted_geometry():
    """Texels the capture left unfitted for their geometry get COVER_UNTRUSTED and no estimate; the others say
    whether their Ps and sigma were measured (their own highlights), interpolated, or the shared lobe."""
    surface, obs = glossy_dome()
    untrusted = torch.zeros(surface.num_texels, dtype=torch.bool)
    untrusted[:30] = True
    obs.valid[:, untrusted] = False
    run = lambda specular: fit_capture(
        local_config(specular),
        Capture(surface, obs, untrusted=untrusted),
        Stages(),
        lambda *a: None,
        torch.device("cpu"),
    )
    res = run("texel")
    assert (res.coverage[untrusted] == COVER_UNTRUSTED).all() and not res.estimated[untrusted].any()
    rest = res.coverage[~untrusted & res.estimated]
    assert int((rest == COVER_FULL).sum()) == res.init_counts["spec_known"]
    assert bool(((rest == COVER_PD_ONLY) | (rest == COVER_PD_BOUND)).any())
    # COVER_SHARED with per-texel lobes: texels beyond two interpolation windows of any measured one take the
    # measured texels' median lobe
    assert set(rest.tolist()) <= {COVER_PD_ONLY, COVER_FULL, COVER_PD_BOUND, COVER_SHARED}
    shared = run("shared")
    assert (shared.coverage[shared.estimated] == COVER_SHARED).all()
    assert (shared.coverage[untrusted] == COVER_UNTRUSTED).all()


def radiosity_level(cfg, s, obs) -> RadiosityLevel:
    """A prepared RadiosityLevel of surface s under obs (all observations fitted)."""
    inputs, _ = level_inputs(cfg, Capture(s, obs), lambda *a: None)
    level = RadiosityLevel(inputs)
    level.prepare()
    return level


def test_the_radiosity_level_splits_patches_at_a_fold():
    """The radiosity level splits patches at a fold: on a fold grid with 5 texel columns per plate the three 2 x 2
    blocks on the fold line are split (18 patches, not 15) and the run log says so."""
    from conftest import fold_surface

    s = fold_surface(6, 10)
    obs = point_light_observations(
        s.normals, s.positions, torch.tensor([[-40.0, 0.0, 25.0]]), torch.tensor([-150.0, 0.0, 150.0])
    )
    cfg = Config()
    cfg.radiosity.patch_size = 2
    cfg.radiosity.hemisphere_samples = 16
    level = radiosity_level(cfg, s, obs)
    assert level.patches.num_patches == 18
    assert "3 more where a block straddles a crease of > 30 deg" in level.note


def test_the_radiosity_setup_builds_a_separate_solve_matrix_when_asked():
    """radiosity.solve_samples: a second F for the solve (its rays in the log); the indirect light then differs
    from the one-matrix setup's but stays close (same patches, both estimates of the same form factors)."""
    from conftest import fold_surface

    s = fold_surface(6, 10)
    obs = point_light_observations(
        s.normals, s.positions, torch.tensor([[-40.0, 0.0, 25.0]]), torch.tensor([-150.0, 0.0, 150.0])
    )
    pd = torch.full((s.num_texels, 3), 0.7, dtype=obs.intensity.dtype)
    out = {}
    for solve in (None, 64):
        cfg = Config()
        cfg.radiosity.hemisphere_samples = 512
        cfg.radiosity.solve_samples = solve
        level = radiosity_level(cfg, s, obs)
        out[solve] = (level.indirect(pd), level.note)
    assert "the solve's: 64 rays" in out[64][1] and "the solve's" not in out[None][1]
    a, b = out[None][0], out[64][0]
    assert not torch.equal(a, b)
    assert float(((a - b).abs().sum() / a.abs().sum())) < 0.1


def test_the_photon_level_gathers_the_radiosity_radiance_when_asked():
    """photon.specular_gather: the radiosity setup's radiance is Pd (E + H) / pi with the same H as its indirect
    light, which the same call returns (static lights: one map); the photon level's cache then holds the flagged
    photons' specular entries plus the gathered ones (counted in its stats), and without the gather every photon's
    entries."""
    from conftest import fold_surface

    from torchrefl.transport.radiosity_level import direct_irradiance

    s = fold_surface(8, 16)
    obs = point_light_observations(
        s.normals, s.positions, torch.tensor([[-40.0, 0.0, 25.0]]), torch.tensor([-150.0, 0.0, 150.0])
    )
    terms = local_terms("torrance_sparrow", s.normals, obs)
    T = s.num_texels
    pd, ps, sigma = (
        torch.full((T, 3), 0.5, dtype=torch.float64),
        torch.full((T, 3), 0.3, dtype=torch.float64),
        torch.full((T,), 0.1, dtype=torch.float64),
    )
    stats = {}
    for gather in (0, 32):
        cfg = Config()
        cfg.reflectance.brdf = "torrance_sparrow"
        cfg.radiosity.hemisphere_samples = 256
        cfg.photon.diffuse_paths = "radiosity"
        cfg.photon.specular_gather = gather
        cfg.photon.photons_per_light = 20_000
        radiosity = radiosity_level(cfg, s, obs)
        indirect, radiance = radiosity.indirect, radiosity.radiance
        H, R, weights = radiance(pd)
        torch.testing.assert_close(H, indirect(pd))  # one solve serves the irradiance and the radiance
        torch.testing.assert_close(R[:, 0], pd[None] * (direct_irradiance(terms, obs.kappa) + indirect(pd)) / math.pi)
        assert weights.shape == (1, T) and bool((weights == 1).all())
        level = PhotonLevel(radiosity.inputs, radiosity)
        level.prepare()
        stats[gather] = level.refresher.cache(pd, ps, sigma, refresh=0).stats
    assert "gather_entries" not in stats[0] and stats[32]["gather_entries"] > 0 and stats[32]["gather_rays"] > 0
    assert 0 < stats[32]["specular_entries"] < stats[0]["specular_entries"]


def test_the_photon_level_logs_the_damping_it_uses():
    """photon.damping reaches the outer loop and the log: the default 0, and an explicit value."""
    from conftest import fold_surface

    s = fold_surface(6, 12, dtype=torch.float32)
    obs = point_light_observations(
        s.normals,
        s.positions,
        torch.tensor([[-40.0, 0.0, 25.0], [-30.0, 10.0, 30.0]]),
        torch.tensor([-150.0, 0.0, 150.0]),
        dtype=torch.float32,
    )
    said = {}
    for damping in (None, 0.3):
        cfg = Config()
        cfg.fit.model = "photon"
        cfg.fit.iterations = 2
        cfg.radiosity.hemisphere_samples = 32
        cfg.photon.photons_per_light = 5000
        cfg.photon.outer_iterations = 1
        cfg.photon.diffuse_paths = "radiosity"
        if damping is not None:
            cfg.photon.damping = damping
        cfg.output.progress = False
        log = []
        fit_capture(cfg, Capture(s, obs), Stages(), log.append, torch.device("cpu"))
        said[damping] = [l for l in log if "Pd damping" in l][0]
    assert "Pd damping 0 between refreshes;" in said[None]
    assert "Pd damping 0.3 between refreshes;" in said[0.3]


def test_held_out_observations_of_texels_without_an_estimate_are_counted_not_evaluated():
    """Texels that only the held-out light sees have no estimate: their held-out observations are left out of the
    held-out error (their placeholder values would dominate it) and counted."""
    surface, obs = glossy_dome()
    unseen = torch.arange(400) % 10 == 0  # every 10th texel seen by light 0 only, the held-out one
    obs.valid[1:, unseen] = False
    cfg = local_config("texel")
    cfg.fit.holdout = [0]
    res = fit_capture(cfg, Capture(surface, obs), Stages(), lambda *a: None, torch.device("cpu"))
    assert not res.estimated[unseen].any()
    assert not res.eval_mask[:, unseen].any() and res.eval_mask[0, ~unseen].any()
    rc = cfg.reflectance
    terms = local_terms(rc.brdf, surface.normals, obs)
    usable = obs.valid & (terms.cos_v > rc.min_cos_view) & (terms.cos_l > rc.min_cos_light)  # observe()'s test
    lit_unseen = int(usable[0, unseen].sum())
    assert lit_unseen > 0 and res.holdout_unestimated == lit_unseen
