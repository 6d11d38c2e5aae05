"""The per-texel LM's closed-form problem (torchrefl.fit.fitted_problem): its residuals are the model's at the fitted
observations, its Jacobian and normal equations are autograd's (float64), and the LM reaches the same parameters
with it as with forward-mode derivatives of the whole images."""

import pytest
import torch
from conftest import noisy_glossy_scene as glossy_scene

from torchrefl.core.brdf import specular_lobe, specular_lobe_dsigma
from torchrefl.core.params import TexelParams
from torchrefl.fit.fitted_problem import FittedEntries, FittedProblem, irls_weight, row_sums, runs
from torchrefl.fit.refine import Objective, Prior, robust_loss
from torchrefl.fit.texel_lm import levenberg_marquardt
from torchrefl.transport.texel_model import SpecularEntries, TexelModel


def indirect_model(terms, seed=0, per_obs=3):
    """A TexelModel of all texels: the local terms, random indirect light per unit Pd, and random specular entries
    (per_obs on average per observation, unsorted), their factor summed plainly as the reference."""
    g = torch.Generator().manual_seed(seed)
    P, T = terms.theta_h.shape
    diffuse = 0.05 * torch.rand(P, T, 3, generator=g, dtype=torch.float64)
    E = per_obs * P * T
    obs = torch.randint(0, P * T, (E,), generator=g)
    theta = 0.6 * torch.rand(E, generator=g, dtype=torch.float64)
    weight = 0.02 * torch.rand(E, 3, generator=g, dtype=torch.float64)

    def specular(sigma):
        D = specular_lobe(terms.brdf, theta, sigma[obs % T])
        return torch.zeros(P * T, 3, dtype=torch.float64).index_add(0, obs, D[:, None] * weight).view(P, T, 3)

    return TexelModel(terms, diffuse, specular, lambda: SpecularEntries(obs, theta, weight))


def problem_and_objective(T=16, seed=5, C=3, loss="huber"):
    obs, terms, (pd, ps, sigma) = glossy_scene(T=T, seed=seed, noise=4.0)
    model = indirect_model(terms, seed)
    ps0 = ps if C == 3 else ps.mean(1, keepdim=True)
    params = TexelParams(pd * 0.9, ps0 * 1.1, sigma * 1.2, 0.01, 0.6, ps_max=float("inf") if C == 1 else 4.0)
    prior = Prior(torch.arange(T) % 2 == 0, torch.full((T, C), 0.3, dtype=torch.float64), torch.full((T,), 0.2), 0.5)
    weight = obs.valid.clone()
    weight[::3, ::2] = False  # some observations not fitted: the entries there are left out
    weight[:, 3] = False  # a texel without fitted observations (and without a prior): no step, no error
    objective = Objective(model, obs.intensity, weight, loss=loss, loss_scale_8bit=2.0, priors=[prior])
    index = torch.arange(T)
    return params, objective, model, index


@pytest.mark.parametrize("model", ["torrance_sparrow", "ward", "ward_normalised"])
def test_the_lobes_sigma_derivative_is_autograds_float64(model):
    theta = torch.linspace(0.0, 1.2, 13, dtype=torch.float64)
    sigma = torch.linspace(0.05, 0.6, 13, dtype=torch.float64).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda s: specular_lobe_dsigma(model, theta, s)[0], (sigma,))
    D, dD = specular_lobe_dsigma(model, theta, sigma.detach())
    (expected,) = torch.autograd.grad(specular_lobe(model, theta, sigma).sum(), sigma)
    torch.testing.assert_close(D, specular_lobe(model, theta, sigma.detach()), rtol=1e-14, atol=0)
    torch.testing.assert_close(dD, expected, rtol=1e-12, atol=1e-14)


def test_the_lambertian_lobe_is_zero_with_its_derivative():
    D, dD = specular_lobe_dsigma("lambertian", torch.rand(5), torch.rand(5))
    assert not D.any() and not dD.any()


def test_row_sums_add_the_runs():
    ids = torch.tensor([0, 0, 2, 2, 2, 4])
    values = torch.arange(12, dtype=torch.float64).reshape(6, 2)
    out = row_sums(runs(ids, 6), values)
    expected = torch.zeros(6, 2, dtype=torch.float64).index_add(0, ids, values)
    torch.testing.assert_close(out, expected, rtol=0, atol=0)


