"""Per-texel uncertainty: the information and covariance against slow references, float64 gradchecks, calibrated
z-scores on a noisy scene fitted from the truth, the noise level recovered from the residuals, and finite, large stds
at the extremes (no highlight, saturated highlights, one light, grazing light)."""

import math

import pytest
import torch
from conftest import dome_scene, point_light_observations
from conftest import noisy_glossy_scene as glossy_scene

from torchrefl.core.params import TexelParams
from torchrefl.fit import uncertainty
from torchrefl.fit.refine import Objective
from torchrefl.fit.texel_jacobian import DenseJacobian, jacobian
from torchrefl.fit.texel_lm import levenberg_marquardt
from torchrefl.fit.uncertainty import (
    ParameterRanges,
    covariance,
    information,
    shared_lobe_covariance,
    texel_uncertainty,
)
from torchrefl.transport.local import local_terms, predict

RANGES = ParameterRanges(ps_max=4.0, sigma_min=0.01, sigma_max=0.6)
RANGE_STD = torch.sqrt(RANGES.prior_var(3))  # pd 3, ps 3, sigma


def model_of(terms):
    return lambda a, b, c: predict(terms, a, b, c)


def random_spd_blocks(T=4, K=7, seed=0):
    g = torch.Generator().manual_seed(seed)
    A = torch.randn(T, K, K, generator=g, dtype=torch.float64)
    return A @ A.transpose(1, 2)


def test_information_equals_autograd_jacobian_products():
    obs, terms, (pd, ps, sigma) = glossy_scene(T=6, seed=2, noise=0.0)
    J = jacobian(model_of(terms), pd, ps, sigma).dense()
    w = obs.valid[..., None].double().expand(-1, -1, 3)
    s = torch.tensor([0.5, 1.0, 2.0], dtype=torch.float64)
    info = information(J, w, s)
    t = 4  # one texel, the slow way: the full Jacobian of its images by reverse mode
    f = lambda x: _one_texel(terms, pd, ps, sigma, t, x)
    x0 = torch.cat([pd[t], ps[t], sigma[t : t + 1]])
    full = torch.autograd.functional.jacobian(f, x0) * 255.0  # (P, 3, K)
    ref = torch.einsum("pck,pc,pcl->kl", full, w[:, t] / s**2, full)
    assert torch.allclose(info[t], ref, rtol=1e-10, atol=1e-12)


def _one_texel(terms, pd, ps, sigma, t, x):
    pd2 = torch.cat([pd[:t], x[None, :3], pd[t + 1 :]])
    ps2 = torch.cat([ps[:t], x[None, 3:6], ps[t + 1 :]])
    sg2 = torch.cat([sigma[:t], x[6:7], sigma[t + 1 :]])
    return predict(terms, pd2, ps2, sg2)[:, t]


def test_covariance_is_the_inverse_with_the_broad_prior():
    info = random_spd_blocks()
    prior = RANGES.prior_var(3)
    ref = torch.linalg.inv(info + torch.diag(1.0 / prior))
    assert torch.allclose(covariance(info, prior), ref, rtol=1e-9, atol=1e-12)
    # no information at all: the range's variance
    assert torch.allclose(torch.diagonal(covariance(torch.zeros(1, 7, 7, dtype=torch.float64), prior)[0]), prior)


