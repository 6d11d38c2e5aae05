"""The masked median filter of range images (step 1 of the seed dissertation's section 2.3,
``median_filter_range``), with the range-image checks and the padding / window unfolding that
torchrefl.geometry.range_image's quadratic fit shares with it.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from torchrefl.errors import GeometryError


def _check_range(r, valid, name_r: str = "r", name_valid: str = "valid") -> None:
    if not isinstance(r, torch.Tensor):
        raise GeometryError(f"argument '{name_r}': expected a torch.Tensor (H, W), got {type(r).__name__}")
    if r.dtype not in (torch.float32, torch.float64):
        raise GeometryError(f"argument '{name_r}': expected dtype float32 or float64, got {r.dtype}")
    if r.ndim != 2:
        raise GeometryError(f"argument '{name_r}': expected shape (H, W), got {tuple(r.shape)}")
    if not isinstance(valid, torch.Tensor):
        raise GeometryError(f"argument '{name_valid}': expected a torch.Tensor (H, W) bool, got {type(valid).__name__}")
    if valid.dtype != torch.bool:
        raise GeometryError(f"argument '{name_valid}': expected dtype torch.bool, got {valid.dtype}")
    if tuple(valid.shape) != tuple(r.shape):
        raise GeometryError(
            f"argument '{name_valid}': shape {tuple(valid.shape)} does not match '{name_r}' {tuple(r.shape)}"
        )
    if valid.device != r.device:
        raise GeometryError(f"argument '{name_valid}': on {valid.device}, '{name_r}' on {r.device}")
    if not bool(valid.any()):
        raise GeometryError(f"argument '{name_valid}': the mask selects no pixel (expected at least one valid pixel)")
    bad = valid & ~torch.isfinite(r)
    if bool(bad.any()):
        k = int(bad.sum())
        raise GeometryError(
            f"argument '{name_r}': {k} pixels inside the valid mask are NaN or inf "
            f"(expected finite ranges where '{name_valid}' is True)"
        )


def _check_odd(value, name: str, minimum: int = 1) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum or value % 2 != 1:
        raise GeometryError(f"argument '{name}': expected an odd integer >= {minimum}, got {value!r}")
    return value


def _pad(x: torch.Tensor, h: int, wrap: bool, fill: float) -> torch.Tensor:
    """(H, W) -> (H + 2h, W + 2h): rows padded with `fill`, columns circular (wrap) or `fill`."""
    if wrap:
        x = torch.cat([x[:, -h:], x, x[:, :h]], dim=1) if h else x
        return F.pad(x, (0, 0, h, h), value=fill)
    return F.pad(x, (h, h, h, h), value=fill)


def _windows(x: torch.Tensor, k: int) -> torch.Tensor:
    """(H + k - 1, W + k - 1) padded -> (k*k, H, W): the k x k window centred on each pixel, row-major."""
    Hp, Wp = x.shape
    cols = F.unfold(x[None, None], kernel_size=k)  # (1, k*k, H*W)
    return cols[0].reshape(k * k, Hp - k + 1, Wp - k + 1)


def median_filter_range(
    r: torch.Tensor, valid: torch.Tensor, size: int = 5, *, wrap: bool = False, symmetric: bool = True
) -> torch.Tensor:
    """Median over the valid pixels of each size x size window (step 1 of section 2.3).

    r: (H, W) float32/float64 range, mm; valid: (H, W) bool. Invalid neighbours (and pixels
    outside the image; columns wrap around when wrap=True) are ignored; invalid pixels are
    returned unchanged. For an even number of valid neighbours the lower of the two middle
    values is taken (torch.nanmedian).

    symmetric=True (default): a neighbour at offset o counts only when its mirror at -o is
    valid too. Inside the valid region this is the plain 5 x 5 median of the seed; at the
    image border and at silhouettes the window is a centrally symmetric subset, whose median
    is the pixel's own value on any locally linear (monotone) surface. The plain masked median
    (symmetric=False) shifts such edge pixels towards the interior values by about one step
    of the slope, which tilts the normals of the whole outer ring (measured: 18 deg on the
    top row of a sphere's range image). Spikes are removed either way wherever the pixel has
    mirrored valid neighbours.

    Why not kornia.filters.median_blur: it has no mask; it pads the border (reflect/constant),
    and a NaN anywhere in a window makes the output NaN, so invalid pixels cannot be excluded
    by marking them NaN. Here the windows are unfolded (torch.nn.functional.unfold) with the
    invalid pixels set to NaN and reduced with torch.nanmedian.

    Returns (H, W) tensor of r's dtype.
    """
    _check_range(r, valid)
    k = _check_odd(size, "size")
    if k == 1:
        return r.clone()
    h = k // 2
    x = torch.where(valid, r, torch.full_like(r, float("nan")))
    win = _windows(_pad(x, h, wrap, float("nan")), k)  # (k*k, H, W)
    if symmetric:  # window index j and k*k-1-j are mirror offsets
        win = torch.where(torch.isnan(win.flip(0)), float("nan"), win)
    med = torch.nanmedian(win.permute(1, 2, 0).contiguous(), dim=-1).values
    return torch.where(valid, med, r)
