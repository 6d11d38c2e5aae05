"""Texels whose footprint the range image says is mixed: the texel's one plane does not describe it.

A texel is shaded as one point with one normal (its tangent plane), but its colour integrates its whole
footprint, which reaches half-way to its neighbours. Where that footprint straddles a rim, a thin edge, a
crease or a depth step, the colour mixes faces that the one normal cannot model: a plate's inside face and its
3 mm end face seen at a grazing light, for instance, read far brighter than the inside face's normal explains.

The test needs only the range image. For each texel and each of its 8 grid neighbours, the neighbour's measured
point (from the range as scanned, before smoothing) is compared with the texel's tangent plane (its smoothed
point and normal): the chord from the texel's point to the neighbour's rises from the plane by an angle. On a
surface that the grid resolves the chord stays close to the plane: a chord angle a means the normal turns by
about 2 a over one texel spacing, so MIXED_ANGLE_DEG = 30 degrees is a surface turning by 60 degrees or
more within one texel, or stepping, which the texel's footprint cannot see as one plane. Range noise lifts
the chord too: NOISE_ALLOWANCE range noise deviations (estimated from the image itself, range_noise_mm) are
subtracted from the rise first, so noisy or quantised scans are not flagged for their noise.
"""

from __future__ import annotations

import numpy as np

from torchrefl.errors import GeometryError

#: A neighbour's chord rising more than this from the texel's tangent plane marks a mixed footprint (degrees).
MIXED_ANGLE_DEG = 30.0
#: Rise (along the normal) forgiven as range noise, in robust standard deviations of the range noise.
NOISE_ALLOWANCE = 5.0
#: The 8 grid neighbours (row, column offsets).
NEIGHBOURS = [(dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1) if (dr, dc) != (0, 0)]


def range_noise_mm(r: np.ndarray, r_fit: np.ndarray, valid: np.ndarray) -> float:
    """Robust standard deviation (1.4826 x the median absolute deviation) of the measured range r (H, W) about
    the fitted range r_fit (H, W), over the valid (H, W) pixels: the scan's range noise in mm (0 for exact
    ranges). No valid pixel: 0."""
    r, r_fit, valid = np.asarray(r, dtype=np.float64), np.asarray(r_fit, dtype=np.float64), np.asarray(valid, bool)
    if r.shape != r_fit.shape or r.shape != valid.shape:
        raise GeometryError(
            f"range_noise_mm: 'r' {r.shape}, 'r_fit' {r_fit.shape} and 'valid' {valid.shape} must be one (H, W) grid"
        )
    dev = np.abs(r - r_fit)[valid & np.isfinite(r) & np.isfinite(r_fit)]
    return float(1.4826 * np.median(dev)) if dev.size else 0.0


def _neighbour(a: np.ndarray, dr: int, dc: int, wrap: bool) -> np.ndarray:
    """a (H, W, ...) float shifted so that [i, j] holds a[i + dr, j + dc] (NaN outside the grid; columns wrap
    around when wrap)."""
    H, W = a.shape[:2]
    out = np.full_like(a, np.nan)
    rows_src, rows_dst = slice(max(dr, 0), H + min(dr, 0)), slice(max(-dr, 0), H + min(-dr, 0))
    if wrap:
        out[rows_dst] = np.roll(a, -dc, axis=1)[rows_src]
        return out
    cols_src, cols_dst = slice(max(dc, 0), W + min(dc, 0)), slice(max(-dc, 0), W + min(-dc, 0))
    out[rows_dst, cols_dst] = a[rows_src, cols_src]
    return out


def chord_angles_deg(
    measured: np.ndarray, points: np.ndarray, normals: np.ndarray, noise_mm: float = 0.0, wrap: bool = False
) -> np.ndarray:
    """(H, W) the largest angle (degrees) by which a chord from a texel's point to a neighbour's measured point
    rises from the texel's tangent plane, after NOISE_ALLOWANCE x noise_mm of the rise is forgiven; 0 where no
    neighbour has a point.

    measured (H, W, 3): points of the range as scanned (NaN where none); points, normals (H, W, 3): the texels'
    smoothed points and unit normals (NaN where none); noise_mm >= 0; wrap: columns wrap around (a full turn).
    """
    measured, points, normals = (np.asarray(a, dtype=np.float64) for a in (measured, points, normals))
    if not (measured.shape == points.shape == normals.shape) or measured.ndim != 3 or measured.shape[-1] != 3:
        raise GeometryError(
            f"chord_angles_deg: 'measured' {measured.shape}, 'points' {points.shape} and 'normals' "
            f"{normals.shape} must each be (H, W, 3)"
        )
    if not np.isfinite(noise_mm) or noise_mm < 0:
        raise GeometryError(f"chord_angles_deg: 'noise_mm' must be a finite number >= 0, got {noise_mm!r}")
    worst = np.zeros(points.shape[:2])
    for dr, dc in NEIGHBOURS:
        chord = _neighbour(measured, dr, dc, wrap) - points
        rise = np.abs(np.einsum("hwi,hwi->hw", chord, normals))
        along = np.sqrt(np.maximum(np.einsum("hwi,hwi->hw", chord, chord) - rise * rise, 0.0))
        angle = np.degrees(np.arctan2(np.maximum(rise - NOISE_ALLOWANCE * noise_mm, 0.0), along))
        worst = np.fmax(worst, np.nan_to_num(angle, nan=0.0))
    return worst


def mixed_footprints(
    measured: np.ndarray,
    points: np.ndarray,
    normals: np.ndarray,
    valid: np.ndarray,
    noise_mm: float = 0.0,
    wrap: bool = False,
) -> np.ndarray:
    """(H, W) bool: valid texels whose footprint is mixed, a neighbour's chord rising more than MIXED_ANGLE_DEG
    from the texel's tangent plane (chord_angles_deg; the module docstring says why)."""
    valid = np.asarray(valid, dtype=bool)
    if valid.shape != np.shape(points)[:2]:
        raise GeometryError(f"mixed_footprints: 'valid' {valid.shape} is not the (H, W) of 'points' {np.shape(points)}")
    return valid & (chord_angles_deg(measured, points, normals, noise_mm, wrap) > MIXED_ANGLE_DEG)
