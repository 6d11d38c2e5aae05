"""Direction sampling for Monte Carlo transport: cosine-weighted, specular-lobe and their mixture.

Shared by the synthetic renderer (torchrefl.synthetic.path_tracer, camera paths) and the photon level
(torchrefl.transport.photon_trace, light paths). numpy in, numpy out, vectorised over rays.

Mixture: with probability q = mean(Ps) / (mean(Pd) + mean(Ps)) a direction from the specular lobe
(Torrance-Sparrow theta_h Gaussian or Ward), otherwise cosine-weighted; `mixture_pdf` is the pdf of
the mixture, so weights g / pdf are unbiased for any q.
"""

from __future__ import annotations

import numpy as np

from torchrefl.core import brdf as brdf_mod
from torchrefl.errors import GeometryError

LOBES = {"torrance_sparrow": "torrance_sparrow", "ward": "ward", "ward_normalised": "ward", "lambertian": None}


def row_dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("ni,ni->n", a, b)


def column_dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N,) dot products of the columns of two component-major (3, N) arrays (the fast layout for numpy)."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def tangent_frame(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Orthonormal tangents t, b (N, 3) with t x b = n for unit normals n (N, 3) (Duff et al. 2017)."""
    sign = np.where(n[:, 2] >= 0, 1.0, -1.0)
    a = -1.0 / (sign + n[:, 2])
    c = n[:, 0] * n[:, 1] * a
    t = np.stack([1.0 + sign * n[:, 0] ** 2 * a, sign * c, -sign * n[:, 0]], -1)
    b = np.stack([c, sign + n[:, 1] ** 2 * a, -n[:, 1]], -1)
    return t, b


def _from_local(n, x, y, z):
    t, b = tangent_frame(n)
    return x[:, None] * t + y[:, None] * b + z[:, None] * n


def sample_cosine(n: np.ndarray, u1: np.ndarray, u2: np.ndarray) -> np.ndarray:
    """(N, 3) cosine-weighted directions about unit normals n (N, 3); pdf = max(n.l, 0) / pi."""
    r = np.sqrt(u1)
    phi = 2 * np.pi * u2
    return _from_local(n, r * np.cos(phi), r * np.sin(phi), np.sqrt(np.maximum(1.0 - u1, 0.0)))


def _ts_norm(sigma: np.ndarray) -> np.ndarray:
    """Z(sigma) = sigma^2 (1 - exp(-(pi/2)^2 / (2 sigma^2))), the normaliser of theta exp(-theta^2/(2 sigma^2))."""
    return sigma * sigma * -np.expm1(-((np.pi / 2) ** 2) / (2 * sigma * sigma))


