"""Method III's outer loop on a diffuse fold whose images carry path-traced interreflection (the
renderer's camera paths, not the fitter's photons): the photon level removes the interreflection
bias that a local fit keeps, with both schedules; the kept parameters are the best scored; same seed,
same result."""

import copy

import numpy as np
import pytest
import torch
from conftest import fold_surface, point_light_observations

from torchrefl.capture.base import Capture
from torchrefl.config import Config
from torchrefl.core.params import TexelParams
from torchrefl.core.rays import RayTracer
from torchrefl.fit.pipeline import level_inputs, refit
from torchrefl.fit.refine import Objective, refine
from torchrefl.synthetic.path_tracer import IndirectRenderer
from torchrefl.transport.levels.photon import AVERAGE_FROM, PhotonLevel
from torchrefl.transport.levels.radiosity import RadiosityLevel
from torchrefl.transport.local import local_terms, predict

LIGHTS = np.array([[-40.0, 5.0, 50.0], [-60.0, -20.0, 30.0], [-20.0, 25.0, 70.0]])
CAMERA = np.array([-150.0, 0.0, 150.0])
PD = 0.6


@pytest.fixture(scope="module")
def scene():
    s = fold_surface(16, 32)
    T = s.num_texels
    obs = point_light_observations(s.normals, s.positions, LIGHTS, CAMERA, intensity=2e4)
    terms = local_terms("lambertian", s.normals, obs)
    pd = torch.full((T, 3), PD, dtype=torch.float64)
    zeros = torch.zeros(T, 3, dtype=torch.float64)
    sigma = torch.full((T,), 0.1, dtype=torch.float64)
    n_np = s.normals.numpy()
    plate = lambda y: np.where((y[:, 2] < -y[:, 0])[:, None], n_np[0], n_np[-1])
    mat = lambda y, tri: {"pd": np.full((len(y), 3), PD), "ps": np.zeros((len(y), 3)), "sigma": np.full(len(y), 0.1)}
    r = IndirectRenderer(
        RayTracer(s.mesh_vertices, s.mesh_faces), lambda y, tri: plate(y), mat, "lambertian", offset=1e-3, seed=11
    )
    g = r.render(
        s.positions.numpy(),
        n_np,
        obs.view_dir.numpy(),
        np.full((T, 3), PD),
        np.zeros((T, 3)),
        np.full(T, 0.1),
        np.broadcast_to(LIGHTS[:, None], (3, T, 3)),
        n_paths=512,
    )
    obs.intensity = predict(terms, pd, zeros, sigma) + obs.kappa * 2e4 * torch.as_tensor(g)
    return s, obs, terms


def photon_level(s, obs, schedule="joint", outer=2, seed=0, damping=0.0, iterations=30):
    """A prepared PhotonLevel (every path from photons) of the scene with this outer loop."""
    cfg = Config()
    cfg.seed = seed
    cfg.reflectance.brdf = "lambertian"
    cfg.fit.iterations = iterations
    for key, value in dict(
        photons_per_light=300_000,
        schedule=schedule,
        outer_iterations=outer,
        damping=damping,
        smoothing=1.0,
        diffuse_paths="photons",
        specular_gather=0,
    ).items():
        setattr(cfg.photon, key, value)
    cfg.output.progress = False
    inputs, _ = level_inputs(cfg, Capture(s, obs), lambda *a: None)
    level = PhotonLevel(inputs, RadiosityLevel(inputs))  # every path from photons: the radiosity level unused
    level.prepare()
    return level


def fit(s, obs, terms, schedule, seed=0, outer=2):
    T = s.num_texels
    start = (obs.intensity / terms.diffuse.clamp_min(1e-12))[0].clamp(0, 2)  # local closed form under light 0
    params = TexelParams(
        start, torch.full((T, 3), 0.01, dtype=torch.float64), torch.full((T,), 0.1, dtype=torch.float64), 0.01, 0.6
    )
    make = lambda model, weight: Objective(predict=model, intensity=obs.intensity, weight=weight, loss="l2")
    level = photon_level(s, obs, schedule, outer, seed)
    refit(level, params, make, level.inputs.cfg)
    return params, level


