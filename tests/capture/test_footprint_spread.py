"""The half-angle offset's spread over an observation's footprint (torchrefl.capture.footprint_spread), and what it
buys at the truth of a rendered glossy ellipsoid."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from torchrefl.capture.footprint_spread import footprint_covariance, half_angle_spread
from torchrefl.capture.mesh_views import MeshViewsLoader
from torchrefl.config import load_config
from torchrefl.core.brdf import specular_lobe
from torchrefl.synthetic.mesh_views import write_capture
from torchrefl.transport.local import local_terms, predict

ROOT = Path(__file__).resolve().parents[2]


def test_a_grid_of_bilinear_samples_spreads_its_own_variance_plus_the_tent_and_the_pixel():
    # 3 x 3 samples 1 px apart at half-pixel offsets: 2/3 px^2 (the grid) + 1/4 (bilinear at f = 1/2) + 1/12 (box)
    a, b = np.meshgrid([-1.0, 0.0, 1.0], [-1.0, 0.0, 1.0], indexing="ij")
    uv = np.stack([a.ravel() + 10.5, b.ravel() + 20.5], -1)[None]
    px = np.diag([4.0, 2.0])[None]  # 4 px per column step, 2 per row step
    cov = footprint_covariance(uv, px)[0]
    np.testing.assert_allclose(cov, np.diag([1.0 / 16.0, 1.0 / 4.0]), atol=1e-12)


def test_on_a_sphere_the_normal_and_the_half_vector_turn_with_the_texel_steps():
    R, s, d_l, d_v = 40.0, 2.0, 300.0, 250.0
    n = np.array([[0.0, 0.0, 1.0]])
    steps = np.array([[[s, 0.0], [0.0, s], [0.0, 0.0]]])
    dnormal = steps / R  # a sphere's normal turns 1/R per mm
    cov = np.diag([0.3, 0.1])[None]
    far = half_angle_spread(n, steps, dnormal, cov, n, np.array([np.inf]), n, np.array([np.inf]))
    np.testing.assert_allclose(far[0], [(s / R) ** 2 * 0.2] * 2 + [0.0], rtol=1e-6, atol=1e-9)  # h = n: even split
    near = half_angle_spread(n, steps, dnormal, cov, n, np.array([d_l]), n, np.array([d_v]))
    rate = 1 / R + (1 / d_l + 1 / d_v) / 2  # the half vector turns the other way from the normal
    np.testing.assert_allclose(near[0, :2].sum(), s**2 * rate**2 * 0.4, rtol=1e-6)


def test_the_spread_lobe_is_the_footprint_mean_of_the_specular_term_on_a_sphere_under_a_near_light():
    # Torrance-Sparrow's specular term falloff * D(theta_h) / cos_v averaged over a Gaussian footprint of a sphere's
    # texel (exact normals, light and view directions at each point) against the spread lobe at the centre
    R, sigma = 40.0, 0.1
    X0, n0 = np.array([0.0, 0.0, R]), np.array([0.0, 0.0, 1.0])
    steps = np.array([[3.0, 0.0], [0.0, 2.0], [0.0, 0.0]])
    cov = np.array([[0.2, 0.03], [0.03, 0.12]])
    camera = X0 + 300.0 * np.array([np.sin(0.7), 0.0, np.cos(0.7)])
    light = X0 + 250.0 * np.array([-np.sin(0.55), 0.12, np.cos(0.55)])

    def term(X, n):
        to_l, to_v = light - X, camera - X
        d_l = np.linalg.norm(to_l, axis=-1)
        l, v = to_l / d_l[..., None], to_v / np.linalg.norm(to_v, axis=-1, keepdims=True)
        h = (l + v) / np.linalg.norm(l + v, axis=-1, keepdims=True)
        theta = np.arccos(np.clip(np.einsum("...i,...i->...", n, h), -1, 1))
        return np.exp(-(theta**2) / (2 * sigma**2)) / np.einsum("...i,...i->...", n, v) / d_l**2, theta, l, v, d_l

    rng = np.random.default_rng(0)
    o = rng.standard_normal((400_000, 2)) @ np.linalg.cholesky(cov).T
    X = X0 + o @ steps.T
    mean = term(X, X / np.linalg.norm(X, axis=1, keepdims=True))[0].mean()
    centre, theta, l, v, d_l = term(X0[None], n0[None])
    dnormal = steps[None] / R
    spread = half_angle_spread(n0[None], steps[None], dnormal, cov[None], l, d_l, v, np.linalg.norm(camera - X0)[None])

    def lobe(sp) -> float:
        t = lambda a: torch.as_tensor(np.asarray(a, dtype=np.float64))  # noqa: E731
        return float(specular_lobe("torrance_sparrow", t(theta), t(sigma), t(sp)))

    weight = centre[0] / np.exp(-(theta[0] ** 2) / (2 * sigma**2))  # falloff / cos_v at the centre
    err = lambda value: abs(value / mean - 1)  # noqa: E731
    centre_err, unshifted, shifted = err(centre[0]), err(weight * lobe(spread[:, :2])), err(weight * lobe(spread))
    assert centre_err > 0.03  # the lobe at the centre: 4 % off
    assert unshifted < 0.3 * centre_err and shifted < 0.3 * unshifted  # the spread: 0.85 %, with its shift 0.2 %


def test_at_the_truth_the_footprint_spread_lobe_explains_the_rendered_highlights(tmp_path):
    # a coarse atlas on small noiseless images: a texel's normal turns ~0.4 rad, against sigma 0.1-0.3
    overrides = [
        "capture.texture_size=16",
        "views.width=120",
        "views.height=90",
        "views.focal_px=195",
        "views.noise_dn=0",
        "views.cameras_per_ring=3",
        "views.camera_elevations_deg=[0.0]",
        "views.lights_per_view=3",
        "threads=1",
    ]
    cfg = load_config(str(ROOT / "configs" / "mesh_views.yaml"), overrides)
    write_capture(tmp_path, cfg.views, texture_size=16, seed=0, threads=1)
    cap = MeshViewsLoader().load(tmp_path, cfg, log=lambda m: None)
    obs, s, t = cap.obs.to(torch.float64), cap.surface, cap.truth
    assert obs.lobe_spread is not None
    pd, ps, sigma = (torch.as_tensor(t[k], dtype=torch.float64) for k in ("pd", "ps", "sigma"))
    terms = local_terms("torrance_sparrow", s.normals.double(), obs)
    spec = predict(terms, torch.zeros_like(pd), ps, sigma)[..., 1]
    highlight = obs.valid & (spec > 0.05 * obs.intensity[..., 1]) & (spec > 2e-3)
    assert int(highlight.sum()) > 50

    def rms(lobe_spread):
        terms.spread = lobe_spread
        diff = predict(terms, pd, ps, sigma) - obs.intensity
        return float(diff[highlight].pow(2).mean().sqrt())

    with_spread, centre = rms(obs.lobe_spread), rms(None)
    assert with_spread < 0.5 * centre, (with_spread, centre)
