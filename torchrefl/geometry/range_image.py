"""Range-image preprocessing of the seed dissertation, section 2.3 (eq. 2.1-2.8).

A cylindrical range image r (H, W) holds the distance (mm) from the rotation axis to the
surface. Column c has the rotation angle s = s0 + c * ds (radians), row k the height
t = t0 + k * dt (mm). The 3-D point of a pixel is (eq. 2.1)

    S(s, t) = (-r sin s, -t, -r cos s)            (world y is up, y = -t: row 0 is t0)

The chain (``preprocess_range_image``):

1. a 5 x 5 median filter over the *valid* pixels only (``median_filter_range``, torchrefl.geometry.range_median);
2. the Yokoya-Levine adaptive local quadratic fit (eq. 2.5-2.8, ``fit_quadratic_yokoya_levine``):
   of the 25 5 x 5 windows that contain a pixel, the one with the smallest least-squares
   residual is used, and its quadratic is evaluated *at the pixel*;
3. points from the fitted (smoothed) range r_hat (``cylindrical_points``, torchrefl.geometry.cylindrical);
4. unit outward normals from the cross product of the tangents (``cylindrical_normals``, same module).

Note on eq. 2.4 of the seed: as printed it reads
    N = {-r_s sin s - r cos s, -r_t r, -r_s cos s + r sin s} / sqrt(r_s^2 + r^2 + r^2 r_t^2),
which for a cylinder (r_s = r_t = 0) gives (-cos s, 0, sin s): a *tangent* of the cylinder, not
its normal. The printed x/z components are S_s itself. Taking the cross product of eq. 2.3,
    S_s = (-r_s sin s - r cos s, 0, -r_s cos s + r sin s),   S_t = (-r_t sin s, -1, -r_t cos s),
    S_t x S_s = (r_s cos s - r sin s, r r_t, -r_s sin s - r cos s),
whose length is the printed denominator sqrt(r_s^2 + r^2 + r^2 r_t^2). S_t x S_s points away from
the axis (for a cylinder it is r * (-sin s, 0, -cos s), parallel to the point's radial
direction), so it is the outward normal used here; S_s x S_t (the order printed in eq. 2.3)
points inward for this parametrisation.

All functions take torch tensors (float32 or float64), are vectorised over pixels and raise
GeometryError naming the argument on bad input.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from torchrefl.errors import GeometryError
from torchrefl.geometry.cylindrical import cylindrical_normals, cylindrical_points
from torchrefl.geometry.range_median import _check_odd, _check_range, _pad, _windows, median_filter_range

#: A pixel whose every candidate window holds an invalid (or out-of-image) pixel is fitted by
#: least squares over the valid pixels of its best partial window; that window must hold at
#: least this many valid pixels (6 unknowns + redundancy) and give a well-conditioned design.
FALLBACK_MIN_POINTS = 9
#: Largest condition number accepted for a partial window's (valid-rows) design matrix.
FALLBACK_MAX_CONDITION = 1.0e4
#: Fallback pixels are solved in chunks of this many to bound memory.
_FALLBACK_CHUNK = 2048


@dataclass
class QuadraticFit:
    """Per-pixel local quadratic fit (eq. 2.5-2.8).

    r_hat: (H, W) float, fitted range at the pixel, mm.
    r_s: (H, W) float, dr/ds at the pixel, mm per radian.
    r_t: (H, W) float, dr/dt at the pixel, mm per mm.
    residual: (H, W) float, sum of squared residuals of the chosen window (eq. 2.8), mm^2.
    valid: (H, W) bool, pixels with a fit; the other pixels hold NaN in the float maps.
    fallback: (H, W) bool, valid pixels fitted from a partial window (see FALLBACK_MIN_POINTS).
    """

    r_hat: torch.Tensor
    r_s: torch.Tensor
    r_t: torch.Tensor
    residual: torch.Tensor
    valid: torch.Tensor
    fallback: torch.Tensor


@dataclass
class RangeGeometry:
    """Preprocessed range image.

    points: (H, W, 3) float, eq. 2.1 from the smoothed range, mm; NaN where not valid.
    normals: (H, W, 3) float, unit, outward (away from the rotation axis); NaN where not valid.
    valid: (H, W) bool, pixels with a measured range and a quadratic fit.
    r_smoothed: (H, W) float, the fitted range r_hat (median filter + quadratic fit), mm; NaN where not valid.
    median_size: the median window applied (1 = none); noise_mm: the range noise estimated before it (mm).
    fit_rms_mm: (H, W) float, rms residual of the quadratic fit's chosen window, mm (NaN where not valid); None:
    not computed.
    spacing_mm: the grid's smaller spacing on the surface, mm: the row step or the median arc step r ds.
    """

    points: torch.Tensor
    normals: torch.Tensor
    valid: torch.Tensor
    r_smoothed: torch.Tensor
    median_size: int = 1
    noise_mm: float = 0.0
    fit_rms_mm: torch.Tensor | None = None
    spacing_mm: float = 0.0


# ----------------------------------------------------------------------------- checks


def _check_step(value, name: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise GeometryError(f"argument '{name}': expected a positive finite number, got {value!r}") from None
    if not math.isfinite(v) or v <= 0:
        raise GeometryError(f"argument '{name}': expected a positive finite number, got {value!r}")
    return v


def _check_tolerance(value) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise GeometryError(f"argument 'noise_tolerance': expected a finite number >= 0, got {value!r}") from None
    if not math.isfinite(v) or v < 0 or isinstance(value, bool):
        raise GeometryError(f"argument 'noise_tolerance': expected a finite number >= 0, got {value!r}")
    return v


# ----------------------------------------------------------------------------- helpers


def _design(k: int, dtype, device) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Quadratic basis [u^2, v^2, uv, u, v, 1] on the k x k grid (u: column offset, v: row offset).

    Returns A (k*k, 6), u (k*k,), v (k*k,), in unfold's row-major order.
    """
    h = k // 2
    off = torch.arange(-h, h + 1, dtype=dtype, device=device)
    v, u = torch.meshgrid(off, off, indexing="ij")
    u, v = u.reshape(-1), v.reshape(-1)
    A = torch.stack([u * u, v * v, u * v, u, v, torch.ones_like(u)], dim=-1)
    return A, u, v


