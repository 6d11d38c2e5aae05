"""Texels whose footprint the range image says is mixed: the texel's one plane does not describe it.

A texel is shaded as one point with one normal (its tangent plane), but its colour integrates its whole
footprint, which reaches half-way to its neighbours. Where that footprint straddles a rim, a thin edge, a
crease or a depth step, the colour mixes faces that the one normal cannot model: a plate's inside face and its
3 mm end face seen at a grazing light, for instance, read far brighter than the inside face's normal explains.

The test needs only the range image. For a texel 0 and each of its 8 grid neighbours 1, two rises are measured:
s0, the neighbour's scanned point (the range as measured, before smoothing) above texel 0's tangent plane (its
smoothed point and normal), and s1, texel 0's scanned point above the neighbour's tangent plane. Range noise
is forgiven first: NOISE_ALLOWANCE times the scan's own range noise (RangeGeometry.noise_mm, from the
quadratic fits' median residual) comes off both rises, so noisy or quantised scans are not flagged for
their noise. Then, with d the distance between
the two texels' points:

- a crease (s0 and s1 of one sign: each point lies on the same side of the other's plane, a fold or a rim):
  the two planes meet at the fraction a = |s1| / (|s0| + |s1|) of the way from texel 0 to its neighbour (in
  the plane across the crease, by the law of sines), and turn by asin(|s0| / d) + asin(|s1| / d). Texel 0
  is mixed when the crease turns by more than MIXED_ANGLE_DEG and lies within CREASE_FRACTION of the way:
  then more than a sixth of its footprint (which reaches half-way) lies on the other face. A fold line between
  two texels leaves both clean (a = 1/2), a texel on the fold line is mixed (its normal is both faces'
  average, a = 0), and on a smooth surface s0 and s1 match (a = 1/2) whatever its curvature;
- a step (s0 and s1 of opposite signs: parallel faces at different depths, a plate lying on another, a plate's
  end seen against what is behind it): where between the two samples the wall stands the range cannot say,
  so texel 0 is mixed when its neighbour rises from its plane by more than MIXED_ANGLE_DEG (asin(|s0| / d)):
  a wall at least as steep as that within one texel.

A texel can also be untrusted for its normal alone (unfit_windows): where every fitting window that contains it
spans a crease or an edge (a strip of a plate's end face narrower than the window, the first texels beyond a rim),
the chosen quadratic leaves a residual no smooth surface leaves and the fitted normal extrapolates across the
crease (6-20 degrees on the fold's end faces, Pd 10-30 % off). A quadratic describes a smooth surface over a
window to far under UNFIT_FRACTION of the grid spacing, so a texel whose window's rms residual exceeds that plus
NOISE_ALLOWANCE times the range noise is untrusted.
"""

from __future__ import annotations

import numpy as np

from torchrefl.errors import GeometryError

#: A crease turning by more than this, or a step rising more than this within one texel, can mix a footprint (degrees).
MIXED_ANGLE_DEG = 30.0
#: A crease closer than this fraction of the way to a neighbour puts more than a sixth of the footprint across it.
CREASE_FRACTION = 1.0 / 3.0
#: Rise (along the normal) forgiven as range noise, in robust standard deviations of the range noise.
NOISE_ALLOWANCE = 5.0
#: A fitting window's rms residual above this fraction of the grid spacing (plus the noise allowance) is no smooth
#: surface: the window spans a crease or an edge.
UNFIT_FRACTION = 0.01
#: The 8 grid neighbours (row, column offsets).
NEIGHBOURS = [(dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1) if (dr, dc) != (0, 0)]


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


def _check_points(measured, points, normals, noise_mm) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    measured, points, normals = (np.asarray(a, dtype=np.float64) for a in (measured, points, normals))
    if not (measured.shape == points.shape == normals.shape) or measured.ndim != 3 or measured.shape[-1] != 3:
        raise GeometryError(
            f"mixed_footprints: 'measured' {measured.shape}, 'points' {points.shape} and 'normals' "
            f"{normals.shape} must each be (H, W, 3)"
        )
    if not np.isfinite(noise_mm) or noise_mm < 0:
        raise GeometryError(f"mixed_footprints: 'noise_mm' must be a finite number >= 0, got {noise_mm!r}")
    return measured, points, normals


