"""The next-best lights for a fitted run: the candidates whose images would reduce its Ps and sigma uncertainty most.

For every candidate light (planning.run_scene: the loader's geometry of the light over the run's texels, with the
camera's and the light's Embree visibility, i.e. cast shadows), the fitted model (transport.local: direct light)
predicts each texel's image; an observation counts as the fitter would count it (fit.observe): seen, lit, not
shadowed, n.v and n.l above reflectance.min_cos_view / min_cos_light, not saturated (a predicted channel at or above
the scan's saturation level), on an estimated texel or one no fitted observation reached (`unobserved`: predicted at
the stand-in of planning.run_scene, with no information yet, so a light that brings it its first observations
counts); it is strong-specular (T_spec, core.observation_classes) when
its half-angle is at most reflectance.theta_specular_deg. Its Fisher information is fit.uncertainty's: J J^T /
noise^2 with J = d(255 i_hat) / d(Pd, Ps, sigma) of the texel's own parameters at the estimate.

A texel's information now is that of the run's own fitted lights, recomputed the same way at the estimate (the
expected information: the run's stds without its robust-loss weights). The score uses the Bayesian posterior
covariance (information + the broad prior's precision)^-1 whatever the texel's count of highlights, so a light is
worth what its observations say about Ps and sigma, directions included: a second highlight from (nearly) the
light of the first adds little, one from another direction separates Ps from sigma. The determined shares
(known_shares: the report and the adaptive loop's stopping rule) say what the fitter would deliver: there the
covariance is fit.uncertainty's texel_covariance, the whole block where the lobe is measured, else Ps and sigma at
the broad prior; a lobe counts as measured after the candidates when it was (the run's lobe_measured) or when the
candidates' T_spec observations bring the texel's count (the run's n_specular plus theirs) to the two the closed
form needs (fit.initialise).

The score of a texel is  u = log r_Ps^2 + log r_sigma^2,  r the relative std (std / value; Ps: the largest over
its channels, as report.uncertainty); a light's gain is the sum over texels of the decrease of u, i.e. of
log(var_before / var_after) over the texels and the two parameters: the expected reduction of the log posterior
variance (D-optimal design per texel and parameter, on the marginal variances). Relative to the value, so that Ps
and sigma weigh alike and a texel counts the same whatever its parameters' scale; halving a std is worth log 4
wherever it happens, so the score keeps rewarding precision on the texels already known to 10 % (the typical texels
that set the median relative error), and a texel's lobe is worth what its information adds to the broad prior's
(large but finite: the prior bounds it). Why not a saturating score such as log(1 + r^2 / 0.1^2): it pays
almost nothing for texels already known better than 10 %, so a light that halves the std of thousands of such
texels lost to one that gives a few texels their second highlight, and the median error lagged (docs/results/
next_best.md). Why not the trace of relative variances (A-optimal): it is dominated by the few texels with Ps near
0 or without a lobe (whose relative variances are huge).

Greedy: each round scores every remaining candidate against the texels' information so far and takes the best; its
information and T_spec counts are added before the next round (a light is chosen at most once). A candidate at the
position of one of the run's own lights is never chosen: its image would repeat one the capture has (a capture
holds each light once).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, Protocol

import numpy as np
import torch

from torchrefl.core.observation_classes import T_SPEC, classify
from torchrefl.core.observations import Observations
from torchrefl.errors import ConfigError
from torchrefl.fit.texel_jacobian import jacobian
from torchrefl.fit.uncertainty import covariance, information, texel_covariance
from torchrefl.planning.run_scene import RunScene
from torchrefl.planning.scenes import load_planning_scene
from torchrefl.report.uncertainty import RELATIVE_PRECISION
from torchrefl.transport.local import local_terms, predict

#: Ps below this counts as this in a relative std (Ps = 0 has no relative precision)
PS_FLOOR = 1e-3
#: candidate lights whose Jacobians are computed at once
CHUNK = 8
#: a light's observation of a texel is scored only where it adds at least this share of the texel's precision (its
#: information plus the prior's, before any candidate) to Ps or sigma; the rest change a score by < 1e-3
RELEVANT = 1e-3
#: what the gain measures (NextBest.score)
SCORE = "sum over texels of log(var_before / var_after) of Ps (largest channel) and sigma (D-optimal per texel)"


class PlanningScene(Protocol):
    """What the planner reads of a fitted run (planning.run_scene.RunScene for a scan,
    planning.views_run_scene.ViewsRunScene for mesh_views): cfg, run (its minnaert_k), normals (T, 3), the estimate
    pd, ps, sigma, estimated, unobserved, lobe_measured, n_specular, lights (P, 3) the run's own light positions,
    saturation_level, noise_dn, ranges; observations(positions (M, 3)): the geometry of M candidate lights, light
    after light, images_per_light rows each; fitted_observations(chunk): the run's own fitted images' geometry, in
    Observations of at most chunk lights' images."""

    images_per_light: int

    def observations(self, positions: np.ndarray) -> Observations: ...

    def fitted_observations(self, chunk: int) -> Iterator[Observations]: ...