def _offsets(k: int, adaptive: bool) -> list[tuple[int, int]]:
    """Offsets (dv, du) of the pixel inside its candidate window, centred window first (wins ties)."""
    h = k // 2
    if not adaptive:
        return [(0, 0)]
    offs = [(dv, du) for dv in range(-h, h + 1) for du in range(-h, h + 1)]
    return sorted(offs, key=lambda o: (o[0] ** 2 + o[1] ** 2, o))


def _evaluate(coef: torch.Tensor, u: torch.Tensor, v: torch.Tensor):
    """Quadratic (6, ...) at local (u, v): value, d/du, d/dv (eq. 2.5-2.7 in pixel units)."""
    a, b, c, d, e, f = coef
    value = a * u * u + b * v * v + c * u * v + d * u + e * v + f
    du = 2 * a * u + c * v + d
    dv = 2 * b * v + c * u + e
    return value, du, dv


# ----------------------------------------------------------------------------- quadratic fit


def fit_quadratic_yokoya_levine(
    r: torch.Tensor,
    valid: torch.Tensor,
    ds: float,
    dt: float,
    window: int = 5,
    *,
    wrap: bool = False,
    adaptive: bool = True,
    noise_tolerance: float = 0.0,
) -> QuadraticFit:
    """Yokoya-Levine adaptive local quadratic fit (eq. 2.5-2.8), evaluated at each pixel.

    r: (H, W) float32/float64 range, mm; valid: (H, W) bool; ds: column step, radians;
    dt: row step, mm; window: odd >= 3 (the seed uses 5).

    For each valid pixel, every window x window window that contains it (window^2 of them) and
    lies entirely on valid pixels inside the image (columns wrap when wrap=True) is a candidate;
    the one with the smallest sum of squared residuals (eq. 2.8) is chosen (ties: the window
    closest to centred), and its quadratic r_hat = a u^2 + b v^2 + c uv + d u + e v + f is
    evaluated AT THE PIXEL (local offset (u, v) inside that window), not at the window centre.
    The fit is done in pixel units (u columns, v rows) and the gradients converted:
    r_s = dr/du / ds (per radian), r_t = dr/dv / dt (per mm).

    The least-squares fit on a fixed grid is a linear projection: with A (k*k, 6) the design
    matrix, coefficients = pinv(A) @ patch and residual = |(I - A pinv(A)) patch|^2, computed
    for every window at once on unfolded patches; each patch is taken relative to its centre
    value for float32 accuracy.

    Pixels with no fully valid candidate window (thin features narrower than the window, the
    image border with adaptive=False): fallback, a weighted least-squares fit over the valid
    pixels of the candidate window with the most valid pixels (ties: smallest residual), among
    windows with at least FALLBACK_MIN_POINTS valid pixels and a design-matrix condition number
    below FALLBACK_MAX_CONDITION. Pixels without such a window are marked invalid (NaN maps).
    QuadraticFit.fallback tells which pixels were fitted this way.

    noise_tolerance (default 0: the seed's rule, strictly the smallest residual): with noise or
    range quantisation every window of a smooth patch fits about equally well, and the strict
    minimum picks an arbitrary one, often a corner window whose gradient at the pixel is an
    extrapolation (and, on 8-bit data, a window lying on one quantisation level, residual 0,
    slope 0). With noise_tolerance = c > 0 the most centred window whose residual is at most
    min + c * (window^2 - 6) * sigma^2 is taken, sigma^2 being the median residual per degree of
    freedom over the fully valid windows of the image; windows across a depth step have residuals
    far above that and are still avoided. Measured on an off-axis ellipsoid at the seed's
    resolution (interior median normal error): 8-bit range 3.4 -> 0.94 deg, Gaussian noise
    0.05 mm 1.4 -> 0.5 deg, with c = 2.

    adaptive=False: the plain centred fit (the only candidate is the window centred on the
    pixel): the reference of what the adaptive operator avoids at depth discontinuities.

    Returns QuadraticFit with (H, W) maps of r's dtype.
    """
    _check_range(r, valid)
    k = _check_odd(window, "window", minimum=3)
    ds = _check_step(ds, "ds")
    dt = _check_step(dt, "dt")
    noise_tolerance = _check_tolerance(noise_tolerance)
    H, W = r.shape
    if H < k or W < k:
        raise GeometryError(f"argument 'r': shape {(H, W)} is smaller than the {k} x {k} fitting window")
    _check_wrap(wrap, W, ds)
    dtype, device = r.dtype, r.device
    nan = float("nan")
    r0 = torch.where(valid, r, torch.zeros_like(r))  # invalid values never enter any product

    A, uu, vv = _design(k, dtype, device)
    coef, res, full, centre = _centred_window_fits(r0, valid, A, k, wrap)
    offsets = _offsets(k, adaptive)
    best, best_res = _best_windows(res, full, offsets, k, wrap, noise_tolerance if adaptive else 0.0)
    value, d_u, d_v = _evaluate_at_pixels(coef, centre, offsets, best, wrap)

    ok = valid & torch.isfinite(best_res)
    r_hat = torch.where(ok, value, nan)
    r_u = torch.where(ok, d_u, nan)
    r_v = torch.where(ok, d_v, nan)
    residual = torch.where(ok, best_res, nan)

    fallback = _fill_fallback(r0, valid & ~ok, valid, offsets, A, uu, vv, k, wrap, (r_hat, r_u, r_v, residual))
    fit_valid = ok | fallback
    return QuadraticFit(r_hat=r_hat, r_s=r_u / ds, r_t=r_v / dt, residual=residual, valid=fit_valid, fallback=fallback)


