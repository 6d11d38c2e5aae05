"""Ground-truth reflectance maps for synthetic scenes.

Maps are texel-aligned (H, W): regions with sharp borders on texel edges (so every
texel has one true value) carrying smooth variation inside. Deterministic in `seed`.
"""

from __future__ import annotations

import numpy as np

# (Pd RGB, Ps RGB, sigma) of the region materials: matte paint, glossy plastic, satin, glossy paint
_PALETTE = [
    ((0.62, 0.60, 0.55), (0.08, 0.08, 0.08), 0.22),
    ((0.55, 0.18, 0.14), (0.30, 0.30, 0.30), 0.09),
    ((0.16, 0.32, 0.58), (0.18, 0.20, 0.22), 0.14),
    ((0.30, 0.52, 0.22), (0.38, 0.36, 0.34), 0.11),
    ((0.70, 0.62, 0.25), (0.12, 0.11, 0.10), 0.18),
]


def region_materials(rows: int, columns: int, seed: int = 0, uniform: bool = False) -> dict:
    """Return {'pd': (H, W, 3), 'ps': (H, W, 3), 'sigma': (H, W)} float64 ground truth.

    Layout: four angular sectors (column ranges with random borders) of different
    materials, a horizontal band (row range) of a fifth material across them, and a
    smooth multiplicative variation of +-15 % in Pd, +-20 % in Ps and +-15 % in sigma.
    uniform=True gives one material everywhere (no variation).
    """
    rng = np.random.default_rng(seed)
    H, W = rows, columns
    region = np.zeros((H, W), dtype=np.int64)
    if not uniform:
        cuts = np.sort(rng.choice(np.arange(W // 8, W - W // 8), size=3, replace=False))
        for i, c in enumerate(cuts):
            region[:, c:] = i + 1
        region[:, : cuts[0]] = 0
        band_top = int(rng.integers(int(0.30 * H), int(0.40 * H)))
        band_h = int(rng.integers(int(0.10 * H), int(0.15 * H)))
        band_cols = slice(int(rng.integers(0, W // 4)), int(rng.integers(W // 2, W)))
        region[band_top:band_top + band_h, band_cols] = 4
    order = rng.permutation(len(_PALETTE)) if not uniform else np.arange(len(_PALETTE))
    pd_tab = np.array([_PALETTE[i][0] for i in order])
    ps_tab = np.array([_PALETTE[i][1] for i in order])
    sg_tab = np.array([_PALETTE[i][2] for i in order])
    pd = pd_tab[region]
    ps = ps_tab[region]
    sigma = sg_tab[region]
    if not uniform:
        yy, xx = np.meshgrid(np.linspace(0, 1, H), np.linspace(0, 1, W), indexing="ij")
        phase = rng.uniform(0, 2 * np.pi, size=3)
        pd = pd * (1 + 0.15 * np.sin(2 * np.pi * 2 * xx + phase[0]) * np.cos(np.pi * yy))[..., None]
        ps = ps * (1 + 0.20 * np.sin(2 * np.pi * 3 * xx + phase[1]) * np.sin(np.pi * 1.5 * yy + phase[2]))[..., None]
        sigma = sigma * (1 + 0.15 * np.cos(2 * np.pi * xx + phase[2]) * np.cos(np.pi * 2 * yy))
    return {"pd": pd.astype(np.float64), "ps": ps.astype(np.float64), "sigma": sigma.astype(np.float64), "region": region}
