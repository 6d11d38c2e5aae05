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
        region[band_top : band_top + band_h, band_cols] = 4
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
    return {
        "pd": pd.astype(np.float64),
        "ps": ps.astype(np.float64),
        "sigma": sigma.astype(np.float64),
        "region": region,
    }


# ---------------------------------------------------------------------------- materials as functions of position
# Mesh objects need the material at arbitrary points (path vertices), not only at texel centres:
# these functions take per-point coordinates and return per-point parameters; truth.npz holds
# them evaluated at the texel centres' scanner hits.

PAPER_WHITE = ((0.8, 0.8, 0.8), (0.0, 0.0, 0.0), 0.1)  # Object E setup 1: white diffuse paper
PAPER_GLOSSY = ((0.55, 0.55, 0.55), (0.35, 0.35, 0.35), 0.08)  # Object E setup 2: glossy paper


def uniform_material(count: int, material=PAPER_WHITE, region=None) -> dict:
    """{'pd': (N, 3), 'ps': (N, 3), 'sigma': (N,), 'region': (N,) int} of one material at `count` points."""
    pd, ps, sigma = material
    return {
        "pd": np.tile(np.asarray(pd, dtype=np.float64), (count, 1)),
        "ps": np.tile(np.asarray(ps, dtype=np.float64), (count, 1)),
        "sigma": np.full(count, float(sigma)),
        "region": np.zeros(count, dtype=np.int64) if region is None else np.asarray(region, dtype=np.int64),
    }


class BowlMaterials:
    """Non-uniform inside of a bowl as a function of the bowl's spherical coordinates.

    Inside (part 0): four azimuthal sectors (random borders) of palette materials, a band of a fifth
    material over a range of polar angle and azimuth, and smooth multiplicative variation (+-15 % Pd,
    +-20 % Ps, +-15 % sigma) in (azimuth, polar angle). Outside and rim (parts 1, 2): the matte paint,
    uniform. Deterministic in `seed`; uniform=True gives the matte paint everywhere.
    """

    def __init__(self, seed: int = 0, uniform: bool = False):
        rng = np.random.default_rng([seed, 0xB0])
        self.uniform = uniform
        self.cuts = np.sort(rng.uniform(0.0, 2 * np.pi, size=4))
        self.band = np.sort(rng.uniform(0.45, 1.15, size=2))  # polar angle range (rad)
        if self.band[1] - self.band[0] < 0.25:
            self.band[1] = self.band[0] + 0.25
        start = rng.uniform(0.0, 2 * np.pi)
        self.band_phi = (start, start + rng.uniform(np.pi / 2, 1.5 * np.pi))
        self.order = rng.permutation(len(_PALETTE))
        self.phase = rng.uniform(0, 2 * np.pi, size=3)

    def __call__(self, alpha: np.ndarray, phi: np.ndarray, part: np.ndarray) -> dict:
        """alpha: (N,) polar angle from the bowl's bottom (0) to the rim (pi/2); phi: (N,) azimuth;
        part: (N,) 0 inside, 1 outside, 2 rim. Returns pd, ps (N, 3), sigma, region (N,)."""
        N = len(alpha)
        phi = np.mod(phi, 2 * np.pi)
        if self.uniform:
            region = np.zeros(N, dtype=np.int64)
        else:
            sector = np.searchsorted(self.cuts, phi) % 4  # wraps: the last and first sector join
            rel = np.mod(phi - self.band_phi[0], 2 * np.pi)
            in_band = (alpha >= self.band[0]) & (alpha < self.band[1]) & (rel < self.band_phi[1] - self.band_phi[0])
            region = np.where(in_band, 4, sector)
            region = np.where(part == 0, region, 5)
        tab = [_PALETTE[i] for i in self.order] + [_PALETTE[0]]
        if self.uniform:
            tab = [_PALETTE[0]]
        pd = np.array([t[0] for t in tab])[region]
        ps = np.array([t[1] for t in tab])[region]
        sigma = np.array([t[2] for t in tab])[region]
        if not self.uniform:
            inside = (part == 0).astype(np.float64)
            ph = self.phase
            pd = pd * (1 + inside * 0.15 * np.sin(2 * phi + ph[0]) * np.cos(2 * alpha))[:, None]
            ps = ps * (1 + inside * 0.20 * np.sin(3 * phi + ph[1]) * np.sin(3 * alpha + ph[2]))[:, None]
            sigma = sigma * (1 + inside * 0.15 * np.cos(phi + ph[2]) * np.cos(4 * alpha))
        return {
            "pd": pd.astype(np.float64),
            "ps": ps.astype(np.float64),
            "sigma": sigma.astype(np.float64),
            "region": region.astype(np.int64),
        }


# (Pd RGB, Ps grey, sigma) of the glossy papers on the non-uniform fold: Ps 0.27-0.44, sigma 0.10-0.30
_GLOSSY_PAPERS = [
    ((0.55, 0.55, 0.55), 0.35, 0.10),
    ((0.62, 0.30, 0.22), 0.30, 0.18),
    ((0.25, 0.40, 0.60), 0.42, 0.12),
    ((0.45, 0.58, 0.30), 0.27, 0.30),
    ((0.72, 0.66, 0.40), 0.44, 0.22),
]


