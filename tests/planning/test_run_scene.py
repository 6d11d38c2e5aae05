"""planning.run_scene.texel_estimate: the estimate a planner predicts with, and the texels no fitted observation
reached (predicted at the estimated texels' median)."""

from types import SimpleNamespace

import numpy as np
import torch

from torchrefl.fit.initialise import COVER_FULL, COVER_MISFIT, COVER_NONE, COVER_PD_ONLY, COVER_UNTRUSTED
from torchrefl.planning.run_scene import texel_estimate


def run_maps(coverage):
    """A 1 x 5 grid: texels 0-2 estimated with distinct parameters, texels 3, 4 not, with the given coverage codes."""
    coverage = np.array([coverage], dtype=np.int8)
    mask = np.array([[True, True, True, False, False]])
    pd = np.array([[[0.1, 0.6, 0.2], [0.5, 0.2, 0.4], [0.3, 0.4, 0.9], [0.0] * 3, [0.0] * 3]])
    ps = np.array([[[0.2], [0.6], [0.4], [0.0], [0.0]]])
    sigma = np.array([[0.1, 0.3, 0.2, 0.0, 0.0]])
    return SimpleNamespace(
        mask=mask, pd=pd, ps=ps, sigma=sigma, coverage=coverage, lobe_measured=coverage == COVER_FULL, n_specular=None
    )


def test_unobserved_texels_are_predicted_at_the_estimated_texels_median():
    run = run_maps([COVER_FULL, COVER_PD_ONLY, COVER_FULL, COVER_NONE, COVER_UNTRUSTED])
    est = texel_estimate(run, np.arange(5), torch.float64)
    assert est.estimated.tolist() == [True, True, True, False, False]
    assert est.unobserved.tolist() == [False, False, False, True, False]  # untrusted: set aside by the fit
    # the median per channel (each channel's middle value, not one texel's)
    assert est.pd[3].tolist() == [0.3, 0.4, 0.4] and est.ps[3].tolist() == [0.4] and float(est.sigma[3]) == 0.2
    assert est.pd[4].abs().sum() == 0 and float(est.sigma[4]) == 0.0
    assert est.pd[:3].tolist() == [[0.1, 0.6, 0.2], [0.5, 0.2, 0.4], [0.3, 0.4, 0.9]]


def test_misfit_texels_are_not_unobserved_and_a_run_without_estimates_has_no_stand_in():
    run = run_maps([COVER_FULL, COVER_FULL, COVER_FULL, COVER_MISFIT, COVER_NONE])
    assert texel_estimate(run, np.arange(5), torch.float64).unobserved.tolist() == [False] * 4 + [True]
    run.mask[:] = False
    est = texel_estimate(run, np.arange(5), torch.float64)
    assert not est.unobserved.any() and torch.isfinite(est.sigma).all() and est.sigma.abs().sum() == 0


def test_a_run_without_a_coverage_map_has_no_unobserved_texel():
    """Without coverage the texels the fit set aside cannot be told from the unobserved: none is planned for; without
    lobe_measured either, no lobe counts as measured."""
    run = run_maps([COVER_FULL, COVER_FULL, COVER_FULL, COVER_NONE, COVER_UNTRUSTED])
    run.coverage, run.lobe_measured = None, None
    est = texel_estimate(run, np.arange(5), torch.float64)
    assert not est.unobserved.any() and not est.lobe_measured.any()
    assert est.pd[3:].abs().sum() == 0
