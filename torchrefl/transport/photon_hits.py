"""The photon hits a trace stores (torchrefl.transport.photon_trace): per hit its source, texel, incident direction,
flux and what the cache (torchrefl.transport.photon_cache) needs to keep the last bounce linear in Pd."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np


@dataclass
class PhotonHits:
    """Stored photon hits (second and later bounces) of all sources.

    source: (N,) int64 index of the emitting source; texel: (N,) int64 receiving texel;
    direction: (N, 3) float32 unit incident direction wi; power: (N, 3) float32 flux Phi;
    emitter: (N,) int64 texel of the photon's last scattering; specular_path: (N,) bool whether any scattering on
    the photon's path so far took the specular lobe (the rest, all-diffuse paths, is what the radiosity level
    computes); density_weight: (N,) float32 max(n_t.wi, 0) / n_f.wi of the hit (the module doc of
    torchrefl.transport.photon_trace; None = 1); diffuse_per_pd: (N, 3) float32 the share of Phi that is linear
    in the emitter's Pd, per unit Pd (Phi_in / ((1 - q) s) after a diffuse scattering with roulette survival s,
    0 after a specular one), so that Phi(Pd') = Phi + diffuse_per_pd (Pd' - Pd) for the last bounce,
    exactly per photon and unbiased over photons (ScatterTables for where q rounds to 1).
    emitted: (S,) photons emitted per source; rays: closest-hit rays traced in all; back_hits: rays that hit
    the back of the scanned surface (absorbed: they passed a hole or an unscanned side of the object, whose
    interreflection is not modelled).
    """

    source: np.ndarray
    texel: np.ndarray
    direction: np.ndarray
    power: np.ndarray
    emitted: np.ndarray
    rays: int
    emitter: np.ndarray | None = None
    diffuse_per_pd: np.ndarray | None = None
    back_hits: int = 0
    specular_path: np.ndarray | None = None
    density_weight: np.ndarray | None = None

    def take(self, idx: np.ndarray) -> "PhotonHits":
        """The hits idx (M,) (a copy), with the totals (emitted, rays, back hits) of all."""
        sub = lambda a: None if a is None else np.take(a, idx, axis=0)  # noqa: E731
        per_hit = (
            "source",
            "texel",
            "direction",
            "power",
            "emitter",
            "diffuse_per_pd",
            "specular_path",
            "density_weight",
        )
        return replace(self, **{k: sub(getattr(self, k)) for k in per_hit})

    @property
    def count(self) -> int:
        return int(len(self.texel))


def shared_hits(hits: PhotonHits, light_of: np.ndarray, K: int) -> PhotonHits:
    """The hits of the distinct lights' traces (sources u * K + k) as the hits of every image (sources p * K + k):
    each image gets a copy of its light's hits; emitted (P * K,)."""
    light = hits.source // K
    parts = [np.flatnonzero(light == u) for u in light_of]
    take = np.concatenate(parts) if parts else np.zeros(0, np.int64)
    image = np.repeat(np.arange(len(light_of)), [len(i) for i in parts])
    per_source = hits.emitted.reshape(-1, K)
    source = image * K + hits.source[take] % K
    return replace(hits.take(take), source=source, emitted=per_source[light_of].reshape(-1))
