"""The export's maps: linear 16-bit PNGs and float OpenEXR files of the estimate, and the 8-bit textures of the mesh
exports (docs/exports.md).

16-bit PNGs on the texel grid (H, W), one pixel per texel, value = round(x * 65535) of the linear quantity x:
- pd.png RGBA: Pd (clipped to [0, 1]); alpha 65535 on the estimated texels, 0 elsewhere (as in every map below);
- ps.png RGBA: Ps (clipped to [0, 1]; the EXR keeps values above 1);
- sigma.png RGBA, grey: sigma / SIGMA_FULL_SCALE (pi / 2 rad = 65535);
- normals.png RGBA: (n + 1) / 2 of the unit world-frame normal, alpha on the texels with geometry;
- coverage.png grey: the coverage code itself (0-7, docs/outputs.md), not scaled.
EXR (float32, unclipped, linear): pd.exr and ps.exr (R, G, B, A), sigma.exr (Y: rad, A), normals.exr (R, G, B = x,
y, z; A).
Textures for the OBJ and the glTF files (texels without an estimate take their nearest estimated texel's value
so that filtering at the edge of the estimate and across atlas gaps shows no black seams):
- basecolor.png: Pd, 8-bit sRGB (glTF's baseColorTexture, the OBJ's map_Kd);
- roughness.png: glTF's metallicRoughnessTexture, 8-bit linear (G roughness, B metallic 0, R 255);
- specular.png: KHR_materials_specular's specularTexture, 8-bit linear, the strength / its maximum in A (and RGB);
- specular_color.png: its specularColorTexture, 8-bit sRGB.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from scipy.ndimage import distance_transform_edt

from torchrefl.capture.images import write_png
from torchrefl.core.exr import write_exr
from torchrefl.report.display import srgb
from torchrefl.report.export_material import GltfMaterial

SIGMA_FULL_SCALE = math.pi / 2  # rad shown as 65535 in sigma.png
MAPS = ("pd", "ps", "sigma", "normals", "coverage")


def _rgb(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    a = a[..., None] if a.ndim == 2 else a
    return np.repeat(a, 3, axis=-1) if a.shape[-1] == 1 else a


def _png16(path: Path, values: np.ndarray, alpha: np.ndarray) -> None:
    """values (H, W) or (H, W, 3) linear, clipped to [0, 1], as a 16-bit RGBA PNG (grey repeated in R, G, B) with
    alpha 1 where `alpha` and 0 (and the values 0) elsewhere."""
    v = _rgb(np.clip(np.nan_to_num(np.asarray(values, dtype=np.float64)), 0.0, 1.0))
    a = np.asarray(alpha, dtype=bool)[..., None]
    write_png(path, np.concatenate([np.where(a, v, 0.0), a.astype(np.float64)], -1), bits=16)


def write_value_maps(folder: Path, pd, ps, sigma, normals, mask, coverage) -> list[Path]:
    """The 16-bit PNG and OpenEXR maps of the estimate in `folder`; returns the files written."""
    folder.mkdir(parents=True, exist_ok=True)
    mask = np.asarray(mask, dtype=bool)
    normals = np.asarray(normals, dtype=np.float64)
    has_normal = np.linalg.norm(normals, axis=-1) > 0.5
    sigma = np.asarray(sigma, dtype=np.float64)
    written = []
    for name, values, alpha in (
        ("pd", _rgb(pd), mask),
        ("ps", _rgb(ps), mask),
        ("normals", (normals + 1.0) / 2.0, has_normal),
    ):
        _png16(folder / f"{name}.png", values, alpha)
        raw = values if name != "normals" else normals
        keep = alpha[..., None]
        channels = {c: np.where(keep, raw, 0.0)[..., i] for i, c in enumerate("RGB")}
        write_exr(folder / f"{name}.exr", {**channels, "A": alpha.astype(np.float32)})
        written += [folder / f"{name}.png", folder / f"{name}.exr"]
    _png16(folder / "sigma.png", sigma / SIGMA_FULL_SCALE, mask)
    write_exr(folder / "sigma.exr", {"Y": np.where(mask, sigma, 0.0), "A": mask.astype(np.float32)})
    cov = np.zeros(mask.shape, dtype=np.uint16) if coverage is None else np.asarray(coverage).astype(np.uint16)
    write_png(folder / "coverage.png", cov, bits=16)
    return written + [folder / "sigma.png", folder / "sigma.exr", folder / "coverage.png"]


def nearest_inside(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(rows, cols) (H, W): for every texel the nearest texel inside `mask` (itself inside it; Euclidean on the
    grid); the identity when the mask is full or empty."""
    mask = np.asarray(mask, dtype=bool)
    if mask.all() or not mask.any():
        return np.indices(mask.shape)
    _, (r, c) = distance_transform_edt(~mask, return_indices=True)
    return r, c


def to_8bit(x: np.ndarray) -> np.ndarray:
    return np.round(np.clip(np.asarray(x, dtype=np.float64), 0.0, 1.0) * 255.0).astype(np.uint8)


def specular_scale(material: GltfMaterial, mask: np.ndarray) -> float:
    """KHR_materials_specular's specularFactor: the largest strength over the estimated texels (specular.png's
    255)."""
    return max(float(material.specular[mask].max()) if np.any(mask) else 0.0, 0.0)


def write_textures(folder: Path, material: GltfMaterial, mask: np.ndarray) -> dict[str, Path]:
    """The 8-bit textures of the mesh exports (module docstring); returns name -> path. The specular strength
    is stored divided by its largest value, specular_scale (the glTF specularFactor)."""
    folder.mkdir(parents=True, exist_ok=True)
    rows, cols = nearest_inside(mask)
    fill = lambda a: np.asarray(a)[rows, cols]
    top = specular_scale(material, mask)
    strength = material.specular / top if top > 0 else np.zeros_like(material.specular)
    ones = np.ones(mask.shape)
    images = {
        "basecolor": to_8bit(srgb(fill(material.base_color))),
        "roughness": to_8bit(np.stack([ones, fill(material.roughness), 0 * ones], -1)),
        "specular": to_8bit(np.repeat(fill(strength)[..., None], 4, -1)),
        "specular_color": to_8bit(srgb(fill(material.specular_color))),
    }
    paths = {}
    for name, img in images.items():
        paths[name] = folder / f"{name}.png"
        write_png(paths[name], img, bits=8)
    return paths