#: median_size None (auto) applies AUTO_MEDIAN_SIZE unless the range noise would tilt the quadratic fit's
#: normals by less than this (degrees): on a noise-free range image a median only rounds folds and creases
NOISE_FREE_NORMAL_DEG = 0.25
AUTO_MEDIAN_SIZE = 5


def estimate_range_noise(r: torch.Tensor, valid: torch.Tensor, window: int = 5, wrap: bool = False) -> float:
    """The range noise (mm): square root of the median, over the fully valid centred windows, of the quadratic fit's
    residual per degree of freedom. Folds and steps occupy few windows, so the median ignores them."""
    k = _check_odd(window, "window", minimum=3)
    if r.shape[0] < k or r.shape[1] < k:
        return 0.0
    A, _, _ = _design(k, torch.float64, r.device)
    r0 = torch.where(valid, r, torch.zeros_like(r)).double()
    _, res, full, _ = _centred_window_fits(r0, valid, A, k, wrap)
    if not bool(full.any()):
        return 0.0
    return float((res[full] / (k * k - 6)).median().clamp_min(0).sqrt())


def grid_spacing(r: torch.Tensor, valid: torch.Tensor, ds: float, dt: float) -> float:
    """The grid's smaller spacing on the surface (mm): the row step dt or the median arc step r ds."""
    arc = float(r[valid].double().median()) * ds if bool(valid.any()) else dt
    return min(dt, arc)


