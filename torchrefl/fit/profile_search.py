"""Global search over sigma by variable projection (an initialiser beyond the seed's closed forms).

For a fixed sigma the local model i = Pd A + Ps D(theta_h; sigma) B is linear in Pd and Ps, so
the least-squares Pd and Ps follow in closed form, and so does the remaining squared error.
Evaluating that error on a geometric grid of sigma values finds the global minimum over sigma
(per texel, or for one lobe shared by the whole object) without any local-minimum trap; a golden-section
search then narrows each texel's sigma within the two grid steps around its best grid value (GOLDEN_STEPS
more evaluations, to 0.2 % of sigma on the default 32-value grid, whose steps are 14 % apart: the refinement
started from a grid value left the fold's measured lobes 2.7 / 2.1 % off and 7 % of their Pd beyond 2 %,
against 1.6 / 1.4 % and 3 % from the narrowed search; docs/results/fold.md).

The interreflection levels add indirect light that is linear in the texel's own Pd and Ps for fixed sigma
(Method III's cache: kappa (Pd/pi H + Ps S(sigma))): transport.levels.base.IndirectTerms adds those factors
to A and E, so the same search re-estimates every texel against direct plus cached indirect light.

Per group g (a texel-channel, a texel, or the whole object), with sums over fitted observations:
    u = i - A S_Ai / S_AA,  v = E - A S_AE / S_AA   (E = D B; Pd eliminated per texel and channel)
    Ps = clamp(sum(u v) / sum(v v), 0, ps_max),  error = sum(u u) - 2 Ps sum(u v) + Ps^2 sum(v v)
    Pd = (S_Ai - Ps S_AE) / S_AA;
a channel whose Pd comes out negative is held at Pd = 0 (its u, v become i, E) and Ps is solved again. With one Ps
per channel that is the least-squares fit with Pd >= 0; with one Ps for several channels (ps_channels 1, a shared
lobe) it is a few rounds of an active set that only adds channels, so the error, always that of the parameters
returned, can lie a few % above the bounded optimum at some sigma values.
"""

from __future__ import annotations

import math
from typing import Optional

import torch

from torchrefl.core.brdf import specular_lobe
from torchrefl.transport.levels.base import IndirectTerms
from torchrefl.transport.local import LocalTerms

#: rounds of holding a negative Pd at 0 and solving Ps again (per-channel Ps: the first is exact; one Ps shared by
#: channels or texels: a channel that turns negative joins the held ones, and after the last round Pd is clamped)
_HOLD_ROUNDS = 3
#: golden-section steps that narrow each texel's sigma within the grid steps around its best grid value
GOLDEN_STEPS = 12
_GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0


def sigma_grid(sigma_min: float, sigma_max: float, count: int) -> torch.Tensor:
    """(count,) geometric grid between the bounds."""
    return torch.exp(torch.linspace(math.log(sigma_min), math.log(sigma_max), count, dtype=torch.float64))


class _Profile:
    """The profiled fit of one sigma per group: Pd and Ps in closed form, the squared error left."""

    def __init__(self, terms, intensity, mask, ps_channels, shared, ps_max, indirect):
        dt = intensity.dtype
        self.dt, self.terms, self.indirect = dt, terms, indirect
        self.shared, self.ps_channels, self.ps_max = shared, ps_channels, ps_max
        self.w = mask.to(dt)[..., None]
        A = (terms.diffuse if indirect is None else terms.diffuse + indirect.diffuse.to(dt)) * self.w
        self.i = intensity * self.w
        self.A = A
        self.S_AA = (A * A).sum(0).clamp_min(1e-30)  # (T, 3)
        self.S_Ai = (A * self.i).sum(0)
        self.ii = (self.i * self.i).sum(0)
        self.uu = self.ii - self.S_Ai * self.S_Ai / self.S_AA

    def __call__(self, sigma: torch.Tensor):
        """(pd (T, 3), ps (T, C), error (T,)) at sigma: a 0-d tensor, or (T,) one value per texel. The error is that of
        the Pd and Ps returned: a channel whose least-squares Pd would be negative takes Pd = 0 and Ps is solved again
        with that channel's whole sums (Pd >= 0 is the model's; the error of a negative Pd lies below any reachable
        one where a broad lobe nearly repeats the diffuse term: docs/results/vase.md)."""
        S_AE, S_Ei, S_EE, uv, vv = self._sums(sigma)
        T = uv.shape[0]
        ps = self._ps(uv, vv)
        pd = (self.S_Ai - ps.expand(T, 3) * S_AE) / self.S_AA
        zero = pd < 0  # (T, 3): these channels' Pd is held at 0 and Ps solved against their whole sums
        for _ in range(_HOLD_ROUNDS):  # one Ps for several channels (or texels): another Pd may turn negative
            if not bool(zero.any()):
                break
            ps = self._ps(torch.where(zero, S_Ei, uv), torch.where(zero, S_EE, vv))
            pd = torch.where(zero, torch.zeros_like(pd), (self.S_Ai - ps.expand(T, 3) * S_AE) / self.S_AA)
            turned = (pd < 0) & ~zero
            zero = zero | turned
            if not bool(turned.any()):
                break
        pd = pd.clamp_min(0)
        ps_full = ps.expand(T, 3)
        free = self.uu - 2 * ps_full * uv + ps_full * ps_full * vv  # Pd at its least squares for this Ps
        held = self.ii - 2 * ps_full * S_Ei + ps_full * ps_full * S_EE  # Pd = 0
        err = torch.where(zero, held, free).sum(-1)  # (T,)
        return pd, ps.expand(T, ps.shape[-1]).clone(), err

    def parts(self, sigma: torch.Tensor):
        """(uu, uv, vv) each (T, 3) at sigma (0-d): the sums of the module docstring, Pd eliminated per texel and
        channel, from which any group of texels' Ps and error follow (torchrefl.fit.material_lobe)."""
        *_, uv, vv = self._sums(sigma)
        return self.uu, uv, vv

    def _sums(self, sigma: torch.Tensor):
        """(S_AE, S_Ei, S_EE, uv, vv) each (T, 3) at sigma: the specular column E's sums and, Pd eliminated, u.v
        and v.v."""
        t = self.terms
        E = specular_lobe(t.brdf, t.theta_h, sigma.to(self.dt), t.spread)[..., None] * t.specular
        if self.indirect is not None:
            E = E + self.indirect.specular(sigma).to(self.dt)
        E = E * self.w
        S_AE, S_Ei, S_EE = (self.A * E).sum(0), (E * self.i).sum(0), (E * E).sum(0)
        uv = S_Ei - S_AE * self.S_Ai / self.S_AA
        vv = (S_EE - S_AE * S_AE / self.S_AA).clamp_min(0)
        return S_AE, S_Ei, S_EE, uv, vv

    def _ps(self, num: torch.Tensor, den: torch.Tensor) -> torch.Tensor:
        """(T or 1, C) Ps = num / den summed per group (and over channels for one Ps), within [0, ps_max]."""
        if self.shared:
            num, den = num.sum(0, keepdim=True), den.sum(0, keepdim=True)
        if self.ps_channels == 1:
            num, den = num.sum(-1, keepdim=True), den.sum(-1, keepdim=True)
        ps = (num / den.clamp_min(1e-30)).clamp(0, self.ps_max)
        return torch.where(den > 0, ps, torch.zeros_like(ps))


