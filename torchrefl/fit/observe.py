"""What the fit sees of a capture before any level: the local terms, the masks and the observation classes."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from torchrefl.config import Config
from torchrefl.core.observation_classes import T_DIFF, class_counts, classify
from torchrefl.core.observations import Observations
from torchrefl.core.surface import Surface
from torchrefl.fit.diffuse_shape import fit_minnaert_exponent
from torchrefl.fit.fit_observations import require_fit_observations
from torchrefl.fit.result import DiffuseModel
from torchrefl.transport.local import LocalTerms, local_terms


@dataclass
class Observed:
    """The local model's terms (with the diffuse shape), the fitted and held-out masks (P, T), the classes and
    their per-texel counts, and the closed-form start's options."""

    terms: LocalTerms
    fit_mask: torch.Tensor
    eval_mask: torch.Tensor
    classes: torch.Tensor
    counts: dict
    diffuse: DiffuseModel
    initialise_options: dict


def observe(cfg: Config, surface: Surface, obs: Observations, held: torch.Tensor, log) -> Observed:
    """Masks (grazing view and light removed, held-out lights apart), classes (eq. 2.20-2.21) and the diffuse shape."""
    rc, fc = cfg.reflectance, cfg.fit
    terms = local_terms(rc.brdf, surface.normals, obs)
    geometric_ok = obs.valid & (terms.cos_v > rc.min_cos_view) & (terms.cos_l > rc.min_cos_light)
    fit_mask = geometric_ok & ~held[:, None]
    eval_mask = geometric_ok & held[:, None]
    require_fit_observations(
        fit_mask, obs.valid, terms.cos_v, terms.cos_l, held, rc.min_cos_view, rc.min_cos_light, obs.source
    )
    classes = classify(terms.theta_h, fit_mask, rc.theta_diffuse_deg, rc.theta_specular_deg)
    diffuse = DiffuseModel(rc.diffuse)
    if rc.diffuse == "minnaert":
        if rc.minnaert_k is None:
            shape = fit_minnaert_exponent(terms, obs.intensity, (classes == T_DIFF) & fit_mask)
            diffuse = DiffuseModel(rc.diffuse, shape.k, True, shape.as_dict())
            log(shape.note)
        else:
            diffuse = DiffuseModel(rc.diffuse, float(rc.minnaert_k), False)
            log(f"diffuse: Minnaert k = {rc.minnaert_k} (reflectance.minnaert_k)")
        terms = local_terms(rc.brdf, surface.normals, obs, diffuse_exponent=diffuse.k)
    options = dict(
        ps_channels=rc.ps_channels,
        sigma_min=rc.sigma_min,
        sigma_max=rc.sigma_max,
        ps_max=rc.ps_max,
        window=fc.interpolation_window,
        sigma_search=fc.sigma_search,
        specular=fc.specular,
    )
    return Observed(terms, fit_mask, eval_mask, classes, class_counts(classes), diffuse, options)
