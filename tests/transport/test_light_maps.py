"""Light maps of moving lights (torchrefl.transport.light_maps): sources at evenly spaced columns, the texels'
weights of the maps (cubic Lagrange), one map per light when no light moves."""

import numpy as np
import torch
from conftest import CACHE_CAMERA as CAMERA
from conftest import CACHE_LIGHTS as LIGHTS
from conftest import fold_surface, point_light_observations

from torchrefl.transport.light_maps import light_sources, map_weights, texel_light_positions


def test_moving_lights_get_light_maps_that_interpolate_by_column():
    """On a co-rotating rig each column sees the light from its own position: maps sit at evenly spaced
    columns, the outer ones on the outermost columns, with weights summing to one, and their positions are the
    lights the texels saw."""
    s = fold_surface(4, 16)
    H, W = s.grid_shape
    col = s.texel_index % W
    # a light that moves with the column (rotates about the fold's y axis)
    angle = (col.double() - 8) * 0.05
    L = torch.stack([-60 * torch.sin(angle) - 30, torch.zeros_like(angle), 60 * torch.cos(angle)], -1)
    obs = point_light_observations(s.normals, s.positions, np.zeros((1, 3)), CAMERA)
    to = L[None] - s.positions[None]
    dist = to.norm(dim=-1)
    obs.light_dir, obs.falloff = to / dist[..., None], 1.0 / dist**2
    torch.testing.assert_close(torch.as_tensor(texel_light_positions(s, obs))[0], L)
    src = light_sources(s, obs, 4)
    assert src.positions.shape == (1, 4, 3)
    np.testing.assert_allclose(src.weights.sum(0), 1.0)
    # each map's position is the light of the texels in its column (columns 0, 5, 10, 15 of 16), where its
    # weight is 1
    for k in range(4):
        cols = col == 5 * k
        np.testing.assert_allclose(src.positions[0, k], L[cols].mean(0).numpy(), atol=1e-9)
        np.testing.assert_allclose(src.weights[k, cols.numpy()], 1.0, atol=1e-12)
    fixed = point_light_observations(s.normals, s.positions, LIGHTS, CAMERA)
    one = light_sources(s, fixed, 4)
    assert one.positions.shape == (2, 1, 3) and np.allclose(one.positions[:, 0], LIGHTS)


def test_map_weights_reproduce_cubics_and_sum_to_one():
    """Cubic Lagrange weights over the four nearest maps reproduce any cubic in the map coordinate exactly, the
    extrapolation half a map step past the outer maps included, and each texel's weights sum to one; fewer maps
    fall back to the polynomial they can hold; order 1 is the tent between the two nearest."""
    rng = np.random.default_rng(0)
    for K, degree in ((8, 3), (4, 3), (3, 2), (2, 1)):
        s = np.concatenate([np.linspace(-0.5, K - 0.5, 101), rng.uniform(0, K - 1, 50)])
        w = map_weights(s, K)
        assert w.shape == (K, s.size)
        np.testing.assert_allclose(w.sum(0), 1.0, atol=1e-12)
        c = rng.normal(size=degree + 1)
        f = lambda x: np.polyval(c, x)
        np.testing.assert_allclose((w * f(np.arange(K))[:, None]).sum(0), f(s), atol=1e-10)
        assert int((np.abs(w) > 0).sum(0).max()) <= min(4, K)
        inside = (s >= 0) & (s <= K - 1)
        assert float(np.sqrt((w[:, inside] ** 2).sum(0)).max()) < 1.09  # little gain on the maps' noise
    np.testing.assert_array_equal(map_weights(np.array([0.3, 2.0]), 1), np.ones((1, 2)))
    tent = map_weights(np.array([1.25, 2.0, 5.5]), 8, order=1)
    expect = np.zeros((8, 3))
    expect[1, 0], expect[2, 0], expect[2, 1], expect[5, 2], expect[6, 2] = 0.75, 0.25, 1.0, 0.5, 0.5
    np.testing.assert_allclose(tent, expect, atol=1e-12)


def test_a_field_that_bends_with_the_light_is_interpolated_within_a_fraction_of_the_tents_error():
    """Indirect light that varies smoothly but not linearly across the columns (here exp of the map coordinate):
    the cubic weights' error is far below the tent's, the error Object E's lower plate showed at 8 maps."""
    K = 8
    s = np.linspace(0, K - 1, 400)
    f = lambda x: np.exp(0.3 * x)
    cubic = np.abs((map_weights(s, K) * f(np.arange(K))[:, None]).sum(0) / f(s) - 1).max()
    tent = np.abs((map_weights(s, K, order=1) * f(np.arange(K))[:, None]).sum(0) / f(s) - 1).max()
    assert cubic < 0.1 * tent, (cubic, tent)
