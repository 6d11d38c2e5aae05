"""The reflectance figure: Pd, Ps, sigma and coverage maps of one run, readable at a notebook's ~10 in width.

Two by two panels cropped to the texels the maps describe (axes in texel rows and columns, the coordinates the
summary's patches use). Pd is shown sRGB-encoded (an albedo in [0, 1]); Ps and sigma on robust colour ranges
(torchrefl.report.display: percentiles of the estimated texels, clipped to their physical limits; arrows on a
colour bar mark values beyond it); texels without an estimate show the hatched grey background in every panel;
the coverage codes are named in a legend of colour swatches below the panels, inside the figure.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.colors import BoundaryNorm, ListedColormap
from matplotlib.patches import Patch

from torchrefl.core.atomic_files import atomic_file
from torchrefl.report.display import BACKGROUND, HATCH, HATCH_COLOUR, robust_range, show_no_data, srgb
from torchrefl.report.maps import COVERAGE_COLOURS, COVERAGE_NAMES

#: The figure's width in inches: a notebook shows a figure about this wide without scaling it down.
WIDTH_IN = 10.0
#: Texels of margin around the described texels in each panel.
MARGIN = 2


def crop_box(described: np.ndarray, margin: int = MARGIN) -> tuple[slice, slice]:
    """Row and column slices around the True texels of an (H, W) mask, `margin` texels wider; the whole grid
    where none is True."""
    rows, cols = np.nonzero(described)
    if rows.size == 0:
        return slice(0, described.shape[0]), slice(0, described.shape[1])
    return (
        slice(max(int(rows.min()) - margin, 0), min(int(rows.max()) + margin + 1, described.shape[0])),
        slice(max(int(cols.min()) - margin, 0), min(int(cols.max()) + margin + 1, described.shape[1])),
    )


def described_texels(mask: np.ndarray, coverage: np.ndarray | None) -> np.ndarray:
    """(H, W) bool: the texels a panel shows, those with an estimate or a coverage code other than 0."""
    mask = np.asarray(mask, dtype=bool)
    return mask if coverage is None else mask | (np.asarray(coverage) != 0)


def figure_size(described: np.ndarray, panel_rows: int = 2) -> tuple[float, float]:
    """(width, height) in inches of the figure of 2 x panel_rows panels of the (H, W) `described` texels' crop box:
    WIDTH_IN wide, the panels' aspect kept, the height bounded so that a strip or a column of texels stays
    readable."""
    box = crop_box(described)
    rows, cols = box[0].stop - box[0].start, box[1].stop - box[1].start
    panel_w = 0.39 * WIDTH_IN
    panel_h = float(np.clip(panel_w * rows / max(cols, 1), 1.6, 6.0))
    return WIDTH_IN, panel_rows * panel_h + 2.6


def draw_reflectance(
    fig,
    pd: np.ndarray,
    ps: np.ndarray,
    sigma: np.ndarray,
    mask: np.ndarray,
    coverage: np.ndarray | None = None,
    sigma_max: float | None = None,
    title: str = "",
    relative: tuple[np.ndarray, np.ndarray] | None = None,
):
    """Draw the four panels (six with `relative`) into an empty matplotlib Figure `fig` (made with
    layout="constrained") and return it.

    pd (H, W, 3), ps (H, W) or (H, W, C), sigma (H, W), mask (H, W) bool: texels with an estimate; coverage (H, W)
    codes 0-7 (torchrefl.report.maps) or None; sigma_max: the fit's upper bound on sigma (rad), the top of its
    colour range where given; relative: (H, W) relative std of Ps and of sigma (torchrefl.report.uncertainty.
    relative_maps; NaN: not determined, shown as the background), drawn as a third row."""
    mask = np.asarray(mask, dtype=bool)
    ps = np.asarray(ps, dtype=np.float64)
    ps = ps.mean(axis=-1) if ps.ndim == 3 else ps
    box = crop_box(described_texels(mask, coverage))
    extent = (box[1].start - 0.5, box[1].stop - 0.5, box[0].stop - 0.5, box[0].start - 0.5)
    axes = fig.subplots(2 if relative is None else 3, 2, sharex=True, sharey=True)
    for ax in axes.flat:
        show_no_data(ax)
        ax.tick_params(labelsize=8)
    for ax in axes[-1]:
        ax.set_xlabel("texel column", fontsize=9)
    for ax in axes[:, 0]:
        ax.set_ylabel("texel row", fontsize=9)
    show = dict(extent=extent, aspect="equal")

    pd = np.broadcast_to(np.asarray(pd, dtype=np.float64).reshape(mask.shape + (-1,)), mask.shape + (3,))
    rgba = np.concatenate([srgb(pd[box]), mask[box][..., None].astype(np.float64)], axis=-1)
    axes[0, 0].imshow(rgba, **show)
    axes[0, 0].set_title("Pd, diffuse albedo (sRGB, 0-1)", fontsize=11)

    panels = [
        (axes[0, 1], ps, mask, "magma", (0.0, None), "Ps, specular albedo (mean of channels)"),
        (axes[1, 0], sigma, mask, "viridis", (0.0, sigma_max), "sigma, lobe width [rad]"),
    ]
    for ax, rel, name in zip(axes[2] if relative is not None else (), relative or (), ("Ps", "sigma")):
        shown = mask & np.isfinite(rel)  # not determined: the background
        label = f"{name} relative std, std / value (hatched: not determined)"
        panels.append((ax, rel, shown, "cividis", (0.0, None), label))
    for ax, values, shown, cmap, limits, label in panels:
        rng = robust_range(np.nan_to_num(values, posinf=0.0), shown, lower=limits[0], upper=limits[1])
        colours = _colormap(cmap)
        im = ax.imshow(np.ma.masked_array(values[box], ~shown[box]), cmap=colours, vmin=rng.vmin, vmax=rng.vmax, **show)
        bar = fig.colorbar(im, ax=ax, extend=rng.extend, shrink=0.9)
        bar.set_label(label, fontsize=9)
        bar.ax.tick_params(labelsize=8)
        bar.formatter.set_useOffset(False)
        if rng.flat:
            bar.set_ticks([rng.level], labels=[f"{rng.level:.4g}"])
        ax.set_title(label.split(",")[0] + f" ({_range_note(rng)})", fontsize=11)

    _draw_coverage(fig, axes[1, 1], coverage, mask, box, show)
    if title:
        fig.suptitle(title, fontsize=12)
    return fig


def _colormap(name: str):
    """The named colour map with an odd number of colours (a constant map, at the range's middle, falls in the
    middle of one colour, not on the edge of two) and transparent masked texels (the background shows)."""
    import matplotlib

    return matplotlib.colormaps[name].resampled(255).with_extremes(bad=(0.0, 0.0, 0.0, 0.0))


def _range_note(rng) -> str:
    """What the colour range is, for a panel's title."""
    if rng.flat:
        return f"constant {rng.level:.4g}"
    return "1st-99th percentile" if rng.below or rng.above else "full range"


