"""Photon refreshes share a light's photons among the images of that light (mesh_views: several views per light)."""

import numpy as np
import torch
from conftest import fold_surface, point_light_observations

from torchrefl.capture.base import Capture
from torchrefl.config import Config
from torchrefl.fit.pipeline import level_inputs
from torchrefl.transport.levels.photon import PhotonLevel
from torchrefl.transport.levels.radiosity import RadiosityLevel
from torchrefl.transport.light_maps import LightSources
from torchrefl.transport.photon_refresh import distinct_lights

CAMERA = np.array([-150.0, 0.0, 150.0])


def test_distinct_lights_in_order_of_their_first_image():
    a, b, c = [1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, 9.0]
    positions = np.array([[a], [b], [a], [c], [b]])
    grey = np.ones((5, 3))
    first, light_of = distinct_lights(LightSources(positions, np.ones((1, 4)), grey))
    assert first.tolist() == [0, 1, 3]
    assert light_of.tolist() == [0, 1, 0, 2, 1]
    brighter = grey.copy()
    brighter[2] *= 2  # the same position at another intensity is another light
    first, light_of = distinct_lights(LightSources(positions, np.ones((1, 4)), brighter))
    assert first.tolist() == [0, 1, 2, 3] and light_of.tolist() == [0, 1, 2, 3, 1]


def test_images_of_one_light_share_its_photons():
    s = fold_surface(12, 24)
    T = s.num_texels
    lights = np.array([[-40.0, 5.0, 50.0], [-60.0, -20.0, 30.0], [-40.0, 5.0, 50.0]])  # image 2: image 0's light
    obs = point_light_observations(s.normals, s.positions, lights, CAMERA, intensity=2e4)
    cfg = Config()
    cfg.reflectance.brdf = "lambertian"
    cfg.photon.photons_per_light = 40_000
    cfg.photon.diffuse_paths = "photons"
    cfg.photon.specular_gather = 0
    cfg.output.progress = False
    inputs, _ = level_inputs(cfg, Capture(s, obs), lambda *a: None)
    level = PhotonLevel(inputs, RadiosityLevel(inputs))
    level.prepare()
    pd = torch.full((T, 3), 0.6, dtype=torch.float64)
    cache = level.refresher.cache(pd, torch.zeros(T, 3, dtype=torch.float64), torch.full((T,), 0.1), 0)
    assert cache.stats["traced_lights"] == 2
    H = cache.irradiance.double()
    assert H[0].abs().sum() > 0 and H[1].abs().sum() > 0
    torch.testing.assert_close(H[2], H[0], rtol=0, atol=0)
    assert not torch.equal(H[1], H[0])
