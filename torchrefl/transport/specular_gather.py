"""Final gathering of the receiving texel's specular reflection of diffusely reflected light.

The photon level predicts observation (p, t) as local + kappa (Pd_t / pi H_pt + Ps_t sum_e D(theta_e; sigma_t) c_e)
(torchrefl.transport.photon_cache). Its specular entries c_e come from the photons stored at t: a few per
observation at full size, and most land far outside a glossy lobe, so the entries are a handful of spikes.
That noise multiplies Ps in the fit and biases it down (errors in variables), and the lost specular
reflection of the neighbouring surfaces then goes into Pd (Object E's lower plate mirrors the upper one).

With photon.diffuse_paths 'radiosity' the light that reaches t after diffuse reflections only is known
without photon noise: a texel u sends L_pu = Pd_u (E_pu + H_pu) / pi towards t (the radiosity level's direct
and all-diffuse irradiance at u, with light p where t's image put it: the emitter maps of t's column,
interpolated as photon_level.map_weights does it). This module estimates t's specular reflection of that radiance
by gathering N directions l_k per texel from t's own lobe (mirrored about the view v_t, roughness sigma_s = min(1.25
sigma_t, sigma_max) at the refresh, so the fit may widen the lobe by a quarter before the next refresh and the weights
stay bounded), each traced with Embree to the texel u_k it hits:

    S_pt = 1/N sum_k D(theta_k; sigma_t) G(n.l_k, n.v_t) / pdf(l_k) * L_{p u_k}(t)

(the photon level's specular entry in expectation: Ps D G is the specular part of f cos_l, torchrefl.core.brdf).
The samples are emitted as entries of the photon cache's format (observation p T + t, theta_h, weight
G L / (N pdf)), merged per theta_h bin with the bins of the photons' (specular_bins.merge_entries), so D stays
differentiable in sigma_t and the product with Ps in Ps; L is fixed until the next refresh, like the photons'.
The photons then keep only the paths with a specular scattering in their specular entries
(build_cache(specular_paths_only=True)), so every path is counted once.

Rays that miss the scan or hit a surface's back carry nothing (a dark room; the radiosity level has no
light on the backs either). Directions: a scrambled Sobol set with a random toroidal shift per texel
(randomised QMC, unbiased), keyed by seed and refresh.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from torchrefl.core import brdf as brdf_mod
from torchrefl.core.distinct_rows import distinct_rows
from torchrefl.core.lobe_sampling import row_dot, sample_mixture
from torchrefl.core.rqmc import sobol_base, toroidal_shift
from torchrefl.errors import ConfigError
from torchrefl.transport.cache_build import LOBE_CUTOFF
from torchrefl.transport.photon_trace import PhotonTracer
from torchrefl.transport.specular_bins import BINS_PER_OBSERVATION, light_slices, theta_bins

WIDEN = 1.25  # sampling roughness over the texel's roughness at the refresh


@dataclass
class GatherSamples:
    """One refresh's gather directions, for every texel with a predicted observation.

    texel (S,) int64 receiving texel; hit (S,) int64 texel hit; theta_h (S,) angle between n_t and the
    half vector of (l, v_t); weight (S,) G / (N pdf) (per unit radiance); view (S,) int64 the distinct view
    (SpecularGather.view_of) the direction was drawn for, or -1 where every image shares the texel's view."""

    texel: np.ndarray
    hit: np.ndarray
    theta_h: np.ndarray
    weight: np.ndarray
    view: np.ndarray
    rays: int


