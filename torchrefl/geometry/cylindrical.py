"""Points and outward normals of a cylindrical range image (seed dissertation, section 2.3, eq. 2.1-2.4).

A range r (H, W) at column angles s (W,) (radians) and row heights t (H,) (mm) gives the points
S(s, t) = (-r sin s, -t, -r cos s) (eq. 2.1, ``cylindrical_points``) and, with the range's gradients r_s, r_t,
the unit outward normals S_t x S_s / |S_t x S_s| (``cylindrical_normals``; eq. 2.4 as printed is garbled: see
torchrefl.geometry.range_image's docstring). Used by range_image.preprocess_range_image.
"""

from __future__ import annotations

import torch

from torchrefl.errors import GeometryError


def _check_range_map(r) -> None:
    if not isinstance(r, torch.Tensor) or r.ndim != 2 or r.dtype not in (torch.float32, torch.float64):
        raise GeometryError(
            f"argument 'r': expected a float32/float64 torch.Tensor (H, W), got "
            f"{getattr(r, 'dtype', type(r).__name__)} {tuple(getattr(r, 'shape', ()))}"
        )


def _check_axis(x, n: int, name: str, like: torch.Tensor) -> torch.Tensor:
    if not isinstance(x, torch.Tensor):
        raise GeometryError(f"argument '{name}': expected a torch.Tensor ({n},), got {type(x).__name__}")
    if not torch.is_floating_point(x):
        raise GeometryError(f"argument '{name}': expected a floating dtype, got {x.dtype}")
    if tuple(x.shape) != (n,):
        raise GeometryError(f"argument '{name}': expected shape ({n},), got {tuple(x.shape)}")
    return x.to(dtype=like.dtype, device=like.device)


def _check_like(x, ref: torch.Tensor, name: str) -> None:
    if not isinstance(x, torch.Tensor):
        raise GeometryError(f"argument '{name}': expected a torch.Tensor {tuple(ref.shape)}, got {type(x).__name__}")
    if tuple(x.shape) != tuple(ref.shape):
        raise GeometryError(f"argument '{name}': shape {tuple(x.shape)} does not match 'r' {tuple(ref.shape)}")
    if x.dtype != ref.dtype:
        raise GeometryError(f"argument '{name}': dtype {x.dtype} does not match 'r' {ref.dtype}")


def cylindrical_points(r: torch.Tensor, s: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    """Eq. 2.1: S(s, t) = (-r sin s, -t, -r cos s).

    r: (H, W) float range, mm; s: (W,) column angles, radians; t: (H,) row heights, mm.
    Returns (H, W, 3) of r's dtype, mm (NaN where r is NaN).
    """
    _check_range_map(r)
    H, W = r.shape
    s = _check_axis(s, W, "s", r)
    t = _check_axis(t, H, "t", r)
    sin, cos = torch.sin(s)[None, :], torch.cos(s)[None, :]
    return torch.stack([-r * sin, (-t)[:, None].expand(H, W), -r * cos], dim=-1)


def cylindrical_normals(
    r: torch.Tensor, r_s: torch.Tensor, r_t: torch.Tensor, s: torch.Tensor, t: torch.Tensor
) -> torch.Tensor:
    """Unit outward normals N = S_t x S_s / |S_t x S_s| (eq. 2.3; eq. 2.4 as printed is garbled,
    see the module docstring):

        N = (r_s cos s - r sin s, r r_t, -r_s sin s - r cos s) / sqrt(r_s^2 + r^2 + r^2 r_t^2).

    r: (H, W) float range, mm; r_s: (H, W) dr/ds, mm/rad; r_t: (H, W) dr/dt, mm/mm;
    s: (W,) radians; t: (H,) mm (the normal does not depend on t; checked for shape only).
    Returns (H, W, 3) of r's dtype, unit, pointing away from the rotation axis;
    NaN where an input is NaN or the normal is undefined (r = r_s = 0).
    """
    _check_range_map(r)
    _check_like(r_s, r, "r_s")
    _check_like(r_t, r, "r_t")
    H, W = r.shape
    s = _check_axis(s, W, "s", r)
    _check_axis(t, H, "t", r)
    sin, cos = torch.sin(s)[None, :], torch.cos(s)[None, :]
    n = torch.stack([r_s * cos - r * sin, r * r_t, -r_s * sin - r * cos], dim=-1)
    length = n.norm(dim=-1, keepdim=True)
    return torch.where(length > 0, n / length.clamp_min(torch.finfo(r.dtype).tiny), float("nan"))