def away_from_fold(s, margin=3):
    W = s.grid_shape[1]
    col = s.texel_index % W
    return (col < W // 2 - margin) | (col >= W // 2 + margin)


def pd_error(pd, keep):
    return float(((pd[keep, 0] - PD).abs() / PD).max())


def test_local_fit_keeps_the_interreflection_bias(scene):
    s, obs, terms = scene
    T = s.num_texels
    params = TexelParams(
        torch.full((T, 3), 0.5, dtype=torch.float64),
        torch.full((T, 3), 0.01, dtype=torch.float64),
        torch.full((T,), 0.1, dtype=torch.float64),
        0.01,
        0.6,
    )
    objective = Objective(
        predict=lambda pd, ps, sg: predict(terms, pd, ps, sg), intensity=obs.intensity, weight=obs.valid, loss="l2"
    )
    refine(params, objective, "lbfgs", 40)
    near = ~away_from_fold(s, 12)
    assert float(params.pd().detach()[near, 0].mean()) > PD * 1.1  # the fold region looks brighter than it is


@pytest.mark.parametrize("schedule", ["joint", "seed"])
def test_photon_level_removes_the_bias(scene, schedule):
    s, obs, terms = scene
    params, level = fit(s, obs, terms, schedule)
    keep = away_from_fold(s)
    err = pd_error(params.pd().detach(), keep)
    assert err < 0.05, err
    # the kept parameters are those of the best-scored refresh
    out = level.report()
    assert out["kept_refresh"] == int(np.argmin(out["image_difference_per_refresh"]))
    assert out["image_difference_per_refresh"][out["kept_refresh"]] < out["image_difference_per_refresh"][0]


def test_same_seed_same_result(scene):
    s, obs, terms = scene
    a, _ = fit(s, obs, terms, "joint", seed=3, outer=1)
    b, _ = fit(s, obs, terms, "joint", seed=3, outer=1)
    torch.testing.assert_close(a.pd(), b.pd(), rtol=0, atol=0)


def test_damping_moves_pd_part_of_the_way_and_leaves_the_lobe(scene):
    """With damping d the Pd handed to the next refresh is d * (Pd the cache was traced with) + (1 - d) * refit,
    so a damped run ends between the start and the undamped refit; Ps and sigma are not re-clamped."""
    s, obs, terms = scene
    T = s.num_texels
    make = lambda model, weight: Objective(predict=model, intensity=obs.intensity, weight=weight, loss="l2")
    ends = {}
    for d in (0.0, 0.5):
        params = TexelParams(
            torch.full((T, 3), 0.9, dtype=torch.float64),
            torch.full((T, 3), 0.002, dtype=torch.float64),
            torch.full((T,), 0.1, dtype=torch.float64),
            0.01,
            0.6,
            init_floor=1e-4,
        )
        level = photon_level(s, obs, "seed", outer=1, seed=1, damping=d, iterations=20)
        refit(level, params, make, level.inputs.cfg)
        ends[d] = (params, level.report())
    keep = away_from_fold(s)
    pd0, pd_half = ends[0.0][0].pd().detach()[keep, 0], ends[0.5][0].pd().detach()[keep, 0]
    assert ends[0.0][1]["kept_refresh"] == 1 and ends[0.5][1]["kept_refresh"] == 1
    torch.testing.assert_close(pd_half, 0.5 * 0.9 + 0.5 * pd0, rtol=0, atol=1e-6)
    # Ps (truth 0) stays where the refit put it: damping does not re-floor it at the starting floor 0.01
    assert float((ends[0.5][0].ps().detach() < 0.01).double().mean()) > 0.9


def test_the_automatic_kernels_follow_the_photon_count_and_warn_when_capped(scene):
    """photon.smoothing / specular_smoothing null: the kernels narrow as photons_per_light grows; with too few
    photons for the capped kernel the log says so and names a photon count that reaches the target."""
    s, obs, _ = scene
    logs = []
    cfg = Config()
    cfg.output.progress = False
    cfg.reflectance.brdf = "lambertian"
    cfg.photon.smoothing = cfg.photon.specular_smoothing = None
    cfg.photon.diffuse_paths, cfg.photon.specular_gather = "photons", 0
    cfg.photon.photons_per_light = 1000
    inputs, _ = level_inputs(cfg, Capture(s, obs), logs.append)
    few = PhotonLevel(inputs, RadiosityLevel(inputs))
    few.prepare()
    assert (few.smoothing, few.specular_smoothing) == (4.0, 3.0)
    warning = [m for m in logs if m.startswith("warning:") and "capped at 4" in m]
    assert warning and "photon.photons_per_light:" in warning[0]
    cfg.photon.photons_per_light = 400_000
    logs.clear()
    inputs, _ = level_inputs(cfg, Capture(s, obs), logs.append)
    many = PhotonLevel(inputs, RadiosityLevel(inputs))
    many.prepare()
    assert 0 < many.smoothing < 4.0 and 0 < many.specular_smoothing < 3.0
    assert not any("capped" in m for m in logs)
    cfg.photon.photons_per_light, cfg.photon.smoothing, cfg.photon.specular_smoothing = 1000, 2.5, 0.0
    logs.clear()
    inputs, _ = level_inputs(cfg, Capture(s, obs), logs.append)
    set_ = PhotonLevel(inputs, RadiosityLevel(inputs))
    set_.prepare()
    assert (set_.smoothing, set_.specular_smoothing) == (2.5, 0.0)  # a value set is used as it is
    assert not any("capped" in m for m in logs)


def test_final_images_average_independent_traces(scene):
    """render(): the kept cache's prediction averaged with fresh traces at the same parameters scatters about a
    quarter as much around the level's expectation (the mean of 16 more independent traces) as one cache's
    prediction, and the kept cache stays the level's cache."""
    s, obs, _ = scene
    level = photon_level(s, obs, outer=0)
    T = s.num_texels
    pd = torch.full((T, 3), PD, dtype=obs.intensity.dtype)
    ps, sigma = torch.zeros_like(pd), torch.full((T,), 0.1, dtype=pd.dtype)
    level.cache = kept = level.refresher.cache(pd, ps, sigma, refresh=0)
    one = level.predict(pd, ps, sigma)
    final = level.render(pd, ps, sigma)
    assert level.cache is kept
    refs = []
    for k in range(16):
        level.cache = level.refresher.cache(pd, ps, sigma, refresh=100 + k)
        refs.append(level.predict(pd, ps, sigma))
    expectation = torch.stack(refs).mean(0)
    spread = lambda images: float((images - expectation)[obs.valid].square().mean())
    # expected ratio (1 / 4 + 1 / 16) / (1 + 1 / 16) = 0.29 for FINAL_TRACES = 4
    assert spread(final) < 0.45 * spread(one), (spread(final), spread(one))


def test_refreshes_after_the_first_two_average_two_traces(scene):
    """From refresh AVERAGE_FROM on, the cache holds the previous trace's photons too: at fixed parameters its images
    scatter about half as much around the level's expectation (16 more independent traces) as one trace's."""
    s, obs, _ = scene
    level = photon_level(s, obs, outer=0)
    T = s.num_texels
    pd = torch.full((T, 3), PD, dtype=obs.intensity.dtype)
    params = TexelParams(pd, torch.full((T, 3), 0.01).double(), torch.full((T,), 0.1).double(), 0.01, 0.6)
    values = [v.detach() for v in params.values()]
    singles, averaged = [], []
    for k in range(AVERAGE_FROM + 2):
        level.refresh(params, k)
        (averaged if k >= AVERAGE_FROM else singles).append(level.predict(*values))
        assert level.cache.stats.get("averaged_traces", 1) == (2 if k >= AVERAGE_FROM else 1)
    refs = []
    for k in range(16):
        level.cache = level.refresher.cache(*values, refresh=100 + k)
        refs.append(level.predict(*values))
    expectation = torch.stack(refs).mean(0)
    spread = lambda images: float((images - expectation)[obs.valid].square().mean())
    one = sum(spread(x) for x in singles) / len(singles)
    two = sum(spread(x) for x in averaged) / len(averaged)
    # expected ratio (1 / 2 + 1 / 16) / (1 + 1 / 16) = 0.53
    assert two < 0.7 * one, (two, one)


def test_the_outer_loop_stops_once_pd_moves_less_than_its_std(scene):
    """Asked for 8 outer iterations, the loop goes on while a refit moves Pd (RMS) by at least Pd's median std and
    stops at the first averaged refresh where it moves less. Without sensor noise the photon noise moves Pd by about
    its std at every refit and all 8 run; with 5 DN of sensor noise Pd's std is larger and the loop stops early."""
    s, obs, terms = scene
    noisy = copy.copy(obs)
    g = torch.Generator().manual_seed(3)
    noisy.intensity = obs.intensity + 5.0 / 255 * torch.randn(obs.intensity.shape, generator=g, dtype=torch.float64)
    for o, stops in ((obs, False), (noisy, True)):
        params, level = fit(s, o, terms, "joint", outer=8)
        out = level.report()
        changes, stds = out["pd_change_per_refresh"], out["pd_std_median_per_refresh"]
        refits = len(changes)  # the refit that stops the loop is not refreshed: no image difference of its own
        assert len(out["image_difference_per_refresh"]) == refits + (0 if refits < 8 else 1)
        went_on = zip(changes[AVERAGE_FROM : refits - 1 if stops else refits], stds)
        assert all(c >= d for c, d in went_on)
        assert (refits < 8) == stops
        if stops:
            assert AVERAGE_FROM < refits and changes[-1] < stds[-1]
            assert pd_error(params.pd().detach(), away_from_fold(s)) < 0.05


def test_final_images_need_no_fresh_trace_when_the_photon_noise_is_small(scene):
    """finish() measured one trace's photon noise far below the images' noise: render() predicts with the kept cache
    alone (no trace; the kept cache's own photons)."""
    s, obs, _ = scene
    level = photon_level(s, obs, outer=0)
    T = s.num_texels
    pd = torch.full((T, 3), PD, dtype=obs.intensity.dtype)
    ps, sigma = torch.zeros_like(pd), torch.full((T,), 0.1, dtype=pd.dtype)
    level.cache = level.refresher.cache(pd, ps, sigma, refresh=0)
    level._photon_noise = (torch.full((3,), 1e-6, dtype=torch.float64), torch.full((3,), 0.2, dtype=torch.float64))
    level.refresher = None  # a trace would fail
    torch.testing.assert_close(level.render(pd, ps, sigma), level.predict(pd, ps, sigma))
    torch.testing.assert_close(level.prediction_variance(), level._photon_noise[0])  # the kept cache: one trace