class FoldMaterials:
    """Non-uniform glossy papers on the two plates of a fold, as a function of plate coordinates.

    Each plate is cut across the fold into two papers at a random position (sharp borders), a band of a
    fifth paper runs parallel to the fold over part of the upper plate, and every paper varies smoothly
    (+-15 % Pd, Ps and sigma) along and across the fold. The plates' edges (rims, back faces) carry the
    paper of the nearest inside face. Deterministic in `seed`; regions 0-4 index _GLOSSY_PAPERS.
    """

    def __init__(self, seed: int = 0):
        rng = np.random.default_rng([seed, 0xF0])
        self.cuts = rng.uniform(0.35, 0.65, size=2)  # along the fold, fraction of the length (upper, lower)
        self.band = np.sort(rng.uniform(0.3, 0.7, size=2))  # across the upper plate, fraction of its width
        if self.band[1] - self.band[0] < 0.15:
            self.band[1] = self.band[0] + 0.15
        self.band_x = (rng.uniform(0.0, 0.3), rng.uniform(0.6, 1.0))  # along the fold
        self.phase = rng.uniform(0, 2 * np.pi, size=3)

    def __call__(self, along: np.ndarray, across: np.ndarray, plate: np.ndarray) -> dict:
        """along: (N,) position along the fold / length, in [0, 1]; across: (N,) distance from the fold / width;
        plate: (N,) 0 upper, 1 lower. Returns pd, ps (N, 3), sigma, region (N,)."""
        x, a, plate = np.clip(along, 0, 1), np.clip(across, 0, 1), np.asarray(plate)
        region = np.where(plate == 0, np.where(x < self.cuts[0], 0, 1), np.where(x < self.cuts[1], 2, 3))
        band = (plate == 0) & (a >= self.band[0]) & (a < self.band[1]) & (x >= self.band_x[0]) & (x < self.band_x[1])
        region = np.where(band, 4, region)
        ph = self.phase
        return _varied_papers(
            region,
            1 + 0.15 * np.sin(2 * np.pi * 1.5 * x + ph[0]) * np.cos(np.pi * a),
            1 + 0.15 * np.sin(2 * np.pi * x + ph[1]) * np.cos(np.pi * 1.2 * a + ph[2]),
            1 + 0.15 * np.cos(2 * np.pi * x + ph[2]) * np.sin(np.pi * a + ph[0]),
        )


def _varied_papers(region: np.ndarray, pd_factor, ps_factor, sigma_factor) -> dict:
    """The material dict of _GLOSSY_PAPERS[region] (N,) with Pd, Ps and sigma scaled by the factors (N,)."""
    pd = np.array([p[0] for p in _GLOSSY_PAPERS])[region] * pd_factor[:, None]
    ps = np.array([p[1] for p in _GLOSSY_PAPERS])[region] * ps_factor
    sigma = np.array([p[2] for p in _GLOSSY_PAPERS])[region] * sigma_factor
    return {
        "pd": pd.astype(np.float64),
        "ps": np.repeat(ps[:, None], 3, axis=1).astype(np.float64),
        "sigma": sigma.astype(np.float64),
        "region": region.astype(np.int64),
    }


class AtlasMaterials:
    """Non-uniform glossy papers (_GLOSSY_PAPERS) as a function of atlas coordinates (u, v) in [0, 1]^2.

    Four column sectors (borders at random multiples of 1/16 in u), a band of a fifth paper over rows
    v_band (multiples of 1/16 within `v_range`) and part of the columns, and a smooth variation (+-15 % Pd,
    Ps and sigma) periodic in u (a closed chart's seam, u = 0 and u = 1, joins smoothly). Region borders on the
    1/16 grid lie on texel edges of any atlas of 16 x 2^k texels, so every texel has one true value.
    Deterministic in `seed`; regions 0-4 index _GLOSSY_PAPERS.
    """

    def __init__(self, seed: int = 0, v_range: tuple = (0.0, 1.0)):
        rng = np.random.default_rng([seed, 0xA7])
        self.cuts = np.sort(rng.choice(np.arange(1, 16), size=3, replace=False)) / 16.0
        lo, hi = int(np.ceil(v_range[0] * 16)), int(np.floor(v_range[1] * 16))
        start = int(rng.integers(lo + 1, max(lo + 2, hi - 3)))
        self.band = (start / 16.0, min(start + 2, hi - 1) / 16.0)
        first = int(rng.integers(0, 6))
        self.band_u = (first / 16.0, (first + int(rng.integers(6, 10))) / 16.0)
        self.phase = rng.uniform(0, 2 * np.pi, size=3)

    def __call__(self, u: np.ndarray, v: np.ndarray) -> dict:
        """u, v: (N,) atlas coordinates. Returns pd, ps (N, 3), sigma, region (N,)."""
        u, v = np.mod(np.asarray(u, dtype=np.float64), 1.0), np.asarray(v, dtype=np.float64)
        region = np.searchsorted(self.cuts, u, side="right")
        band = (v >= self.band[0]) & (v < self.band[1]) & (u >= self.band_u[0]) & (u < self.band_u[1])
        region = np.where(band, 4, region)
        ph, a, b = self.phase, 2 * np.pi * u, np.pi * v
        return _varied_papers(
            region,
            1 + 0.15 * np.sin(2 * a + ph[0]) * np.cos(b),
            1 + 0.15 * np.sin(a + ph[1]) * np.cos(1.5 * b + ph[2]),
            1 + 0.15 * np.cos(a + ph[2]) * np.sin(2 * b + ph[0]),
        )