def auto_median_size(noise_mm: float, r: torch.Tensor, valid: torch.Tensor, ds: float, dt: float, window: int) -> int:
    """AUTO_MEDIAN_SIZE, or 1 where noise_mm tilts the window's fitted normals by under NOISE_FREE_NORMAL_DEG.

    The slope of a least-squares quadratic over a k x k window of spacing h has a standard deviation of about
    noise / (h sqrt(sum u^2)), sum u^2 = k^2 (k^2 - 1) / 12 (column offsets u in pixels); h is grid_spacing."""
    h = grid_spacing(r, valid, ds, dt)
    spread = math.sqrt(window * window * (window * window - 1) / 12.0)
    tilt_deg = math.degrees(noise_mm / max(h * spread, 1e-12))
    return 1 if tilt_deg < NOISE_FREE_NORMAL_DEG else AUTO_MEDIAN_SIZE


def median_note(median_size: int, noise_mm: float, configured: int | None) -> str:
    """One sentence on the median filter applied (median_size) and, when chosen automatically (configured None),
    why."""
    if configured is not None:
        return f"range median {median_size} x {median_size} (geometry.median_size)"
    if median_size == 1:
        return (
            f"no range median: the range image's noise ({noise_mm:.3g} mm) tilts normals by under a quarter degree, "
            "and a median would round its folds (geometry.median_size: auto)"
        )
    auto = "(geometry.median_size: auto)"
    return f"range median {median_size} x {median_size} against {noise_mm:.3g} mm of range noise {auto}"


def _check_wrap(wrap: bool, W: int, ds: float) -> None:
    if wrap and abs(W * ds - 2 * math.pi) > 0.01 * ds:
        raise GeometryError(
            f"argument 'wrap': wrap=True needs W * ds = 2 pi (a full turn), got "
            f"W * ds = {W * ds:.6g} rad for W = {W}, ds = {ds:.6g}"
        )