@dataclass
class LightInformation:
    """What each of M lights adds to the texels it measures: texels[m] (N_m,) int64 indices of the texels with a
    fitted observation, info[m] (N_m, K, K) float64 their Fisher information, specular[m] (N_m,) int64 their T_spec
    observations (0 or 1 on a scan; up to the cameras that photograph the light on a mesh_views run)."""

    texels: list[torch.Tensor]
    info: list[torch.Tensor]
    specular: list[torch.Tensor]


@dataclass
class NextBest:
    """The greedy choice among the candidates (M, 3) head-frame mm: chosen, indices in choice order; gain (k,) the
    score decrease of each when chosen (SCORE); sigma_known / both_known: the predicted share of the estimated
    texels with sigma (and Ps) known to tau = 0.1 before any chosen light and after each (k + 1 values)."""

    chosen: list[int]
    gain: np.ndarray
    candidates: np.ndarray
    sigma_known: list[float]
    both_known: list[float]
    score: str = SCORE

    @property
    def positions(self) -> np.ndarray:
        """(k, 3) the chosen lights' positions, in choice order."""
        return self.candidates[self.chosen]

    def to_json(self) -> dict:
        """The plan file (`positions_mm`, which the rig's `capture --plan` reads) and the prediction behind it."""
        return {
            "planner": "next_best",
            "positions_mm": self.positions.tolist(),
            "chosen": [int(c) for c in self.chosen],
            "gain": [float(g) for g in self.gain],
            "score": self.score,
            "relative_precision": RELATIVE_PRECISION,
            "sigma_known_share": [float(x) for x in self.sigma_known],
            "ps_sigma_known_share": [float(x) for x in self.both_known],
            "candidates": len(self.candidates),
        }


def light_information(scene: PlanningScene, positions: np.ndarray) -> LightInformation:
    """The information each light at positions (M, 3) mm (the scene's frame) would add (module docstring); a light
    is scene.images_per_light consecutive rows of scene.observations (one per camera that photographs it)."""
    parts = [
        observation_information(scene, scene.observations(np.asarray(positions[s : s + CHUNK], dtype=np.float64)))
        for s in range(0, len(positions), CHUNK)
    ]
    return LightInformation(*(sum((getattr(p, f) for p in parts), []) for f in ("texels", "info", "specular")))


def observation_information(
    scene: PlanningScene, obs: Observations, rows_per_light: int | None = None
) -> LightInformation:
    """The information of Observations obs, per group of rows_per_light consecutive rows (one light; default
    scene.images_per_light): the texels some row of the group measures as the fitter would, their information
    summed over the group's rows and their T_spec observations counted."""
    rc = scene.cfg.reflectance
    V = scene.images_per_light if rows_per_light is None else rows_per_light
    terms = local_terms(rc.brdf, scene.normals, obs, scene.run.minnaert_k)
    model = lambda pd, ps, sigma: predict(terms, pd, ps, sigma)
    with torch.no_grad():
        saturated = (model(scene.pd, scene.ps, scene.sigma) >= scene.saturation_level).any(-1)
    fit = obs.valid & (terms.cos_v > rc.min_cos_view) & (terms.cos_l > rc.min_cos_light) & ~saturated
    fit &= (scene.estimated | scene.unobserved)[None]
    spec = classify(terms.theta_h, fit, rc.theta_diffuse_deg, rc.theta_specular_deg) == T_SPEC
    J = jacobian(model, scene.pd, scene.ps, scene.sigma).dense().double()
    texels, infos, specular = [], [], []
    for start in range(0, len(fit), V):
        rows = slice(start, start + V)
        idx = torch.nonzero(fit[rows].any(0)).squeeze(1)
        used = fit[rows][:, idx]  # a light's images that do not measure a texel add nothing (not even a NaN)
        weight = used[..., None].expand(-1, -1, 3).double()
        texels.append(idx)
        infos.append(information(torch.where(used[..., None, None], J[rows, idx], 0.0), weight, scene.noise_dn))
        specular.append(spec[rows][:, idx].sum(0).long())
    return LightInformation(texels, infos, specular)