class _Best:
    """The best (pd, ps, sigma, error) seen so far per group (the whole object when shared)."""

    def __init__(self, shared: bool):
        self.shared, self.values = shared, None

    def offer(self, pd, ps, sigma, err) -> None:
        sigma = sigma.expand(err.shape[0]).clone()
        if self.values is None:
            self.values = [pd, ps, sigma, err]
            return
        if self.shared:
            if float(err.sum()) < float(self.values[3].sum()):
                self.values = [pd, ps, sigma, err]
            return
        better = err < self.values[3]
        for j, new in enumerate((pd, ps, sigma, err)):
            cond = better[:, None] if new.dim() == 2 else better
            self.values[j] = torch.where(cond, new, self.values[j])


def profiled_fit(
    terms: LocalTerms,
    intensity: torch.Tensor,
    mask: torch.Tensor,
    ps_channels: int = 3,
    ps_max: float = float("inf"),
    indirect: Optional[IndirectTerms] = None,
):
    """sigma ((T,) or 0-d) -> (pd (T, 3), ps (T, C), error (T,)): each texel's Pd and Ps in closed form at that sigma
    and the squared error of its fitted observations with them (the search's profile, one texel at a time)."""
    return _Profile(terms, intensity, mask, ps_channels, False, ps_max, indirect)


def profile_search(
    terms: LocalTerms,
    intensity: torch.Tensor,
    mask: torch.Tensor,
    sigmas: torch.Tensor,
    ps_channels: int = 3,
    shared: bool = False,
    ps_max: float = float("inf"),
    indirect: Optional[IndirectTerms] = None,
    golden_steps: int = GOLDEN_STEPS,
):
    """Best (pd (T, 3), ps (T, C), sigma (T,), error (T,)) over the sigma grid, narrowed between the grid values
    next to each group's best by golden_steps golden-section steps (0 = the grid value).

    intensity (P, T, 3); mask (P, T) fitted observations. shared=True picks one sigma and one Ps
    for all texels (Pd stays per texel). indirect: cached interreflection added to the local model.
    """
    dt = intensity.dtype
    profile = _Profile(terms, intensity, mask, ps_channels, shared, ps_max, indirect)
    best = _Best(shared)
    grid = sigmas.to(dt)
    errors = []
    for s in grid:
        pd, ps, err = profile(s)
        best.offer(pd, ps, s, err)
        errors.append(err.sum() if shared else err)
    if golden_steps <= 0 or grid.numel() < 2:
        return tuple(best.values)
    idx = torch.stack(errors).argmin(0)  # () or (T,): the best grid value per group
    log_grid = grid.log()
    lo = log_grid[(idx - 1).clamp_min(0)]
    hi = log_grid[(idx + 1).clamp_max(grid.numel() - 1)]
    total = lambda e: e.sum() if shared else e  # noqa: E731
    c, d = hi - _GOLDEN * (hi - lo), lo + _GOLDEN * (hi - lo)
    f = {}
    for name, x in (("c", c), ("d", d)):
        pd, ps, err = profile(x.exp())
        best.offer(pd, ps, x.exp(), err)
        f[name] = total(err)
    for _ in range(golden_steps - 2):
        left = f["c"] < f["d"]  # the minimum lies in [lo, d]: drop (d, hi]
        hi, lo = torch.where(left, d, hi), torch.where(left, lo, c)
        # left: the old c becomes d and a new c is evaluated; otherwise the old d becomes c and a new d
        c, d = torch.where(left, hi - _GOLDEN * (hi - lo), d), torch.where(left, c, lo + _GOLDEN * (hi - lo))
        x = torch.where(left, c, d)
        pd, ps, err = profile(x.exp())
        best.offer(pd, ps, x.exp(), err)
        fx = total(err)
        f["c"], f["d"] = torch.where(left, fx, f["d"]), torch.where(left, f["c"], fx)
    return tuple(best.values)