def _draw_coverage(fig, ax, coverage, mask, box, show) -> None:
    """The coverage panel and the swatch legend below the panels; code 0 (no usable observation) and texels
    without an estimate share the background swatch."""
    no_estimate = Patch(
        facecolor=BACKGROUND,
        edgecolor="0.4",
        hatch=HATCH,
        hatchcolor=HATCH_COLOUR,
        label="no estimate / no usable observation",
    )
    if coverage is None:
        ax.set_title("coverage (not in params.npz)", fontsize=11)
        fig.legend(handles=[no_estimate], loc="outside lower center", fontsize=9, frameon=False)
        return
    codes = np.asarray(coverage)[box]
    colours = np.array([COVERAGE_COLOURS[k] for k in range(len(COVERAGE_COLOURS))], dtype=np.float64) / 255.0
    rgba = np.concatenate([colours, np.ones((len(colours), 1))], axis=1)
    rgba[0] = 0.0  # code 0 shows the background
    n = len(colours)
    ax.imshow(
        codes,
        cmap=ListedColormap(rgba),
        norm=BoundaryNorm(np.arange(n + 1) - 0.5, n),
        interpolation="nearest",
        **show,
    )
    ax.set_title("coverage: how each texel was determined", fontsize=11)
    full = np.asarray(coverage)
    handles = [no_estimate]
    for code in range(1, n):
        count = int((full == code).sum())
        if count:
            handles.append(Patch(facecolor=colours[code], edgecolor="0.4", label=f"{COVERAGE_NAMES[code]} ({count})"))
    fig.legend(
        handles=handles,
        loc="outside lower center",
        ncols=min(len(handles), 3),
        fontsize=9,
        frameon=False,
        title="coverage (texels)",
        title_fontsize=9,
    )


def write_figure(
    path: Path,
    pd: np.ndarray,
    ps: np.ndarray,
    sigma: np.ndarray,
    mask: np.ndarray,
    coverage: np.ndarray | None,
    sigma_max: float | None,
    title: str,
    relative: tuple[np.ndarray, np.ndarray] | None = None,
    dpi: int = 100,
) -> None:
    """Draw the reflectance figure (draw_reflectance's arguments) into a Figure of its own, not pyplot's (no global
    matplotlib state changes), and save it as a PNG at `path`."""
    from matplotlib.figure import Figure

    rows = 2 if relative is None else 3
    fig = Figure(figsize=figure_size(described_texels(mask, coverage), rows), layout="constrained")
    draw_reflectance(fig, pd, ps, sigma, mask, coverage, sigma_max, title, relative)
    with atomic_file(path) as fh:
        fig.savefig(fh, format="png", dpi=dpi)