def _mixed_towards(rise0: np.ndarray, rise1: np.ndarray, distance: np.ndarray, noise: float) -> np.ndarray:
    """(H, W) bool: the footprint of texel 0 is mixed by what lies towards one neighbour (the module docstring):
    rise0 the neighbour's scanned point above texel 0's plane, rise1 texel 0's scanned point above the
    neighbour's plane, distance between them, noise the rise forgiven (all (H, W), NaN where no neighbour)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        sin0 = np.clip((np.abs(rise0) - noise) / distance, 0.0, 1.0)
        sin1 = np.clip((np.abs(rise1) - noise) / distance, 0.0, 1.0)
    limit = np.radians(MIXED_ANGLE_DEG)
    crease = np.sign(rise0) == np.sign(rise1)
    turns = np.arcsin(sin0) + np.arcsin(sin1) > limit
    near = sin1 * (1.0 - CREASE_FRACTION) < sin0 * CREASE_FRACTION  # a = sin1 / (sin0 + sin1) < CREASE_FRACTION
    mixed = np.where(crease, turns & near, np.arcsin(sin0) > limit)
    return mixed & np.isfinite(distance) & (distance > 0)


def mixed_footprints(
    measured: np.ndarray,
    points: np.ndarray,
    normals: np.ndarray,
    valid: np.ndarray,
    noise_mm: float = 0.0,
    wrap: bool = False,
) -> np.ndarray:
    """(H, W) bool: valid texels whose footprint is mixed by a crease or a step towards one of their 8 grid
    neighbours (the module docstring says how).

    measured (H, W, 3): points of the range as scanned (NaN where none); points, normals (H, W, 3): the texels'
    smoothed points and unit normals (NaN where none); valid (H, W) bool; noise_mm >= 0: the range noise
    (RangeGeometry.noise_mm); wrap: columns wrap around (a full turn).
    """
    measured, points, normals = _check_points(measured, points, normals, noise_mm)
    valid = np.asarray(valid, dtype=bool)
    if valid.shape != points.shape[:2]:
        raise GeometryError(f"mixed_footprints: 'valid' {valid.shape} is not the (H, W) of 'points' {points.shape}")
    dot = lambda a, b: np.einsum("hwi,hwi->hw", a, b)
    mixed = np.zeros(valid.shape, dtype=bool)
    for dr, dc in NEIGHBOURS:
        their_measured = _neighbour(measured, dr, dc, wrap)
        chord = their_measured - points
        rise0 = dot(chord, normals)
        rise1 = dot(measured - _neighbour(points, dr, dc, wrap), _neighbour(normals, dr, dc, wrap))
        distance = np.linalg.norm(their_measured - measured, axis=-1)
        mixed |= _mixed_towards(rise0, rise1, distance, NOISE_ALLOWANCE * noise_mm)
    return valid & mixed


def unfit_windows(fit_rms_mm: np.ndarray, valid: np.ndarray, spacing_mm: float, noise_mm: float = 0.0) -> np.ndarray:
    """(H, W) bool: valid texels whose quadratic fit window (RangeGeometry.fit_rms_mm, mm) leaves an rms residual
    over UNFIT_FRACTION * spacing_mm + NOISE_ALLOWANCE * noise_mm (the module docstring)."""
    rms = np.asarray(fit_rms_mm, dtype=np.float64)
    if not np.isfinite(spacing_mm) or spacing_mm <= 0:
        raise GeometryError(f"unfit_windows: 'spacing_mm' must be a positive number, got {spacing_mm!r}")
    limit = UNFIT_FRACTION * spacing_mm + NOISE_ALLOWANCE * noise_mm
    with np.errstate(invalid="ignore"):
        return np.asarray(valid, dtype=bool) & (rms > limit)