def half_vector_pdf(model: str, cos_h: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Solid-angle pdf (N,) of half vectors at cos(theta_h) (upper hemisphere) for the lobe sampler.

    torrance_sparrow: theta_h on [0, pi/2] with density theta exp(-theta^2/(2 sigma^2)) / Z, phi uniform,
        so p_h = theta exp(-theta^2/(2 sigma^2)) / (2 pi Z sin theta) (theta / sin theta is bounded).
    ward: tan theta_h = sigma sqrt(-ln u) (Walter 2005), p_h = exp(-tan^2/sigma^2) / (pi sigma^2 cos^3).
    """
    c = np.clip(cos_h, 0.0, 1.0)
    s = np.sqrt(np.maximum(1.0 - c * c, 0.0))
    theta = np.arctan2(s, c)
    if model == "torrance_sparrow":
        ratio = np.where(s > 1e-8, theta / np.maximum(s, 1e-300), 1.0)
        return ratio * np.exp(-theta * theta / (2 * sigma * sigma)) / (2 * np.pi * _ts_norm(sigma))
    if model == "ward":
        cc = np.maximum(c, 1e-12)
        tan2 = (s / cc) ** 2
        return np.where(c > 0, np.exp(-tan2 / (sigma * sigma)) / (np.pi * sigma * sigma * cc**3), 0.0)
    raise GeometryError(f"synthetic.brdf: no lobe sampler for '{model}'")


def sample_lobe(
    model: str, n: np.ndarray, v: np.ndarray, sigma: np.ndarray, u1: np.ndarray, u2: np.ndarray
) -> np.ndarray:
    """(N, 3) directions l: a half vector h drawn from the lobe about n, then l = reflect(v, h).

    n, v: (N, 3) unit; sigma: (N,) roughness (radians). Its pdf is `lobe_pdf` (over the whole sphere;
    directions below the surface simply carry zero BRDF).
    """
    sig = np.maximum(sigma, brdf_mod.SIGMA_EPS)
    if model == "torrance_sparrow":
        theta = sig * np.sqrt(-2.0 * np.log1p(-u1 * -np.expm1(-((np.pi / 2) ** 2) / (2 * sig * sig))))
        theta = np.minimum(theta, np.pi / 2)
    elif model == "ward":
        theta = np.arctan(sig * np.sqrt(-np.log(np.maximum(1.0 - u1, 1e-300))))
    else:
        raise GeometryError(f"synthetic.brdf: no lobe sampler for '{model}'")
    phi = 2 * np.pi * u2
    st = np.sin(theta)
    h = _from_local(n, st * np.cos(phi), st * np.sin(phi), np.cos(theta))
    return 2.0 * row_dot(v, h)[:, None] * h - v


def lobe_pdf(model: str, n: np.ndarray, v: np.ndarray, l: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """(N,) solid-angle pdf of `sample_lobe` producing direction l: p_h(h) / (4 |v.h|), h = +-(l+v)/|l+v|
    taken in the upper hemisphere of n."""
    sig = np.maximum(sigma, brdf_mod.SIGMA_EPS)
    h = l + v
    norm = np.linalg.norm(h, axis=-1)
    h = h / np.maximum(norm, 1e-300)[:, None]
    cos_h = row_dot(n, h)
    h = np.where((cos_h < 0)[:, None], -h, h)
    cos_h = np.abs(cos_h)
    vh = np.abs(row_dot(v, h))
    p = half_vector_pdf(model, cos_h, sig) / np.maximum(4.0 * vh, 1e-300)
    return np.where(norm > 1e-12, p, 0.0)


def specular_probability(lobe: str | None, pd: np.ndarray, ps: np.ndarray) -> np.ndarray:
    """(N,) probability of sampling the specular lobe for reflectances pd, ps (N, 3)."""
    if lobe is None:
        return np.zeros(len(pd))
    a, b = pd.mean(-1), ps.mean(-1)
    return np.where(a + b > 0, b / np.maximum(a + b, 1e-300), 0.0)


def mixture_pdf(lobe: str | None, n, v, l, pd, ps, sigma) -> np.ndarray:
    """(N,) solid-angle pdf of `sample_mixture` producing l."""
    q = specular_probability(lobe, pd, ps)
    p = (1.0 - q) * np.maximum(row_dot(n, l), 0.0) / np.pi
    i = np.flatnonzero(q > 0)
    if i.size:
        p[i] += q[i] * lobe_pdf(lobe, n[i], v[i], l[i], sigma[i])
    return p


def _combine(t, b, n, x, y, z) -> np.ndarray:
    """x t + y b + z n, with few temporaries."""
    d = t * x[:, None]
    d += b * y[:, None]
    d += n * z[:, None]
    return d


def lobe_constants(lobe: str, sigma: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-roughness constants of the lobe sampler, for callers that draw many half vectors per texel:
    (truncation, ratio_scale), each (N,) float64 for sigma (N,) (already >= brdf.SIGMA_EPS).

    torrance_sparrow: truncation = 1 - exp(-(pi/2)^2 / (2 sigma^2)) (the share of the Gaussian in theta_h
    below pi/2), ratio_scale = 2 pi Z(sigma); ward: truncation = 1 (unused), ratio_scale = 1/4.
    """
    sigma = np.asarray(sigma, dtype=np.float64)
    if lobe == "torrance_sparrow":
        trunc = -np.expm1(-((np.pi / 2) ** 2) / (2 * sigma * sigma))
        return trunc, 2 * np.pi * sigma * sigma * trunc
    if lobe == "ward":
        return np.ones_like(sigma), np.full_like(sigma, 0.25)
    raise GeometryError(f"synthetic.brdf: no lobe sampler for '{lobe}'")


def lobe_over_pdf(
    lobe: str, theta: np.ndarray, cos_theta: np.ndarray, sin_theta: np.ndarray, ratio_scale: np.ndarray
) -> np.ndarray:
    """D(theta_h; sigma) / p_h(theta_h): brdf.specular_lobe over the solid-angle pdf of the half vectors
    `half_vector_pdf` draws, in closed form (the exponentials cancel, so it stays finite in the far tail):
    torrance_sparrow 2 pi Z sin(theta) / theta (2 pi Z at theta = 0), ward cos^3(theta) / 4, with
    ratio_scale from lobe_constants. Any float dtype (float32 in, float32 out when ratio_scale is float32 too)."""
    if lobe == "torrance_sparrow":
        small = theta < 1e-4
        return ratio_scale * np.where(small, 1.0, sin_theta / np.where(small, 1.0, theta)).astype(theta.dtype)
    if lobe == "ward":
        return ratio_scale * (cos_theta * cos_theta * cos_theta)
    raise GeometryError(f"synthetic.brdf: no lobe sampler for '{lobe}'")


def lobe_theta(lobe: str, sigma: np.ndarray, u1: np.ndarray, truncation: np.ndarray | None = None) -> np.ndarray:
    """theta_h drawn from the lobe's half-vector distribution (see sample_lobe); truncation: lobe_constants'
    (computed here when None)."""
    if lobe == "torrance_sparrow":
        if truncation is None:
            truncation = -np.expm1(-((np.pi / 2) ** 2) / (2 * sigma * sigma))
        theta = sigma * np.sqrt(-2.0 * np.log1p(-u1 * truncation))
        return np.minimum(theta, np.float32(np.pi / 2) if theta.dtype == np.float32 else np.pi / 2)
    if lobe == "ward":
        return np.arctan(sigma * np.sqrt(-np.log(np.maximum(1.0 - u1, 1e-300))))
    raise GeometryError(f"synthetic.brdf: no lobe sampler for '{lobe}'")


def sample_mixture(lobe: str | None, n, v, pd, ps, sigma, u, frame=None, q=None, with_cos_h: bool = False):
    """Directions (N, 3) about normals n with the lobe mirrored from v, and their pdf (N,), from
    uniforms u (N, 3) (u[:, 2] picks the component).

    The same distribution as sample_cosine / sample_lobe chosen by u[:, 2] < q with the pdf of
    mixture_pdf, fused into one pass (one tangent frame, one half vector): the path tracer's sampler
    (torchrefl.synthetic.path_tracer; the photon tracer selects one component per sample instead).
    frame: precomputed tangent_frame(n); q: precomputed specular_probability(lobe, pd, ps) (then pd and ps
    are not read); with_cos_h: also return n.h (N,) of the half vector h = normalize(l + v).
    """
    t, b = tangent_frame(n) if frame is None else frame
    u1 = u[:, 0]
    phi = 2 * np.pi * u[:, 1]
    cphi, sphi = np.cos(phi), np.sin(phi)
    if lobe is None:
        st, ct = np.sqrt(u1), np.sqrt(np.maximum(1.0 - u1, 0.0))
        l = _combine(t, b, n, st * cphi, st * sphi, ct)
        if with_cos_h:
            h = l + v
            return l, ct / np.pi, row_dot(n, h) / np.maximum(np.sqrt(row_dot(h, h)), 1e-300)
        return l, ct / np.pi
    q = specular_probability(lobe, pd, ps) if q is None else q
    spec = u[:, 2] < q
    sig = np.maximum(sigma, brdf_mod.SIGMA_EPS)
    theta = lobe_theta(lobe, sig, u1)
    st = np.where(spec, np.sin(theta), np.sqrt(u1))
    ct = np.where(spec, np.cos(theta), np.sqrt(np.maximum(1.0 - u1, 0.0)))
    d = _combine(t, b, n, st * cphi, st * sphi, ct)
    l = np.where(spec[:, None], 2.0 * row_dot(v, d)[:, None] * d - v, d)
    # pdf of the mixture at l (the half vector of the lobe samples is d itself, up to rounding)
    h = l + v
    norm = np.sqrt(row_dot(h, h))
    h /= np.maximum(norm, 1e-300)[:, None]
    cos_h = row_dot(n, h)
    vh = np.abs(row_dot(v, h))
    p_lobe = np.where(norm > 1e-12, half_vector_pdf(lobe, np.abs(cos_h), sig) / np.maximum(4.0 * vh, 1e-300), 0.0)
    pdf = (1.0 - q) * np.maximum(row_dot(n, l), 0.0) / np.pi + q * p_lobe
    return (l, pdf, cos_h) if with_cos_h else (l, pdf)
