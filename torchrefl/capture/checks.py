"""Checks of a capture before any fit: what cannot be right is a CaptureError, what may be wrong a warning.

Shared by the capture kinds. Errors (the fit would give a plausible wrong answer): a light subset that is
empty, out of range or repeats a light; one image file used for two lights; a constant image (all black,
all saturated: a light that did not fire, a lens cap); images whose channel count or size differs (read_images);
light intensities whose scale cannot be that of the images; no observation left, with the count each
filter removed. Warnings (the fit is still right, but the folder may not be what was meant): image files
on disk that no light lists; two lights whose images are identical although the files differ.
"""

from __future__ import annotations

import os
from collections import Counter
from pathlib import Path

import numpy as np

from torchrefl.errors import CaptureError

#: a light's median implied diffuse albedo (intensity / (kappa / pi * Y * falloff * n.l)) outside this range
#: means the light intensities (or the images' scale) cannot be right: Pd would come out absurd
IMPLIED_ALBEDO_RANGE = (1e-4, 1e3)
#: an image whose brightest object pixel is below this fraction of full range (2 DN of 8 bits) shows only noise
DARK_LEVEL = 2.0 / 255.0


def light_indices(subset, count: int, where: str) -> list[int]:
    """The lights to load: all (subset None) or capture.light_subset, checked against the `count` lights `where`
    lists."""
    if subset is None:
        return list(range(count))
    subset = list(subset)
    if not subset:
        raise CaptureError(f"capture.light_subset is empty: it selects none of the {count} lights in {where}")
    bad = [i for i in subset if isinstance(i, bool) or not isinstance(i, (int, np.integer)) or not 0 <= i < count]
    if bad:
        raise CaptureError(
            f"capture.light_subset: indices {bad} out of range for the {count} lights in {where} "
            f"(expected 0..{count - 1})"
        )
    repeated = sorted(i for i, n in Counter(subset).items() if n > 1)
    if repeated:
        raise CaptureError(f"capture.light_subset: indices {repeated} repeated (each light once) for {where}")
    return [int(i) for i in subset]


def distinct_image_files(paths: list[Path], names: list[str], where: str) -> None:
    """CaptureError when one image file serves two lights (same name, or two names of one file)."""
    seen: dict[tuple, int] = {}
    for i, path in enumerate(paths):
        try:
            st = os.stat(path)
            key = (st.st_dev, st.st_ino)
        except OSError:
            key = (str(Path(path).resolve()),)
        if key in seen:
            raise CaptureError(
                f"{where}: lights {seen[key]} and {i} use the same image file {path} "
                f"('{names[seen[key]]}', '{names[i]}'); each light needs its own photograph"
            )
        seen[key] = i


def image_content_checks(intensity: np.ndarray, paths: list[Path]) -> list[str]:
    """intensity (P, K, 3) fractions of full range at the object's pixels. CaptureError naming the files of
    constant images (no light, or all saturated) or when every image is black; returns warnings for black
    images among others and for identical images of different files."""
    lo, hi = intensity.min(axis=(1, 2)), intensity.max(axis=(1, 2))
    constant = np.flatnonzero(hi - lo <= 0)
    if constant.size:
        names = ", ".join(f"{paths[i]} (all {float(lo[i]):.4g})" for i in constant[:3])
        raise CaptureError(
            f"{len(constant)} of {len(paths)} images are constant on the object, e.g. {names}: a "
            "light that did not fire, a covered lens or a saturated exposure carries no reflectance; "
            "reshoot them or leave them out with capture.light_subset"
        )
    dark = np.flatnonzero(hi < DARK_LEVEL)
    if dark.size == len(paths):
        raise CaptureError(
            f"all {len(paths)} images are black on the object (brightest pixel below 2 DN of 8 bits, "
            f"e.g. {paths[0]}): no light reached the camera; check the exposure and the lights"
        )
    warnings = (
        [
            f"{len(dark)} image(s) are black on the object (brightest pixel below 2 DN of 8 bits), e.g. "
            f"{', '.join(str(paths[i]) for i in dark[:3])}: did their lights fire?"
        ]
        if dark.size
        else []
    )
    digests: dict[bytes, int] = {}
    for i in range(len(paths)):
        key = intensity[i].tobytes()
        if key in digests:
            warnings.append(f"{paths[i]} is identical to {paths[digests[key]]}: two lights with the same photograph?")
        else:
            digests[key] = i
    return warnings


def unlisted_images(folder: Path, listed: list[Path], pattern: str, where: str) -> list[str]:
    """A warning when `folder` holds image files matching `pattern` that no light lists."""
    if not folder.is_dir():
        return []
    listed_set = {Path(p).resolve() for p in listed}
    extra = sorted(p.name for p in folder.glob(pattern) if p.is_file() and p.resolve() not in listed_set)
    if not extra:
        return []
    return [
        f"{folder} holds {len(extra)} image file(s) that no light in {where} lists (e.g. {', '.join(extra[:3])}): "
        "a truncated light list?"
    ]


def implied_albedo_check(
    intensity: np.ndarray, valid: np.ndarray, cos_l: np.ndarray, scale: np.ndarray, kappa: np.ndarray, source: str
) -> None:
    """CaptureError naming the light-intensity source when a light's median implied diffuse albedo
    i / (kappa / pi * Y * falloff * n.l) is outside IMPLIED_ALBEDO_RANGE.

    intensity (P, T, 3); valid (P, T); cos_l (P, T); scale (P, T, 3) = Y * falloff per observation; kappa (3,)."""
    lo, hi = IMPLIED_ALBEDO_RANGE
    use = valid & (cos_l > 0.2)
    for p in range(intensity.shape[0]):
        if not use[p].any():
            continue
        denom = (kappa / np.pi)[None] * scale[p][use[p]] * cos_l[p][use[p]][:, None]
        albedo = float(np.median(intensity[p][use[p]].mean(-1) / denom.mean(-1)))
        if not lo <= albedo <= hi:
            raise CaptureError(
                f"{source}: light {p}'s intensity gives the object a diffuse albedo of {albedo:.3g} (median over its "
                f"lit texels), expected {lo:g}..{hi:g}: the intensities are not in the images' units (or the "
                "images are not linear fractions of full range)"
            )


def observations_left(valid: np.ndarray, removed: dict[str, np.ndarray], where: str) -> None:
    """CaptureError saying why when no observation is valid: how many of all observations each filter removed
    (removed: filter description -> (P, T) bool of the observations it removes; filters may overlap)."""
    if valid.any():
        return
    total = valid.size
    reasons = "; ".join(f"{name}: {int(mask.sum())}" for name, mask in removed.items())
    raise CaptureError(
        f"{where}: nothing to fit: none of the {total} observations is usable ({reasons}; "
        "an observation may fall under several)"
    )
