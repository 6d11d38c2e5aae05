"""The fit pipeline's choices that only show end to end."""

import torch

from conftest import dome_scene, point_light_observations
from torchrefl.config import Config
from torchrefl.fit.pipeline import fit_capture
from torchrefl.geometry.surface import Surface
from torchrefl.report.stages import Stages
from torchrefl.transport.local import local_terms, predict


def test_a_shared_lobe_is_not_pulled_to_the_floor_by_texels_without_highlights():
    """One glossy material, lights that show highlights at only some texels: the shared lobe must come out
    near the truth (a per-texel prior towards the unknown texels' floor values once collapsed it to Ps ~ 0)."""
    T = 400
    nrm, pos, lights, cam = dome_scene(T=T, seed=2)
    lights = lights[[0, 4, 8, 36, 40, 44, 72, 76, 80]]
    obs = point_light_observations(nrm, pos, lights, cam, dtype=torch.float32)
    n = torch.as_tensor(nrm, dtype=torch.float32)
    terms = local_terms("torrance_sparrow", n, obs)
    pd = torch.full((T, 3), 0.5)
    ps_true, sigma_true = 0.3, 0.08
    obs.intensity = predict(terms, pd, torch.full((T, 3), ps_true), torch.full((T,), sigma_true))
    surface = Surface((20, 20), torch.arange(T), torch.as_tensor(pos, dtype=torch.float32), n, torch.ones(T))
    cfg = Config()
    cfg.fit.specular = "shared"
    cfg.fit.model = "local"
    cfg.output.progress = False
    res = fit_capture(cfg, surface, obs, Stages(), lambda *a: None, torch.device("cpu"))
    assert bool((~res["init"].known).any())           # some texel has no specular evidence of its own
    ps = float(res["ps"][0].mean())
    sigma = float(res["sigma"][0])
    assert abs(ps / ps_true - 1) < 0.1 and abs(sigma / sigma_true - 1) < 0.1, (ps, sigma)
