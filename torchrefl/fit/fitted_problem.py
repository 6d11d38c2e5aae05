"""The per-texel LM's residuals and Jacobian in closed form, at the fitted observations only.

For a TexelModel (torchrefl.transport.texel_model) each fitted observation o = (p, t) predicts, per channel c,
    i_oc = Pd_tc a_oc + Ps_tc (D(theta_o; sigma_t) b_oc + S_oc(sigma_t)),   S_oc = sum_e D(theta_e; sigma_t) w_ec
(a: the local diffuse term plus the indirect light per unit Pd, b: the local specular term, e: the specular entries of
o), so its derivatives are a_oc, D b_oc + S_oc and Ps_tc (D' b_oc + S'_oc) (D' = dD/dsigma,
torchrefl.core.brdf.specular_lobe_dsigma), times the raw tensors' derivatives (torchrefl.core.params). This replaces
forward-mode passes of the whole (P, T, 3) model, one per unknown, by two passes over the fitted observations and
their specular entries (the Jacobian's, then the trial step's). The observations are listed texel by texel and the
entries in the same order, so that every per-texel sum is a sparse row sum (CSR), not a scatter.
"""

from __future__ import annotations

import warnings

import torch

from torchrefl.core.brdf import specular_lobe_dsigma
from torchrefl.core.params import SHARPNESS, TexelParams, softplus_b
from torchrefl.errors import FitError
from torchrefl.fit.refine import _LOG_EPS, Objective, robust_loss
from torchrefl.transport.texel_model import TexelModel

# the CSR products below are what the beta warning is about; they are tested (tests/fit/test_fitted_problem.py)
warnings.filterwarnings("ignore", message="Sparse CSR tensor support is in beta", category=UserWarning)

#: fitted observations per chunk of the normal equations' products (bounds their float64 temporaries)
_CHUNK = 1 << 16


def irls_weight(r: torch.Tensor, kind: str, scale: float) -> torch.Tensor:
    """w(r) with rho'(r) = w(r) r for the robust losses of torchrefl.fit.refine.robust_loss."""
    if kind == "l2":
        return torch.ones_like(r)
    if kind == "huber":
        a = r.abs()
        return torch.where(a <= scale, torch.ones_like(r), scale / a.clamp_min(1e-30))
    if kind == "cauchy":
        return 1.0 / (1.0 + (r / scale) ** 2)
    raise FitError(f"fit.loss: unknown robust loss '{kind}', expected l2, huber or cauchy")


def texel_priors(objective: Objective, index: torch.Tensor | None) -> list:
    """The objective's active priors of the texels index (None: all) as (mask, ps, sigma, root) for prior_pulls: the
    objective is (sum of robust losses + sum of prior pulls) / count, so per texel, in units of the robust loss, a
    prior of weight w over n texels pulls with w * count / n (root: the square root of twice that)."""
    pick = (lambda x: x) if index is None else (lambda x: x.index_select(0, index))
    return [
        (pick(q.mask), pick(q.ps), pick(q.sigma), (2.0 * q.weight * objective.count / int(q.mask.sum())) ** 0.5)
        for q in objective.active_priors()
    ]


def prior_pulls(priors: list, ps: torch.Tensor, sigma: torch.Tensor) -> torch.Tensor:
    """(n, m (C + 1)) the m priors' residuals (texel_priors) at ps (n, C), sigma (n,): root times the log ratios."""
    pulls = [ps.new_zeros(ps.shape[0], 0)]
    for mask, prior_ps, prior_sigma, root in priors:
        m = mask.to(ps.dtype)[:, None] * root
        d_ps = torch.log(ps + _LOG_EPS) - torch.log(prior_ps + _LOG_EPS)
        d_sigma = torch.log(sigma / prior_sigma)[:, None]
        pulls.append(torch.cat([d_ps, d_sigma], 1) * m)
    return torch.cat(pulls, 1)


def row_sums(crow: torch.Tensor, values: torch.Tensor) -> torch.Tensor:
    """(R, m) sums of the consecutive runs of rows of values (N, m): run r is rows crow[r]:crow[r + 1] (crow (R + 1,)
    long, non-decreasing, from 0 to N). A CSR product: a deterministic sum, several times faster than index_add."""
    n = len(values)
    ones = torch.ones(n, dtype=values.dtype, device=values.device)
    cols = torch.arange(n, device=values.device)
    return torch.sparse_csr_tensor(crow, cols, ones, (len(crow) - 1, n), check_invariants=False) @ values


def runs(sorted_ids: torch.Tensor, count: int) -> torch.Tensor:
    """(count + 1,) crow of row_sums for rows whose ids (N,) long, sorted, lie in 0..count-1."""
    return torch.searchsorted(sorted_ids, torch.arange(count + 1, device=sorted_ids.device))