def _centred_window_fits(r0: torch.Tensor, valid: torch.Tensor, A: torch.Tensor, k: int, wrap: bool):
    """Least-squares quadratics of the k x k window centred on every pixel (centres outside the image are never
    fully valid), each patch relative to its centre value.

    Returns coef (6, H, W), residual (H, W) (inf where the window is not fully valid), full (H, W) bool
    (fully valid windows) and the centre values (H, W)."""
    h = k // 2
    dtype, device = r0.dtype, r0.device
    P = torch.linalg.pinv(A)  # (6, k*k)
    M = torch.eye(k * k, dtype=dtype, device=device) - A @ P  # residual projector
    patches = _windows(_pad(r0, h, wrap, 0.0), k)  # (k*k, H, W)
    full = _windows(_pad(valid.to(dtype), h, wrap, 0.0), k).amin(0) > 0.5  # (H, W)
    centre = patches[(k * k) // 2]
    rel = patches - centre
    coef = torch.einsum("pk,khw->phw", P, rel)  # (6, H, W)
    res = torch.einsum("jk,khw->jhw", M, rel).square().sum(0)  # (H, W)
    inf = torch.tensor(float("inf"), dtype=dtype, device=device)
    res = torch.where(full, res, inf)
    return coef, res, full, centre


def _best_windows(res: torch.Tensor, full: torch.Tensor, offsets, k: int, wrap: bool, noise_tolerance: float):
    """The chosen candidate window of each pixel (index into offsets, (H, W)) and its residual (H, W): the
    smallest residual or, with noise_tolerance > 0, the most centred window within the noise of it."""
    H, W = res.shape
    h = k // 2
    # candidate windows of each pixel: centre = pixel - offset
    res_pad = _pad(res, h, wrap, float("inf"))
    cand = torch.stack([res_pad[h - dv : h - dv + H, h - du : h - du + W] for dv, du in offsets])  # (K, H, W)
    best_res, best = cand.min(dim=0)
    if noise_tolerance > 0 and bool((full & (res > 0)).any()):
        # accept the most centred window whose residual is within the noise of the best one;
        # noise variance: median residual per degree of freedom of the fully valid windows
        # (windows with an exactly zero residual, e.g. on one 8-bit level, carry no noise information)
        sigma2 = (res[full & (res > 0)] / (k * k - 6)).median()
        accept = cand <= (best_res + noise_tolerance * (k * k - 6) * sigma2)[None]
        best = accept.to(torch.uint8).argmax(dim=0)
        best_res = torch.where(torch.isfinite(best_res), cand.gather(0, best[None])[0], best_res)
    return best, best_res


def _evaluate_at_pixels(coef: torch.Tensor, centre: torch.Tensor, offsets, best: torch.Tensor, wrap: bool):
    """Each pixel's chosen window quadratic evaluated at the pixel: value (range), d/du, d/dv (H, W)."""
    _, H, W = coef.shape
    dtype, device = coef.dtype, coef.device
    off = torch.tensor(offsets, dtype=torch.long, device=device)  # (K, 2) (dv, du)
    dv_b, du_b = off[best, 0], off[best, 1]  # (H, W)
    rows = torch.arange(H, device=device)[:, None]
    cols = torch.arange(W, device=device)[None, :]
    crow = (rows - dv_b).clamp(0, H - 1)
    ccol = cols - du_b
    ccol = ccol % W if wrap else ccol.clamp(0, W - 1)
    cf = coef[:, crow, ccol]  # (6, H, W)
    value, d_u, d_v = _evaluate(cf, du_b.to(dtype), dv_b.to(dtype))
    return value + centre[crow, ccol], d_u, d_v


def _fill_fallback(r0, need, valid, offsets, A, uu, vv, k, wrap, maps) -> torch.Tensor:
    """Fits the pixels `need` (H, W) bool with no fully valid window by _fallback_fit, in chunks, writing value,
    d/du, d/dv and residual into maps (four (H, W) tensors; NaN where no partial window fits either).
    Returns the (H, W) bool mask of the pixels so fitted."""
    W = r0.shape[1]
    nan = float("nan")
    fallback = torch.zeros_like(valid)
    if bool(need.any()):
        idx = need.flatten().nonzero().squeeze(1)
        for start in range(0, idx.numel(), _FALLBACK_CHUNK):
            chunk = idx[start : start + _FALLBACK_CHUNK]
            got = _fallback_fit(r0, valid, chunk, offsets, A, uu, vv, k, wrap)
            fit_ok, fit = got[0], got[1:]
            rr, cc = chunk // W, chunk % W
            for m, f in zip(maps, fit):
                m[rr, cc] = torch.where(fit_ok, f, nan)
            fallback[rr, cc] = fit_ok
    return fallback


def _fallback_fit(r0, valid, pix, offsets, A, uu, vv, k, wrap):
    """Weighted fits for pixels (flat indices pix (N,)) with no fully valid window.

    Returns ok (N,) bool, value, d/du, d/dv, residual (N,) of the chosen partial window.
    """
    H, W = r0.shape
    h = k // 2
    dtype, device = r0.dtype, r0.device
    N = pix.numel()
    prow, pcol = pix // W, pix % W
    off = torch.tensor(offsets, dtype=torch.long, device=device)  # (K, 2)
    K = off.shape[0]
    crow = prow[:, None] - off[None, :, 0]  # (N, K)
    ccol = pcol[:, None] - off[None, :, 1]
    ki = torch.arange(-h, h + 1, device=device)
    wr = crow[..., None, None] + ki[:, None]  # (N, K, k, 1)
    wc = ccol[..., None, None] + ki[None, :]  # (N, K, 1, k)
    inside = (wr >= 0) & (wr < H)
    if wrap:
        wc = wc % W
    else:
        inside = inside & (wc >= 0) & (wc < W)
    wr_c, wc_c = wr.clamp(0, H - 1), wc.clamp(0, W - 1)
    wr_c, wc_c = torch.broadcast_tensors(wr_c, wc_c)
    inside = inside.expand_as(wr_c)
    w = (valid[wr_c, wc_c] & inside).reshape(N, K, k * k)  # (N, K, k*k)
    z = r0[wr_c, wc_c].reshape(N, K, k * k)
    z = z - r0[prow, pcol][:, None, None]  # relative to the pixel's own range
    wf = w.to(dtype)
    # weighted normal equations G c = A^T W z, G = A^T W A (6 x 6 per candidate window)
    outer = (A[:, :, None] * A[:, None, :]).reshape(k * k, 36)
    G = (wf @ outer).reshape(N, K, 6, 6)
    lam = torch.linalg.eigvalsh(G)  # ascending
    cond = (lam[..., -1] / lam[..., 0].clamp_min(torch.finfo(dtype).tiny)).sqrt()  # of sqrt(W) A
    count = w.sum(-1)
    usable = (count >= FALLBACK_MIN_POINTS) & (lam[..., 0] > 0) & (cond < FALLBACK_MAX_CONDITION)
    eye = torch.eye(6, dtype=dtype, device=device)
    G = torch.where(usable[..., None, None], G, eye)
    coef = torch.linalg.solve(G, (z * wf) @ A)  # (N, K, 6)
    fitted = coef @ A.T  # (N, K, k*k)
    res = ((z - fitted) * wf).square().sum(-1)  # (N, K)
    # most valid pixels first, then smallest residual
    big = res.max().clamp_min(1.0) * 10 + 1
    score = torch.where(usable, -count.to(dtype) * big + res, torch.full_like(res, float("inf")))
    best = score.argmin(dim=1)
    ok = torch.isfinite(score.gather(1, best[:, None]).squeeze(1))
    cb = coef[torch.arange(N, device=device), best].T  # (6, N)
    dv_b = off[best, 0].to(dtype)
    du_b = off[best, 1].to(dtype)
    value, d_u, d_v = _evaluate(cb, du_b, dv_b)
    value = value + r0[prow, pcol]
    return ok, value, d_u, d_v, res[torch.arange(N, device=device), best]


# ----------------------------------------------------------------------------- the chain


def preprocess_range_image(
    r: torch.Tensor,
    valid: torch.Tensor,
    *,
    s0: float,
    ds: float,
    t0: float,
    dt: float,
    median_size: int | None = 5,
    window: int = 5,
    wrap: bool = False,
    noise_tolerance: float = 0.0,
) -> RangeGeometry:
    """Section 2.3: median filter, Yokoya-Levine quadratic fit, points and outward normals.

    r: (H, W) float32/float64 range, mm (values at invalid pixels are ignored);
    valid: (H, W) bool, pixels where the scanner measured the surface;
    s0, ds: angle of column 0 and column step, radians; t0, dt: height of row 0 and row step, mm;
    median_size: odd >= 1 (1 = no median), or None: auto (auto_median_size from the estimated noise); window: odd >= 3;
    wrap: columns wrap around (only when W * ds is a full turn);
    noise_tolerance: see fit_quadratic_yokoya_levine (0 = the seed's strict minimum; 2 is much
    better on noisy or 8-bit ranges).
    Returns RangeGeometry; valid = measured, fitted and with a finite normal.
    """
    _check_range(r, valid)
    if median_size is not None:
        _check_odd(median_size, "median_size")
    _check_odd(window, "window", minimum=3)
    ds = _check_step(ds, "ds")
    dt = _check_step(dt, "dt")
    for name, value in (("s0", s0), ("t0", t0)):
        if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(float(value)):
            raise GeometryError(f"argument '{name}': expected a finite number, got {value!r}")
    H, W = r.shape
    s = float(s0) + ds * torch.arange(W, dtype=r.dtype, device=r.device)
    t = float(t0) + dt * torch.arange(H, dtype=r.dtype, device=r.device)
    _check_wrap(wrap, W, ds)
    noise = estimate_range_noise(r, valid, window, wrap)
    if median_size is None:
        median_size = auto_median_size(noise, r, valid, ds, dt, window)
    rm = median_filter_range(r, valid, median_size, wrap=wrap)
    fit = fit_quadratic_yokoya_levine(rm, valid, ds, dt, window, wrap=wrap, noise_tolerance=noise_tolerance)
    points = cylindrical_points(fit.r_hat, s, t)
    normals = cylindrical_normals(fit.r_hat, fit.r_s, fit.r_t, s, t)
    ok = fit.valid & torch.isfinite(normals).all(-1) & torch.isfinite(points).all(-1)
    nan = float("nan")
    return RangeGeometry(
        points=torch.where(ok[..., None], points, nan),
        normals=torch.where(ok[..., None], normals, nan),
        valid=ok,
        r_smoothed=torch.where(ok, fit.r_hat, nan),
        median_size=int(median_size),
        noise_mm=noise,
        fit_rms_mm=torch.where(ok, (fit.residual.clamp_min(0) / (window * window)).sqrt(), nan),
        spacing_mm=grid_spacing(r, valid, ds, dt),
    )