def test_gradcheck_covariance_and_information():
    info = random_spd_blocks(T=2, K=3).requires_grad_()
    prior = torch.tensor([0.3, 0.5, 0.2], dtype=torch.float64, requires_grad=True)
    # information is symmetric (the Cholesky factor reads one triangle): perturb it symmetrically
    sym = lambda a, v: covariance(0.5 * (a + a.transpose(1, 2)), v)
    assert torch.autograd.gradcheck(sym, (info, prior))
    g = torch.Generator().manual_seed(1)
    J = torch.randn(2, 3, 3, 2, generator=g, dtype=torch.float64, requires_grad=True)
    w = torch.rand(2, 3, 3, generator=g, dtype=torch.float64, requires_grad=True)
    s = torch.tensor([0.5, 1.0, 2.0], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(information, (J, w, s))


def test_shared_lobe_covariance_is_the_joint_inverse():
    """One lobe for all texels: the Schur-complement form equals inverting the whole (3T + 4) system."""
    T, K = 3, 7
    info = random_spd_blocks(T, K, seed=3)
    prior = RANGES.prior_var(3)
    n = 3 * T + 4
    big = torch.zeros(n, n, dtype=torch.float64)
    for t in range(T):
        i = slice(3 * t, 3 * t + 3)
        big[i, i] += info[t, :3, :3]
        big[i, 3 * T :] += info[t, :3, 3:]
        big[3 * T :, i] += info[t, 3:, :3]
        big[3 * T :, 3 * T :] += info[t, 3:, 3:]
    big += torch.diag(torch.cat([prior[:3].repeat(T), prior[3:]]).reciprocal())
    ref = torch.linalg.inv(big)
    cov = shared_lobe_covariance(info, prior, torch.ones(T, dtype=torch.bool))
    for t in range(T):
        i = slice(3 * t, 3 * t + 3)
        assert torch.allclose(cov[t, :3, :3], ref[i, i], rtol=1e-9)
        assert torch.allclose(cov[t, 3:, 3:], ref[3 * T :, 3 * T :], rtol=1e-9)
        assert torch.allclose(cov[t, :3, 3:], ref[i, 3 * T :], rtol=1e-9, atol=1e-14)


@pytest.fixture(scope="module")
def fitted_from_truth():
    """The noisy glossy dome (0.5 DN noise, 8-bit) fitted per texel from the truth: no local minima, so the stds
    alone decide the z-scores."""
    obs, terms, (pd, ps, sigma) = glossy_scene(T=200, seed=4, noise=0.5)
    params = TexelParams(pd, ps, sigma, 0.01, 0.6, ps_max=4.0)
    obj = Objective(model_of(terms), obs.intensity, obs.valid, loss="huber", loss_scale_8bit=3.0)
    levenberg_marquardt(params, obj, lambda _: model_of(terms), 30)
    est = tuple(x.detach() for x in params.values())
    return obs, terms, est, (pd, ps, sigma)


def test_z_scores_are_calibrated_and_the_noise_is_recovered(fitted_from_truth):
    obs, terms, est, truth = fitted_from_truth
    measured = torch.ones(len(est[2]), dtype=torch.bool)
    u = texel_uncertainty(model_of(terms), *est, obs.intensity, obs.valid, measured, RANGES)
    # 0.5 DN Gaussian noise plus 8-bit rounding (1/12 DN^2)
    assert u.noise_source == "residuals"
    assert torch.allclose(u.noise_dn, torch.full((3,), math.sqrt(0.25 + 1 / 12), dtype=torch.float64), rtol=0.1)
    good = (u.sigma_std / est[2] < 0.1) & (u.ps_std / est[1]).amax(1).lt(0.1)
    assert int(good.sum()) > 100
    for e, s, t in zip(est, (u.pd_std, u.ps_std, u.sigma_std), truth):
        z = ((e - t) / s)[good]
        assert 0.75 < float(z.std()) < 1.3
        assert 0.88 < float((z.abs() < 1.96).double().mean()) < 0.995
    known = texel_uncertainty(model_of(terms), *est, obs.intensity, obs.valid, measured, RANGES, noise_dn=0.577)
    assert known.noise_source == "capture.noise_dn"
    assert torch.allclose(known.sigma_std, u.sigma_std, rtol=0.15)


def test_noise_from_a_stride_of_the_texels_matches_all_of_them(fitted_from_truth, monkeypatch):
    obs, terms, est, _ = fitted_from_truth
    measured = torch.ones(len(est[2]), dtype=torch.bool)
    every = texel_uncertainty(model_of(terms), *est, obs.intensity, obs.valid, measured, RANGES)
    monkeypatch.setattr(uncertainty, "NOISE_TEXELS", 50)  # every 4th of the 200 texels
    some = texel_uncertainty(model_of(terms), *est, obs.intensity, obs.valid, measured, RANGES)
    assert not torch.equal(some.noise_dn, every.noise_dn)
    assert torch.allclose(some.noise_dn, torch.full((3,), math.sqrt(0.25 + 1 / 12), dtype=torch.float64), rtol=0.1)
    assert torch.allclose(some.noise_dn, every.noise_dn, rtol=0.05)
    assert torch.allclose(some.sigma_std, every.sigma_std, rtol=0.05)


def test_lobe_not_measured_gets_the_range_std_and_pd_with_the_lobe_free(fitted_from_truth):
    obs, terms, est, _ = fitted_from_truth
    T = len(est[2])
    measured = torch.arange(T) % 2 == 0
    known = dict(noise_dn=0.577)  # the same noise for both (the estimate's leverages differ a little)
    u = texel_uncertainty(model_of(terms), *est, obs.intensity, obs.valid, measured, RANGES, **known)
    every = torch.ones(T, dtype=torch.bool)
    full = texel_uncertainty(model_of(terms), *est, obs.intensity, obs.valid, every, RANGES, **known)
    assert torch.equal(u.lobe_measured, measured)
    assert torch.allclose(u.ps_std[~measured], RANGE_STD[3:6].expand(int((~measured).sum()), 3))
    assert torch.allclose(u.sigma_std[~measured], RANGE_STD[6].expand(int((~measured).sum())))
    # Pd of a texel whose lobe was borrowed is as uncertain as with its lobe free (the borrowed lobe may be off):
    # Pd's part of the whole block's covariance, as for a texel that measured its lobe
    torch.testing.assert_close(u.pd_std, full.pd_std, rtol=1e-12, atol=0)


def test_a_held_lobes_texel_covariance_is_pd_of_the_whole_block_and_the_lobe_at_its_prior():
    g = torch.Generator().manual_seed(3)
    K = 7
    A = torch.randn(4, 10, K, generator=g, dtype=torch.float64)
    info = A.transpose(1, 2) @ A  # (4, K, K) information blocks, Pd and the lobe coupled
    prior_var = torch.tensor([1 / 12] * 3 + [4 / 3] * 3 + [0.02], dtype=torch.float64)
    measured = torch.tensor([True, False, True, False])
    cov = uncertainty.texel_covariance(info, prior_var, measured)
    whole = torch.linalg.inv(info + torch.diag(1 / prior_var))  # by hand: the information plus the broad prior
    torch.testing.assert_close(cov[measured], whole[measured])
    torch.testing.assert_close(cov[~measured, :3, :3], whole[~measured, :3, :3])
    torch.testing.assert_close(cov[~measured, 3:, 3:], torch.diag(prior_var[3:]).expand(2, 4, 4))
    assert bool((cov[~measured, :3, 3:] == 0).all())
    held_alone = torch.linalg.inv(info[~measured, :3, :3] + torch.diag(1 / prior_var[:3]))
    assert bool((whole[~measured, :3, :3].diagonal(dim1=1, dim2=2) > held_alone.diagonal(dim1=1, dim2=2)).all())


def extreme_scene():
    """Four texels on the dome under a light grid: 0 sees highlights, 1 sees none (lights far from its mirror
    direction), 2 has its highlights saturated (not valid), 3 is lit at grazing incidence only; 0.5 DN noise."""
    nrm, pos, lights, cam = dome_scene(T=4, seed=1)
    obs = point_light_observations(nrm, pos, lights, cam, intensity=2.0e4)
    terms = local_terms("torrance_sparrow", torch.as_tensor(nrm), obs)
    pd = torch.full((4, 3), 0.4, dtype=torch.float64)
    ps = torch.full((4, 3), 0.3, dtype=torch.float64)
    sigma = torch.full((4,), 0.08, dtype=torch.float64)
    g = torch.Generator().manual_seed(0)
    clean = predict(terms, pd, ps, sigma)
    obs.intensity = clean + 0.5 / 255 * torch.randn(clean.shape, generator=g, dtype=torch.float64)
    th = terms.theta_h
    valid = obs.valid.clone()
    valid[:, 1] &= th[:, 1] > 0.6  # no observation near the lobe: sigma unconstrained
    valid[:, 2] &= th[:, 2] > 0.3  # the highlights saturated, so not valid
    valid[:, 3] &= terms.cos_l[:, 3] < 0.1  # grazing light only
    return obs, terms, valid, (pd, ps, sigma)


@pytest.mark.parametrize("noise_dn", [None, 0.5])
def test_extremes_are_finite_and_undetermined_parameters_large(noise_dn):
    obs, terms, valid, (pd, ps, sigma) = extreme_scene()
    assert bool(valid[:, 3].any())
    measured = torch.ones(4, dtype=torch.bool)
    u = texel_uncertainty(model_of(terms), pd, ps, sigma, obs.intensity, valid, measured, RANGES, noise_dn=noise_dn)
    for std in (u.pd_std, u.ps_std, u.sigma_std):
        assert bool(torch.isfinite(std).all()) and bool((std > 0).all())
        assert bool((std <= RANGE_STD.max() * 1.0001).all())
    assert float(u.sigma_std[0]) < 0.01  # highlights: sigma known
    for t in (1, 2):  # no usable highlight: sigma about its range's std
        assert float(u.sigma_std[t]) > 0.5 * float(RANGE_STD[6])
    assert bool((u.pd_std[3] > 10 * u.pd_std[0]).all())  # grazing light: Pd far less certain
    assert bool(torch.isfinite(u.noise_dn).all())


def test_one_light_and_no_observation_stay_finite():
    obs, terms, valid, (pd, ps, sigma) = extreme_scene()
    one = torch.zeros_like(valid)
    one[0] = valid[0]
    one[:, 3] = False  # texel 3 has no observation at all
    measured = torch.ones(4, dtype=torch.bool)
    u = texel_uncertainty(model_of(terms), pd, ps, sigma, obs.intensity, one, measured, RANGES, noise_dn=0.5)
    for std in (u.pd_std, u.ps_std, u.sigma_std):
        assert bool(torch.isfinite(std).all())
    assert torch.allclose(u.sigma_std[3], RANGE_STD[6])
    assert torch.allclose(u.pd_std[3], RANGE_STD[0].expand(3))


def test_a_shared_lobe_is_known_better_than_any_texel_alone():
    """fit.specular: shared hands the one lobe over expanded (stride 0) to every texel."""
    obs, terms, (pd, ps, sigma) = glossy_scene(T=20, seed=0)
    ps, sigma = ps[:1].expand(20, -1), sigma[:1].expand(20)
    every = torch.ones(20, dtype=torch.bool)
    args = (model_of(terms), pd, ps, sigma, obs.intensity, obs.valid, every, RANGES)
    shared = texel_uncertainty(*args, noise_dn=0.5, shared_lobe=every)
    alone = texel_uncertainty(*args, noise_dn=0.5)
    assert torch.allclose(shared.sigma_std, shared.sigma_std[0].expand(20))
    assert float(shared.sigma_std[0]) < float(alone.sigma_std.min())


def test_nearly_collinear_parameters_keep_a_positive_definite_block():
    """Two parameters whose Jacobian columns agree to 1e-4 at 3e3 DN (a strong lobe's Ps and sigma): their
    information block is positive definite to the last digit, so every texel gets a covariance. (Summed in
    float32, about half of these blocks came out indefinite and the Cholesky factorisation failed.)"""
    g = torch.Generator().manual_seed(0)
    prior = torch.tensor([1 / 12] * 3 + [0.1] * 3 + [0.02], dtype=torch.float64)
    for _ in range(50):
        a = torch.randn(40, 1, 3, 1, generator=g) * 3e3
        b = a * (1 + 1e-4 * torch.randn(40, 1, 3, 1, generator=g))
        J = torch.cat([torch.randn(40, 1, 3, 5, generator=g) * 50, a, b], -1).float()
        info = information(J, torch.ones(40, 1, 3), torch.full((3,), 0.3, dtype=torch.float64))
        assert torch.linalg.cholesky_ex(info + torch.diag(1 / prior))[1].item() == 0
        assert torch.isfinite(covariance(info, prior)).all()


@pytest.mark.parametrize("measured", [False, True])
def test_noise_estimate_of_held_and_measured_lobes(measured):
    """Residuals of 0.5 DN Gaussian noise where every observation shows the lobe (a broad lobe: its Jacobian
    columns 20-100 DN per unit Ps on all 40 lights): the leverage-corrected estimate is 0.5 DN whether the lobe was
    measured or held. A held lobe takes no leverage (not fitted); its broad-prior variance, counted, put h far over
    1 on every observation and the cap's 1 / sqrt(1 - 0.9) tripled the estimate (the fold's photon run: 0.99
    against 0.57 DN)."""
    g = torch.Generator().manual_seed(3)
    P, T = 40, 100
    J = torch.zeros(P, T, 3, 7, dtype=torch.float64)
    for c in range(3):
        J[..., c, c] = 50 + 150 * torch.rand(P, T, generator=g, dtype=torch.float64)  # Pd
        J[..., c, 3 + c] = 20 + 80 * torch.rand(P, T, generator=g, dtype=torch.float64)  # Ps
    J[..., 6] = 100 * torch.rand(P, T, 3, generator=g, dtype=torch.float64) - 50  # sigma
    r = 0.5 * torch.randn(P, T, 3, generator=g, dtype=torch.float64)
    weight, mask = torch.ones(P, T, 3, dtype=torch.float64), torch.ones(P, T, dtype=torch.bool)
    lobe = torch.full((T,), measured)
    J = DenseJacobian(J)
    s = uncertainty.residual_noise(r, J, weight, J.information(weight), mask, RANGES.prior_var(3), lobe)
    assert torch.allclose(s, torch.full((3,), 0.5, dtype=torch.float64), rtol=0.06)


def test_the_models_own_noise_adds_to_the_sensors(fitted_from_truth):
    """A level's Monte Carlo noise (model_var, DN^2) adds to the sensor's variance: 0.5 DN of sensor noise and 0.75
    DN^2 of the model's give the stds of 1 DN of noise."""
    obs, terms, est, _ = fitted_from_truth
    every = torch.ones(len(est[2]), dtype=torch.bool)
    args = (model_of(terms), *est, obs.intensity, obs.valid, every, RANGES)
    both = texel_uncertainty(*args, noise_dn=0.5, model_var=torch.full((3,), 0.75, dtype=torch.float64))
    one = texel_uncertainty(*args, noise_dn=1.0)
    for a, b in ((both.pd_std, one.pd_std), (both.ps_std, one.ps_std), (both.sigma_std, one.sigma_std)):
        torch.testing.assert_close(a, b, rtol=1e-12, atol=0)
    torch.testing.assert_close(both.noise_dn, torch.ones(3, dtype=torch.float64))
    torch.testing.assert_close(both.model_noise_dn, torch.full((3,), 0.75**0.5, dtype=torch.float64))
    assert one.model_noise_dn is None