class FittedEntries:
    """The specular entries of the refit texels at their fitted observations, kept for a whole refit (they do not
    depend on Pd): key (E,) texel * P + image, sorted; theta_h (E,); weight (E, 3)."""

    def __init__(self, model: TexelModel, weight: torch.Tensor, index: torch.Tensor):
        """model: of the texels index (n,) long; weight (P, T) bool the fitted observations."""
        P, n = weight.shape[0], len(index)
        if model.entries is None:
            device, dtype = weight.device, model.local.specular.dtype
            self.key = torch.zeros(0, dtype=torch.long, device=device)
            self.theta_h = torch.zeros(0, dtype=dtype, device=device)
            self.weight = torch.zeros(0, 3, dtype=dtype, device=device)
            return
        e = model.entries()
        p, j = e.obs // n, e.obs % n
        key = index.index_select(0, j) * P + p
        fitted = weight.t().reshape(-1).index_select(0, key)
        keep = fitted.nonzero()[:, 0]
        key = key.index_select(0, keep)
        key, order = torch.sort(key, stable=True)
        keep = keep.index_select(0, order)
        self.key, self.theta_h, self.weight = key, e.theta_h.index_select(0, keep), e.weight.index_select(0, keep)


class FittedProblem:
    """The per-texel residuals of an Objective at its fitted observations (N of them, texel by texel), for a
    TexelModel of the texels index (n,) long, with their Jacobian in closed form."""

    def __init__(
        self,
        params: TexelParams,
        objective: Objective,
        model: TexelModel,
        index: torch.Tensor,
        entries: FittedEntries,
    ):
        self.params, self.objective, self.brdf = params, objective, model.local.brdf
        P, T = objective.weight.shape
        n = len(index)
        tp = objective.weight.index_select(1, index).t().nonzero()  # (N, 2) (j, p), texel by texel
        self.t, p = tp[:, 0], tp[:, 1]
        flat = p * n + self.t  # into (P, n)
        self.crow = runs(self.t, n)

        def at(x: torch.Tensor) -> torch.Tensor:
            return x.reshape(P * n, *x.shape[2:]).index_select(0, flat)

        local = model.local
        self.theta = at(local.theta_h)
        self.spread = None if local.spread is None else at(local.spread)
        self.a = at(local.diffuse if model.diffuse is None else local.diffuse + model.diffuse)
        self.b = at(local.specular)
        # the intensities straight from the (P, T, 3) tensor (not a (P, n, 3) copy of the texels')
        whole = p * T + index.index_select(0, self.t)
        self.intensity = objective.intensity.reshape(P * T, -1).index_select(0, whole)
        # this refit's entries of these texels, renumbered to the observations above (both sorted by texel, image)
        lookup = torch.full((T * P,), -1, dtype=torch.long, device=self.t.device)
        lookup[index.index_select(0, self.t) * P + p] = torch.arange(len(flat), device=self.t.device)
        row = lookup.index_select(0, entries.key)
        live = (row >= 0).nonzero()[:, 0]
        if len(live) == len(row):
            self.e_row, self.e_theta, self.e_weight = row, entries.theta_h, entries.weight
        else:
            self.e_row = row.index_select(0, live)
            self.e_theta, self.e_weight = entries.theta_h.index_select(0, live), entries.weight.index_select(0, live)
        self.e_texel = self.t.index_select(0, self.e_row)
        self.e_crow = runs(self.e_row, len(flat))
        self.priors = texel_priors(objective, index)

    def _lobes(self, sigma: torch.Tensor, derivative: bool):
        """(D, S) at the observations (N,), (N, 3), and with derivative their d / dsigma too."""
        s_obs = sigma.index_select(0, self.t)
        s_ent = sigma.index_select(0, self.e_texel)
        n, e = len(self.t), len(self.e_row)
        cols = torch.arange(e, device=sigma.device)

        def summed(values: torch.Tensor) -> torch.Tensor:
            m = torch.sparse_csr_tensor(self.e_crow, cols, values, (n, e), check_invariants=False)
            return m @ self.e_weight

        if not derivative:
            lobe, _ = specular_lobe_dsigma(self.brdf, self.theta, s_obs, self.spread)
            spec, _ = specular_lobe_dsigma(self.brdf, self.e_theta, s_ent)
            return lobe, summed(spec)
        lobe, dlobe = specular_lobe_dsigma(self.brdf, self.theta, s_obs, self.spread)
        spec, dspec = specular_lobe_dsigma(self.brdf, self.e_theta, s_ent)
        return lobe, summed(spec), dlobe, summed(dspec)

    def _values(self, raw_pd, raw_ps, raw_sigma):
        p = self.params
        return softplus_b(raw_pd), p.ps_of(raw_ps), p.sigma_of(raw_sigma)

    def _pulls(self, ps: torch.Tensor, sigma: torch.Tensor) -> torch.Tensor:
        return prior_pulls(self.priors, ps, sigma)

    def residuals(self, raw_pd, raw_ps, raw_sigma) -> tuple[torch.Tensor, torch.Tensor]:
        """(N, 3) the fitted observations' residuals in 8-bit DN, and (n, m (C + 1)) the priors' residuals."""
        pd, ps, sigma = self._values(raw_pd, raw_ps, raw_sigma)
        lobe, spec = self._lobes(sigma, False)
        return self._residual(pd, ps, lobe, spec), self._pulls(ps, sigma)

    def _residual(self, pd, ps, lobe, spec) -> torch.Tensor:
        pd_o, ps_o = pd.index_select(0, self.t), ps.index_select(0, self.t)
        return (pd_o * self.a + ps_o * (lobe[:, None] * self.b + spec) - self.intensity) * 255.0

    def cost(self, r: torch.Tensor, pulls: torch.Tensor) -> torch.Tensor:
        """(n,) each texel's cost: its robust losses plus half its squared prior residuals."""
        o = self.objective
        data = row_sums(self.crow, robust_loss(r, o.loss, o.loss_scale_8bit).sum(1, keepdim=True))[:, 0]
        return data + 0.5 * (pulls * pulls).sum(1)

    def normal_equations(self, x: list, columns: list) -> tuple:
        """(n, K, K) J^T W J, (n, K) J^T W r per texel (float64) for the raw components columns [(tensor, component)]
        (as torchrefl.fit.texel_lm._normal_equations), and the residuals r, pulls at x."""
        p = self.params
        raw_pd, raw_ps, raw_sigma = x
        pd, ps, sigma = self._values(raw_pd, raw_ps, raw_sigma)
        lobe, spec, dlobe, dspec = self._lobes(sigma, True)
        r = self._residual(pd, ps, lobe, spec)
        pulls = self._pulls(ps, sigma)
        # the raw tensors' derivatives
        d_pd = torch.sigmoid(SHARPNESS * raw_pd)
        if p.ps_max == float("inf"):
            d_ps = torch.sigmoid(SHARPNESS * raw_ps)
        else:
            s = torch.sigmoid(raw_ps)
            d_ps = p.ps_max * s * (1.0 - s)
        s = torch.sigmoid(raw_sigma)
        d_sigma = (p.sigma_max - p.sigma_min) * s * (1.0 - s)
        C = ps.shape[1]
        o = self.objective
        w = irls_weight(r, o.loss, o.loss_scale_8bit)
        n, K = len(pd), len(columns)
        offset = {0: 0, 1: 3, 2: 3 + C}
        wanted = [offset[i] + j for i, j in columns]
        H = torch.zeros((n, K, K), dtype=torch.float64, device=r.device)
        g = torch.zeros((n, K), dtype=torch.float64, device=r.device)
        for a in range(0, len(self.t), _CHUNK):
            part = slice(a, a + _CHUNK)
            t = self.t[part]
            J = torch.zeros((len(t), 3, 3 + C + 1), dtype=torch.float64, device=r.device)
            diag = torch.arange(3, device=r.device)
            J[:, diag, diag] = (self.a[part] * d_pd.index_select(0, t)).double() * 255.0
            dps_o = (lobe[part, None] * self.b[part] + spec[part]) * d_ps.index_select(0, t)
            if C == 3:
                J[:, diag, 3 + diag] = dps_o.double() * 255.0
            else:
                J[:, :, 3] = dps_o.double() * 255.0
            ds = ps.index_select(0, t) * (dlobe[part, None] * self.b[part] + dspec[part])
            J[:, :, 3 + C] = (ds * d_sigma.index_select(0, t)[:, None]).double() * 255.0
            J = J[..., wanted]
            wd = w[part].double()
            Jw = J * wd[..., None]
            hj = torch.einsum("nck,ncl->nkl", Jw, J).reshape(len(t), K * K)
            prods = torch.cat([hj, torch.einsum("nck,nc->nk", Jw, r[part].double())], 1)
            ids = t - t[0]
            summed = row_sums(runs(ids, int(t[-1] - t[0]) + 1), prods)
            span = slice(int(t[0]), int(t[-1]) + 1)
            H[span] += summed[:, : K * K].reshape(-1, K, K)
            g[span] += summed[:, K * K :]
        if pulls.shape[1]:
            Jp = torch.zeros((n, pulls.shape[1], 3 + C + 1), dtype=torch.float64, device=r.device)
            col = 0
            for mask, _, _, root in self.priors:
                m = mask.to(torch.float64) * root
                for c in range(C):
                    Jp[:, col + c, 3 + c] = m * (d_ps[:, c] / (ps[:, c] + _LOG_EPS)).double()
                Jp[:, col + C, 3 + C] = m * (d_sigma / sigma).double()
                col += C + 1
            Jp = Jp[..., wanted]
            H = H + torch.einsum("tjk,tjl->tkl", Jp, Jp)
            g = g + torch.einsum("tjk,tj->tk", Jp, pulls.double())
        return H, g, r, pulls
