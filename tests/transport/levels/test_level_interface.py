"""The refinement loop drives any TransportLevel through its hooks, in order (a small fake level)."""

import torch
from conftest import dome_scene, point_light_observations

from torchrefl.capture.base import Capture
from torchrefl.config import Config
from torchrefl.core.params import TexelParams
from torchrefl.core.surface import Surface
from torchrefl.fit.pipeline import level_inputs, refit
from torchrefl.fit.refine import Objective
from torchrefl.transport.levels.base import RefitStep, TransportLevel
from torchrefl.transport.local import predict


class ScaledLevel(TransportLevel):
    """Direct light times a factor that each refresh re-estimates from the current Pd (a stand-in for a cache)."""

    name = "scaled"
    refits = 3

    def __init__(self, inputs):
        super().__init__(inputs)
        self.calls, self.factor = [], 1.0

    @property
    def reason(self):
        return "a fake level"

    def predict(self, pd, ps, sigma):
        return self.factor * predict(self.inputs.terms, pd, ps, sigma)

    def steps(self, k):
        self.calls.append(("steps", k))
        return [RefitStep(["raw_pd"], self.inputs.fit_mask, f"fake {k}", 30)]

    def refresh(self, params, k):
        self.calls.append(("refresh", k))
        self.factor = 1.0 + 0.1 * k

    def finish(self, params):
        self.calls.append(("finish",))


def scene():
    nrm, pos, lights, cam = dome_scene(T=100, seed=1)
    obs = point_light_observations(nrm, pos, lights[:9], cam)
    n = torch.as_tensor(nrm, dtype=torch.float64)
    s = Surface(
        (10, 10), torch.arange(100), torch.as_tensor(pos, dtype=torch.float64), n, torch.ones(100, dtype=torch.float64)
    )
    cfg = Config()
    cfg.reflectance.brdf = "lambertian"
    cfg.output.progress = False
    inputs, _ = level_inputs(cfg, Capture(s, obs), lambda *a: None)
    obs.intensity = predict(
        inputs.terms,
        torch.full((100, 3), 0.5, dtype=torch.float64),
        torch.zeros(100, 3, dtype=torch.float64),
        torch.full((100,), 0.1, dtype=torch.float64),
    )
    return cfg, inputs, obs


def test_the_loop_calls_refresh_steps_and_finish_in_order_and_trains_only_the_named_tensors():
    cfg, inputs, obs = scene()
    level = ScaledLevel(inputs)
    params = TexelParams(
        torch.full((100, 3), 0.3, dtype=torch.float64),
        torch.full((100, 3), 0.2, dtype=torch.float64),
        torch.full((100,), 0.2, dtype=torch.float64),
        0.01,
        0.6,
    )
    ps0, sigma0 = params.ps().detach().clone(), params.sigma().detach().clone()
    make = lambda model, mask: Objective(predict=model, intensity=obs.intensity, weight=mask, loss="l2")
    history = refit(level, params, make, cfg)
    assert level.calls == [
        ("refresh", 0),
        ("steps", 0),
        ("refresh", 1),
        ("steps", 1),
        ("refresh", 2),
        ("steps", 2),
        ("refresh", 3),
        ("finish",),
    ]
    assert len(history) > 3 and history[-1] < history[0]
    torch.testing.assert_close(params.ps(), ps0, rtol=0, atol=0)  # only raw_pd was trained
    torch.testing.assert_close(params.sigma(), sigma0, rtol=0, atol=0)
    # the last refit saw factor 1.2: Pd compensates for it
    seen = inputs.fit_mask.sum(0) >= 3
    assert abs(float(params.pd().detach()[seen].median()) - 0.5 / 1.2) < 1e-3