class TexelState:
    """The texels' information and T_spec counts as lights are added, and their scores (module docstring)."""

    def __init__(self, scene: RunScene, info: torch.Tensor):
        self.scene = scene
        self.info = info
        self.added_spec = torch.zeros(len(info), dtype=torch.int64)
        self.prior_var = scene.ranges.prior_var(scene.ps.shape[1])
        self.scores = self.score(torch.arange(len(info)), info)

    def lobe(self, idx: torch.Tensor, added_spec: torch.Tensor) -> torch.Tensor:
        """(N,) bool: the fitter would estimate the lobe of texels idx (N,) with added_spec (N,) T_spec observations
        more than the run's: it did, or they bring its count to the closed form's two."""
        s = self.scene
        return s.lobe_measured[idx] | ((added_spec > 0) & (s.n_specular[idx] + added_spec >= 2))

    def relative_var(self, idx: torch.Tensor, cov: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(N,) squared relative stds of Ps (largest channel) and sigma of texels idx (N,) with covariance cov."""
        s = self.scene
        var = torch.diagonal(cov, dim1=1, dim2=2)
        C = s.ps.shape[1]
        ps, sigma = s.ps[idx].double(), s.sigma[idx].double()
        ps_rel = (var[:, 3 : 3 + C] / ps.clamp_min(PS_FLOOR).square()).amax(1)
        return ps_rel, var[:, -1] / sigma.clamp_min(s.ranges.sigma_min).square()

    def score(self, idx: torch.Tensor, info: torch.Tensor) -> torch.Tensor:
        """(N,) the score u of texels idx (N,) with information info (N, K, K): of the Bayesian posterior
        (info + prior precision)^-1 whatever the texel's count of highlights (module docstring)."""
        ps_rel, sg_rel = self.relative_var(idx, covariance(info, self.prior_var))
        return torch.log(ps_rel) + torch.log(sg_rel)

    def relevant(self, light: LightInformation) -> LightInformation:
        """light without the texels where it adds less than RELEVANT of the current precision of Ps or sigma (the
        precision only grows, so what is negligible now stays negligible)."""
        precision = torch.diagonal(self.info, dim1=1, dim2=2)[:, 3:] + 1.0 / self.prior_var[3:]
        texels, infos, specular = [], [], []
        for idx, info, spec in zip(light.texels, light.info, light.specular):
            keep = (torch.diagonal(info, dim1=1, dim2=2)[:, 3:] > RELEVANT * precision[idx]).any(1) | (spec > 0)
            texels.append(idx[keep])
            infos.append(info[keep])
            specular.append(spec[keep])
        return LightInformation(texels, infos, specular)

    def gain(self, light: LightInformation, m: int) -> float:
        """The decrease of the summed score were light m added."""
        idx = light.texels[m]
        if not len(idx):
            return 0.0
        new = self.score(idx, self.info[idx] + light.info[m])
        return float((self.scores[idx] - new).sum())

    def add(self, light: LightInformation, m: int) -> None:
        idx = light.texels[m]
        self.info[idx] += light.info[m]
        self.added_spec[idx] += light.specular[m]
        self.scores[idx] = self.score(idx, self.info[idx])

    def known_shares(self) -> tuple[float, float]:
        """The shares of the estimated texels with sigma, and with Ps and sigma, known to RELATIVE_PRECISION."""
        e = torch.nonzero(self.scene.estimated).squeeze(1)
        if not len(e):
            return 0.0, 0.0
        cov = texel_covariance(self.info[e], self.prior_var, self.lobe(e, self.added_spec[e]))
        ps_rel, sg_rel = self.relative_var(e, cov)
        tau2 = RELATIVE_PRECISION**2
        sigma_ok = sg_rel <= tau2
        return float(sigma_ok.double().mean()), float((sigma_ok & (ps_rel <= tau2)).double().mean())


def current_information(scene: RunScene) -> torch.Tensor:
    """(T, K, K) the information of the run's own fitted lights at the estimate; none at the unobserved texels (no
    fitted observation reached them, whatever the prediction at their stand-in says)."""
    T, K = len(scene.sigma), 4 + scene.ps.shape[1]
    info = torch.zeros(T, K, K, dtype=torch.float64)
    for obs in scene.fitted_observations(CHUNK):
        own = observation_information(scene, obs, 1)
        for idx, block in zip(own.texels, own.info):
            info[idx] += block
    info[scene.unobserved] = 0.0
    return info


class Planner:
    """One fitted run's planning inputs, computed once: its texels' information now and what each of the candidates
    (M, 3) head-frame mm would add (module docstring); choose(k) the greedy choice, reachable() the ceiling."""

    def __init__(self, scene: RunScene, candidates: np.ndarray):
        self.scene = scene
        self.candidates = check_candidates(candidates, "candidates")
        self.available = ~taken(self.candidates, scene.lights)
        self.info = current_information(scene)
        self.light = TexelState(scene, self.info.clone()).relevant(light_information(scene, self.candidates))

    def choose(self, k: int) -> NextBest:
        """Greedy choice of k of the candidates (module docstring)."""
        m_all = len(self.candidates)
        if int(k) < 1 or int(k) > m_all:
            raise ConfigError(f"--lights {k}: expected a number of lights between 1 and the {m_all} candidates")
        available = self.available.copy()
        if int(k) > int(available.sum()):
            raise ConfigError(
                f"--lights {k}: only {int(available.sum())} of the {m_all} candidates are not already lights of the run"
            )
        state = TexelState(self.scene, self.info.clone())
        chosen, gains = [], []
        s, b = state.known_shares()
        sigma_known, both_known = [s], [b]
        for _ in range(int(k)):
            g = np.array([state.gain(self.light, m) if available[m] else -np.inf for m in range(m_all)])
            m = int(np.argmax(g))
            state.add(self.light, m)
            available[m] = False
            chosen.append(m)
            gains.append(g[m])
            s, b = state.known_shares()
            sigma_known.append(s)
            both_known.append(b)
        return NextBest(chosen, np.array(gains), self.candidates, sigma_known, both_known)

    def reachable(self) -> float:
        """The predicted share of the estimated texels with Ps and sigma known to RELATIVE_PRECISION were every
        candidate (not already a light of the run) added: the ceiling of what the candidates can determine, by the
        same prediction as the choice's (TexelState.known_shares)."""
        state = TexelState(self.scene, self.info.clone())
        for m in np.flatnonzero(self.available):
            state.add(self.light, int(m))
        return state.known_shares()[1]


def choose(scene: RunScene, candidates: np.ndarray, k: int) -> NextBest:
    """Greedy choice of k of the candidates (M, 3) head-frame mm for the RunScene (module docstring)."""
    return Planner(scene, candidates).choose(k)


def taken(candidates: np.ndarray, lights: np.ndarray, tolerance_mm: float = 1e-3) -> np.ndarray:
    """(M,) bool: the candidates (M, 3) within tolerance_mm of one of the run's lights (P, 3)."""
    if not len(lights):
        return np.zeros(len(candidates), dtype=bool)
    d = np.linalg.norm(candidates[:, None] - np.asarray(lights, dtype=np.float64)[None], axis=-1)
    return d.min(1) <= tolerance_mm


def check_candidates(candidates, where: str) -> np.ndarray:
    """(M, 3) float64 finite light positions, M >= 1; ConfigError naming `where` otherwise."""
    a = np.asarray(candidates, dtype=np.float64) if not isinstance(candidates, str) else np.zeros(0)
    if a.ndim != 2 or a.shape[1] != 3 or len(a) < 1 or not np.isfinite(a).all():
        raise ConfigError(f"{where}: shape {a.shape}, expected (M, 3) finite light positions in mm, M >= 1")
    return a


def next_best_lights(run_dir: Path, candidates: np.ndarray, k: int) -> NextBest:
    """The k next-best of the candidate lights (M, 3) (positions in mm in the run's lights' frame: head frame for a
    scan, world for mesh_views) for the finished run in run_dir, greedily (module docstring)."""
    return choose(load_planning_scene(run_dir), candidates, k)