@pytest.mark.parametrize(("C", "loss"), [(3, "huber"), (1, "cauchy")])
def test_residuals_jacobian_and_normal_equations_are_autograds_float64(C, loss):
    """Subsets of texels (as the LM evaluates once texels converge): the residuals are the dense model's at the
    fitted observations, J^T W J and J^T W r are autograd's Jacobian's, and J^T W r is the cost's gradient."""
    params, objective, model, _ = problem_and_objective(C=C, loss=loss)
    T = params.num_texels
    entries = FittedEntries(model, objective.weight, torch.arange(T))
    assert 0 < len(entries.key) < len(model.entries().obs)  # the unfitted observations' entries are left out
    index = torch.arange(1, T, 2)
    sub = TexelModel(model.local.texels(index), model.diffuse.index_select(1, index), None, lambda: None)
    problem = FittedProblem(params, objective, sub, index, entries)
    x = [q.detach().index_select(0, index) for q in (params.raw_pd, params.raw_ps, params.raw_sigma)]
    w = objective.weight.index_select(1, index)

    def dense_residuals(*raw):  # the reference: the whole model's images at the fitted observations, texel by texel
        pd, ps, sigma = params.pd().detach().clone(), params.ps().detach().clone(), params.sigma().detach().clone()
        pd = pd.index_put((index,), torch.nn.functional.softplus(raw[0], beta=20.0))
        ps = ps.index_put((index,), params.ps_of(raw[1]))
        sigma = sigma.index_put((index,), params.sigma_of(raw[2]))
        images = model(pd, ps, sigma).index_select(1, index)
        return ((images - objective.intensity.index_select(1, index)) * 255.0).transpose(0, 1)[w.t()]

    r, pulls = problem.residuals(*x)
    torch.testing.assert_close(r, dense_residuals(*x), rtol=1e-12, atol=1e-10)
    columns = [(0, 0), (0, 1), (0, 2)] + [(1, c) for c in range(C)] + [(2, 0)]
    H, g, r0, pulls0 = problem.normal_equations(x, columns)
    torch.testing.assert_close(r0, r)
    jac = torch.autograd.functional.jacobian(dense_residuals, tuple(x))  # (N, 3, n, ...) per raw tensor
    N, n = r.shape[0], len(index)
    t = problem.t
    per_texel = [jac[0][torch.arange(N), :, t], jac[1][torch.arange(N), :, t], jac[2][torch.arange(N), :, t, None]]
    J = torch.cat(per_texel, -1)  # (N, 3, K): each observation's derivatives in its own texel's unknowns
    wr = irls_weight(r, objective.loss, objective.loss_scale_8bit)
    H_data = torch.zeros(n, len(columns), len(columns), dtype=torch.float64).index_add(
        0, t, torch.einsum("nck,nc,ncl->nkl", J, wr, J)
    )
    x_req = [q.clone().requires_grad_(True) for q in x]
    _, pulls_req = problem.residuals(*x_req)
    cost = (robust_loss(dense_residuals(*x_req), objective.loss, objective.loss_scale_8bit).sum()) + 0.5 * (
        pulls_req * pulls_req
    ).sum()
    grads = torch.autograd.grad(cost, x_req)
    torch.testing.assert_close(g, torch.cat([grads[0], grads[1], grads[2][:, None]], 1), rtol=1e-9, atol=1e-9)
    Jp = torch.autograd.functional.jacobian(lambda *raw: problem.residuals(*raw)[1], tuple(x))
    Jp = torch.cat([Jp[0].diagonal(0, 0, 2).permute(2, 0, 1), Jp[1].diagonal(0, 0, 2).permute(2, 0, 1)], -1)
    Jp_sigma = torch.autograd.functional.jacobian(lambda s: problem.residuals(x[0], x[1], s)[1], x[2])
    Jp = torch.cat([Jp, Jp_sigma.diagonal(0, 0, 2).t()[..., None]], -1)
    torch.testing.assert_close(H, H_data + torch.einsum("tjk,tjl->tkl", Jp, Jp), rtol=1e-9, atol=1e-9)
    torch.testing.assert_close(pulls0, pulls)


def test_the_lm_reaches_the_same_parameters_in_closed_form_as_by_forward_mode():
    """The same refit with the level's TexelModel (closed form) and with plain callables (forward-mode derivatives
    of the whole images): the same parameters, and fewer texels evaluated as they converge."""
    fits = []
    for closed in (True, False):
        params, objective, model, _ = problem_and_objective(T=18, seed=2)
        full = model if closed else (lambda *v: model(*v))

        def texels_model(pd, index, closed=closed):
            sub = TexelModel(model.local.texels(index), model.diffuse.index_select(1, index), None)
            if closed:
                entries = model.entries()
                sub.entries = lambda: _entries_of(entries, index, model.local.theta_h.shape)
                sub.specular = lambda s: (_ for _ in ()).throw(AssertionError("the closed form sums the entries"))
                return sub
            return None  # the whole model's images of them

        levenberg_marquardt(params, objective, lambda pd: full, 12, texels_model=texels_model)
        fits.append([q.detach() for q in params.values()])
    for a, b in zip(*fits):
        torch.testing.assert_close(a, b, rtol=1e-7, atol=1e-9)
    start = problem_and_objective(T=18, seed=2)[0]
    assert float((fits[0][2] - start.sigma().detach()).abs().max()) > 1e-3  # the refit moved the texels


def _entries_of(entries: SpecularEntries, index: torch.Tensor, shape) -> SpecularEntries:
    """The entries of the texels index (n,), renumbered to p * n + j."""
    P, T = shape
    row = torch.full((T,), -1, dtype=torch.long)
    row[index] = torch.arange(len(index))
    of = row[entries.obs % T]
    keep = of >= 0
    obs = (entries.obs[keep] // T) * len(index) + of[keep]
    return SpecularEntries(obs, entries.theta_h[keep], entries.weight[keep])
