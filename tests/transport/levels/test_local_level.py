"""transport.levels.local: the local level's render, a block of texels at a time, is its predict."""

from __future__ import annotations

import torch
from conftest import dome_scene, point_light_observations

import torchrefl.transport.levels.local as local_level
from torchrefl.capture.base import Capture
from torchrefl.config import Config
from torchrefl.core.surface import Surface
from torchrefl.fit.pipeline import level_inputs


def test_render_in_blocks_of_texels_equals_predict(monkeypatch):
    nrm, pos, lights, cam = dome_scene(T=50, seed=1)
    obs = point_light_observations(nrm, pos, lights[:6], cam, dtype=torch.float32)
    n = torch.as_tensor(nrm, dtype=torch.float32)
    surface = Surface((5, 10), torch.arange(50), torch.as_tensor(pos, dtype=torch.float32), n, torch.ones(50))
    inputs, _ = level_inputs(Config(), Capture(surface, obs), lambda *a: None)
    level = local_level.LocalLevel(inputs)
    g = torch.Generator().manual_seed(0)
    pd, ps, sigma = torch.rand(50, 3, generator=g), torch.rand(50, 3, generator=g) * 0.3, torch.rand(50, generator=g)
    sigma = 0.05 + 0.3 * sigma
    monkeypatch.setattr(local_level, "RENDER_TEXELS", 7)  # 8 blocks, the last of 1 texel
    out = level.render(pd, ps, sigma)
    assert out.shape == (6, 50, 3) and float(out.abs().max()) > 0
    torch.testing.assert_close(out, level.predict(pd, ps, sigma), rtol=0, atol=0)
