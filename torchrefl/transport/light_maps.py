"""Light maps of moving lights, for the photon cache (torchrefl.transport.photon_cache).

On the cylindrical rig the lights co-rotate with the scan, so each texel column sees
light p from its own position L_pt = x_t + l_pt / sqrt(falloff_pt). `light_sources` places K
sources per light at evenly spaced columns; a texel's indirect light interpolates the maps in its column
(`map_weights`: cubic Lagrange through the four nearest sources; the tent between the two nearest left the
indirect light of Object E's lower plate 1.3 % low at 8 maps, since it bends with the light's position, and
the end columns beyond the outer sources took the end maps' values unchanged). A capture whose lights do
not move uses one source per light.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from torchrefl.errors import ConfigError


@dataclass
class LightSources:
    """positions (P, K, 3) source positions of light p's K maps; weights (K, T) per-texel weights of
    the maps (each column sums to 1); intensity (P, 3)."""

    positions: np.ndarray
    weights: np.ndarray
    intensity: np.ndarray

    @property
    def num_maps(self) -> int:
        return int(self.positions.shape[1])


def texel_light_positions(surface, obs) -> np.ndarray:
    """(P, T, 3) position of light p as texel t saw it: x_t + l_pt / sqrt(falloff_pt)."""
    if obs.light_positions is None:
        raise ConfigError(
            f"fit.model: 'photon' needs point lights, but the capture {obs.source} has directional "
            "lights: use fit.model=local"
        )
    dist = 1.0 / torch.sqrt(obs.falloff.double().clamp_min(1e-300))
    return (surface.positions.double()[None] + obs.light_dir.double() * dist[..., None]).numpy()


def map_weights(s: np.ndarray, K: int, order: int = 3) -> np.ndarray:
    """(K, T) weights of K maps at map coordinates 0..K-1 for texels at map coordinate s (T,): Lagrange
    interpolation through the order + 1 nearest maps (fewer when K is smaller; order 1 = the tent between
    the two nearest; past the end maps the same polynomial extrapolates). Every column sums to 1 and a field
    that is a polynomial of that order in s is reproduced exactly; order 3 weights dip below 0 between
    maps (to -0.064 in the middle intervals, -0.32 in the two end ones), and their root sum of squares, the
    gain on independent noise in the maps, stays below 1.09 between the end maps."""
    s = np.asarray(s, dtype=np.float64)
    T = s.shape[0]
    if K <= 1:
        return np.ones((1, T))
    n = min(order + 1, K)
    j0 = np.clip(np.floor(s).astype(np.int64) - (n - 1) // 2, 0, K - n)
    weights = np.zeros((K, T))
    for a in range(n):
        w = np.ones(T)
        for b in range(n):
            if b != a:
                w *= (s - (j0 + b)) / (a - b)
        weights[j0 + a, np.arange(T)] += w
    return weights


def light_sources(surface, obs, max_maps: int, order: int = 3) -> LightSources:
    """Sources and their per-texel map weights (module docstring; map_weights of this order); one map per
    light when no light moves."""
    L = texel_light_positions(surface, obs)
    P, T, _ = L.shape
    intensity = obs.light_intensity.double().numpy()
    centre = np.median(L, axis=1)  # (P, 3)
    spread = float(np.abs(L - centre[:, None]).max()) if T else 0.0
    scale = float(np.abs(surface.positions.double().numpy()).max()) + 1.0
    if spread <= 1e-6 * scale or max_maps <= 1:
        return LightSources(
            centre[:, None] if spread <= 1e-6 * scale else L.mean(1)[:, None], np.ones((1, T)), intensity
        )
    W = surface.grid_shape[1]
    col = (surface.texel_index.numpy() % W).astype(np.float64)
    cmin, cmax = col.min(), col.max()
    K = int(min(max_maps, cmax - cmin + 1))
    if K == 1:
        return LightSources(L.mean(1)[:, None], np.ones((1, T)), intensity)
    # the outer maps sit on the outermost columns, so every texel interpolates (no extrapolation, whose
    # weights would amplify a photon map's noise at the object's ends)
    step = (cmax - cmin) / (K - 1)
    centres = cmin + step * np.arange(K)
    weights = map_weights((col - cmin) / step, K, order)
    positions = np.empty((P, K, 3))
    for k, c in enumerate(centres):
        nearest = np.abs(col - c)
        sel = nearest <= nearest.min() + 1e-9
        positions[:, k] = L[:, sel].mean(1)
    return LightSources(positions, weights, intensity)
