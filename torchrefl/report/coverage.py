"""Where Ps and sigma come from: metrics.json's `specular_source` block (docs/outputs.md).

A texel's Ps and sigma are measured (its own T_spec observations gave them: coverage code 2), taken from measured
texels of its colour or its measured neighbours (codes 1 and 3: no usable highlight; "interpolated") or the object's
lobe (code 5: fit.specular shared, or the measured texels' median lobe where none is measured within two
interpolation windows) or their material's lobe fitted to its interreflected light (code 7, "material": no measured
texel of their colour; torchrefl.fit.material_lobe). The shares are over the estimated texels, for the object and
per material region where the capture's truth has a region map (synthetic captures); for every capture the largest
connected patches of texels whose Ps and sigma are not measured (interpolated, the object's or the material's lobe)
are listed with their size and bounding box, which says where a real capture lacks highlights.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import find_objects, label

from torchrefl.fit.initialise import COVER_FULL, COVER_MATERIAL, COVER_PD_BOUND, COVER_PD_ONLY, COVER_SHARED

#: The largest patches of interpolated texels listed.
PATCHES = 10
SOURCES = {
    "measured": (COVER_FULL,),
    "interpolated": (COVER_PD_ONLY, COVER_PD_BOUND),
    "shared": (COVER_SHARED,),
    "material": (COVER_MATERIAL,),
}


def source_counts(coverage: np.ndarray, estimated: np.ndarray) -> dict:
    """Counts and shares of the estimated texels whose Ps and sigma are measured, interpolated or shared.
    coverage, estimated: arrays of one shape (codes, bool); shares are None over no texel."""
    est = np.asarray(estimated, dtype=bool)
    n = int(est.sum())
    out: dict = {"estimated": n}
    for name, codes in SOURCES.items():
        k = int((est & np.isin(coverage, codes)).sum())
        out[name] = k
        out[f"{name}_share"] = k / n if n else None
    return out


def unmeasured_patches(coverage: np.ndarray, estimated: np.ndarray, largest: int = PATCHES) -> list[dict]:
    """The `largest` 8-connected patches of estimated texels whose Ps and sigma are not measured (interpolated or the
    object's lobe) on the (H, W) grid, largest first: {texels, rows: [first, last], columns: [first, last]}
    (inclusive, texel coordinates)."""
    unmeasured = np.asarray(estimated, dtype=bool) & np.isin(
        coverage, SOURCES["interpolated"] + SOURCES["shared"] + SOURCES["material"]
    )
    labels, n = label(unmeasured, structure=np.ones((3, 3), dtype=bool))
    if not n:
        return []
    sizes = np.bincount(labels.ravel(), minlength=n + 1)[1:]
    boxes = find_objects(labels)
    order = sorted(range(n), key=lambda i: (-sizes[i], boxes[i][0].start, boxes[i][1].start))[:largest]
    return [
        {
            "texels": int(sizes[i]),
            "rows": [boxes[i][0].start, boxes[i][0].stop - 1],
            "columns": [boxes[i][1].start, boxes[i][1].stop - 1],
        }
        for i in order
    ]


def specular_sources(coverage: np.ndarray, estimated: np.ndarray, region: np.ndarray | None = None) -> dict:
    """metrics.json's specular_source block from the (H, W) coverage codes, the (H, W) estimated mask and, when the
    truth has one, the (H, W) integer region map (-1: no region): the object's counts and shares, `regions`
    (per region id) and `unmeasured_patches`."""
    coverage, estimated = np.asarray(coverage), np.asarray(estimated, dtype=bool)
    if coverage.shape != estimated.shape or (region is not None and np.shape(region) != coverage.shape):
        raise ValueError(
            f"specular_sources: coverage {coverage.shape}, estimated {estimated.shape} and region "
            f"{None if region is None else np.shape(region)} must be one (H, W) grid"
        )
    out = source_counts(coverage, estimated)
    if region is not None:
        ids = np.unique(np.asarray(region)[estimated])
        out["regions"] = {str(int(i)): source_counts(coverage, estimated & (region == i)) for i in ids if i >= 0}
    out["unmeasured_patches"] = unmeasured_patches(coverage, estimated)
    return out