class SpecularGather:
    """Gather directions from each texel's lobe and turn the radiosity level's radiance into specular entries.

    tracer: the photon level's PhotonTracer (Embree scene, texel lookup, face normals, origin offset);
    view_dirs (T, 3) or (P, T, 3); keep (P, T) bool predicted observations; brdf: the fitter's model;
    samples: directions per texel (and per distinct view where the images' views differ: images whose views are
    equal bit for bit, a camera's under its several lights, share their directions); min_cos_light:
    directions at or below this n.l carry no specular term (as in the photon entries and the fit);
    sigma_max: the fit's upper bound of sigma (caps the sampling roughness).
    """

    def __init__(
        self,
        tracer: PhotonTracer,
        view_dirs,
        keep,
        brdf: str,
        samples: int,
        min_cos_light: float,
        sigma_max: float,
        seed: int = 0,
    ):
        if int(samples) < 1:
            raise ConfigError(
                f"photon.specular_gather: expected a positive number of directions per texel, got {samples}"
            )
        if tracer.lobe is None:
            raise ConfigError(f"photon.specular_gather: reflectance.brdf '{brdf}' has no specular lobe to gather with")
        self.tracer = tracer
        self.view = np.asarray(view_dirs, dtype=np.float64)
        self.keep = np.asarray(keep, dtype=bool)
        # (V,) an image of each distinct view and (P,) each image's view (per-image views only)
        self.view_first, self.view_of = (
            (None, None) if self.view.ndim == 2 else distinct_rows(self.view.reshape(len(self.view), -1))
        )
        self.brdf = brdf
        self.samples = int(samples)
        self.min_cos_light = float(min_cos_light)
        self.sigma_max = float(sigma_max)
        self.seed = int(seed)

    def directions(self, sigma, refresh: int = 0) -> GatherSamples:
        """Draw and trace the directions for the texels' roughness sigma (T,) at this refresh."""
        N = self.samples
        rng = np.random.default_rng([self.seed, 0x67, int(refresh)])
        base = sobol_base(N, 2, rng)
        sig_all = np.minimum(
            WIDEN * np.maximum(np.asarray(sigma, dtype=np.float64), brdf_mod.SIGMA_EPS), self.sigma_max
        )
        groups = (
            [(-1, self.keep.any(0), self.view)]
            if self.view.ndim == 2
            else [(g, self.keep[self.view_of == g].any(0), self.view[p]) for g, p in enumerate(self.view_first)]
        )
        parts, rays = [], 0
        for group, wanted, view in groups:
            texels = np.flatnonzero(wanted)
            if not texels.size:
                continue
            t = np.repeat(texels, N)
            u = toroidal_shift(base, rng.random((len(texels), 2)))
            n, v, sig = self.tracer.normals[t], view[t], sig_all[t]
            l, pdf = sample_mixture(
                self.tracer.lobe, n, v, None, None, sig, np.column_stack([u, np.zeros(len(t))]), q=np.ones(len(t))
            )
            cos_i, cos_v = row_dot(n, l), row_dot(n, v)
            ok = np.flatnonzero((cos_i > self.min_cos_light) & (cos_v > 0) & (pdf > 0))
            t, n, v, l, pdf, cos_i, cos_v = t[ok], n[ok], v[ok], l[ok], pdf[ok], cos_i[ok], cos_v[ok]
            hits = self.tracer.tracer.closest_hit(self.tracer.positions[t] + self.tracer.offset * n, l)
            rays += len(t)
            front = hits.hit.copy()
            i = np.flatnonzero(front)
            front[i] = row_dot(self.tracer.face_normals[hits.triangle[i]], l[i]) < 0  # the lit side faces the ray
            i = np.flatnonzero(front)
            hit, _ = self.tracer.hit_texels(hits.triangle[i], hits.barycentric[i, 0], hits.barycentric[i, 1], l[i].T)
            t, n, v, l, pdf, cos_i, cos_v = t[i], n[i], v[i], l[i], pdf[i], cos_i[i], cos_v[i]
            with torch.no_grad():
                tt = lambda x: torch.from_numpy(np.ascontiguousarray(x))
                theta = brdf_mod.half_angle(tt(n), tt(l), tt(v)).numpy()
                geom = brdf_mod.specular_geometry(self.brdf, tt(cos_i), tt(cos_v)).numpy()
                alive = (
                    brdf_mod.specular_lobe(
                        self.brdf, tt(theta), tt(np.minimum(3.0 * sig_all[t] / WIDEN, self.sigma_max))
                    ).numpy()
                    > LOBE_CUTOFF
                )
            a = np.flatnonzero(alive)
            parts.append(
                (
                    t[a],
                    hit.astype(np.int64)[a],
                    theta[a],
                    geom[a] / (N * pdf[a]),
                    np.full(a.size, group, dtype=np.int64),
                )
            )
        if not parts:
            z = np.zeros(0)
            return GatherSamples(z.astype(np.int64), z.astype(np.int64), z, z, z.astype(np.int64), rays)
        cat = lambda j: np.concatenate([x[j] for x in parts])
        return GatherSamples(cat(0), cat(1), cat(2), cat(3), cat(4), rays)

    def entries(
        self, samples: GatherSamples, radiance, map_weights, sigma
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Specular entries (entry_obs (E,), theta_h (E,), weight (E, 3)) from the outgoing radiance
        (P, K, T, 3) of every texel with light p at map k's source, map_weights (K, T) (each texel's weights
        over the maps: photon_level.map_weights), and sigma (T,) (the merge bins' widths).

        The samples of a texel are grouped per theta_h bin (the bins of specular_bins.merge_entries) once for the
        images that share its view (a scan's) and per image where each has its own (mesh_views: an image reads only
        its own view's samples); per image a group's weight is the sum of its samples' G L / (N pdf) and its theta_h
        their mean weighted by that (as merge_entries weighs photons). Sorted by image, texel and bin."""
        R = np.asarray(radiance, dtype=np.float64)
        P, K, T, _ = R.shape
        Wm = np.asarray(map_weights, dtype=np.float64)
        if Wm.shape != (K, T):
            raise ValueError(f"specular gather: map weights of shape {Wm.shape}, expected {(K, T)}")
        order = np.argsort(-np.abs(Wm), axis=0, kind="stable")[: max(1, int((Wm != 0).sum(0).max(initial=0)))]
        t = samples.texel
        empty = np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros((0, 3))
        if not t.size:
            return empty
        bins = theta_bins(samples.theta_h, np.take(np.asarray(sigma, dtype=np.float64), t))
        obs, th, wt = [], [], []
        for images, sel in _image_samples(samples.view, self.view_of, P):
            part = self._image_entries(samples, sel, bins, images, R, Wm, order)
            for out, x in zip((obs, th, wt), part):
                out.extend(x)
        return np.concatenate(obs), np.concatenate(th), np.concatenate(wt)

    def _image_entries(self, samples: GatherSamples, sel, bins, images, R, Wm, order) -> tuple[list, list, list]:
        """entries' part for the images `images` from the samples sel (their view's): per image, its observations'
        groups of samples per theta_h bin (obs, theta_h, weight), sorted by texel and bin."""
        P, K, T, _ = R.shape
        t, hit, w, theta_h = (np.take(x, sel) for x in (samples.texel, samples.hit, samples.weight, samples.theta_h))
        nb = BINS_PER_OBSERVATION
        uniq, group = torch.unique(torch.from_numpy(t * nb + np.take(bins, sel)), sorted=True, return_inverse=True)
        uniq, group = uniq.numpy(), group.numpy()
        G = len(uniq)
        g_texel = uniq // nb
        wsum = np.bincount(group, weights=w, minlength=G)
        g_theta = np.bincount(group, weights=w * theta_h, minlength=G) / np.maximum(wsum, 1e-300)
        # each sample's maps and their weights: radiance of the texel hit with the light where t's image put it
        k_s = [np.take(order[j], t) for j in range(order.shape[0])]
        a_s = [Wm[k, t] * w for k in k_s]
        obs, th, wt = [], [], []
        for p in images:
            flat = R[p].reshape(K * T, 3).T  # (3, K T), component-major
            L = np.zeros((3, t.size))
            for k, a in zip(k_s, a_s):
                L += np.take(flat, k * T + hit, axis=1) * a
            vals = np.stack([np.bincount(group, weights=L[c], minlength=G) for c in range(3)], -1)
            m = L.mean(0)
            msum = np.bincount(group, weights=m, minlength=G)
            theta = np.where(
                msum > 0,
                np.bincount(group, weights=m * theta_h, minlength=G) / np.where(msum > 0, msum, 1.0),
                g_theta,
            )
            gk = np.flatnonzero(self.keep[p, g_texel] & (vals.max(-1) > 0))
            obs.append(p * T + g_texel[gk])
            th.append(theta[gk])
            wt.append(vals[gk])
        return obs, th, wt


def _image_samples(view: np.ndarray, view_of: np.ndarray | None, P: int) -> list[tuple[range | list, np.ndarray]]:
    """(images, samples) pairs: every image reads every sample where the texels' view is shared (view -1), else the
    images of each distinct view (view_of (P,)) that view's samples, in the samples' order."""
    if view_of is None or not (view >= 0).any():
        return [(range(P), np.arange(view.size))]
    V = int(view_of.max()) + 1
    return [(np.flatnonzero(view_of == g).tolist(), idx) for g, idx in enumerate(light_slices(view, 1, V))]
