"""The radiosity and photon levels on a mesh's atlas: inside a closed room (the real mesh traced, texels by uv)
the interreflected light keeps the energy balance sum_t A_t H_t = rho / (1 - rho) sum_t A_t E_t of a closed
enclosure of uniform albedo rho (every unit of light reflected lands on the room again)."""

import numpy as np
import pytest
import torch
from conftest import atlas_room, point_light_observations

from torchrefl.capture.base import Capture
from torchrefl.config import Config
from torchrefl.core.params import TexelParams
from torchrefl.fit.pipeline import level_inputs
from torchrefl.transport.levels.photon import PhotonLevel
from torchrefl.transport.levels.radiosity import RadiosityLevel

RHO = 0.5
Y = 1.0e4
LIGHT = np.array([5.0, 3.0, 2.5])  # mm, inside the 8 mm room


@pytest.fixture(scope="module")
def room():
    s = atlas_room().surface
    obs = point_light_observations(s.normals, s.positions, LIGHT[None], np.array([4.0, 2.0, 6.0]), intensity=Y)
    cfg = Config()
    cfg.reflectance.brdf = "lambertian"
    cfg.output.progress = False
    cfg.radiosity.patch_size = 2
    cfg.radiosity.hemisphere_samples = 256
    cfg.radiosity.solve_samples = None
    cfg.photon.photons_per_light = 100_000
    cfg.photon.diffuse_paths = "photons"
    cfg.photon.specular_gather = 0
    inputs, _ = level_inputs(cfg, Capture(s, obs), lambda *a: None)
    d = torch.as_tensor(LIGHT) - s.positions
    E = Y * (s.normals * d).sum(1).clamp(min=0) / d.norm(dim=1) ** 3  # no wall shadows another in a box
    balance = RHO / (1 - RHO) * float((s.areas * E).sum())
    radiosity = RadiosityLevel(inputs)
    radiosity.prepare()
    return s, inputs, radiosity, balance


def test_the_radiosity_level_keeps_the_rooms_energy_balance(room):
    s, _, radiosity, balance = room
    H = radiosity.indirect(torch.full((s.num_texels, 3), RHO, dtype=torch.float64))[0, :, 0]
    assert float((s.areas * H).sum()) == pytest.approx(balance, rel=0.03)
    assert (H > 0).all()


def test_the_photon_level_keeps_the_rooms_energy_balance(room):
    s, inputs, radiosity, balance = room
    T = s.num_texels
    pd = torch.full((T, 3), RHO, dtype=torch.float64)
    level = PhotonLevel(inputs, radiosity)
    level.prepare()
    level.refresh(
        TexelParams(pd, torch.zeros(T, 3, dtype=torch.float64), torch.full((T,), 0.2, dtype=torch.float64), 0.01, 0.6),
        0,
    )
    H = level.cache.irradiance_at(pd)[0, :, 0]
    assert float((s.areas * H).sum()) == pytest.approx(balance, rel=0.04)
    assert (H > 0).all()
