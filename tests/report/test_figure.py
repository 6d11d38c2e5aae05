import io

import numpy as np
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from torchrefl.report.display import BACKGROUND
from torchrefl.report.figure import described_texels, draw_reflectance, figure_size
from torchrefl.report.maps import COVERAGE_NAMES

H, W = 40, 60


def maps(seed=0):
    """Maps with an 8 x 10 block of texels without an estimate (all 0, coverage 0) inside the object."""
    rng = np.random.default_rng(seed)
    mask = np.ones((H, W), dtype=bool)
    mask[16:24, 25:35] = False
    pd = rng.uniform(0.2, 0.8, (H, W, 3))
    ps = rng.uniform(0.1, 0.3, (H, W, 3))
    sigma = rng.uniform(0.1, 0.3, (H, W))
    coverage = np.where(mask, 2, 0)
    coverage[:5] = np.where(mask[:5], 1, 0)
    for a in (pd, ps, sigma):
        a[~mask] = 0.0
    return dict(pd=pd, ps=ps, sigma=sigma, mask=mask, coverage=coverage)


def drawn(m, sigma_max=0.6):
    fig = Figure(figsize=figure_size(described_texels(m["mask"], m["coverage"])), layout="constrained")
    FigureCanvasAgg(fig)
    return draw_reflectance(fig, **m, sigma_max=sigma_max, title="a run")


def panel(fig, word):
    (ax,) = [a for a in fig.axes if a.get_title().startswith(word)]
    return ax


def test_outliers_do_not_set_the_ps_scale():
    m = maps()
    m["ps"][3, 4] = m["ps"][30, 50] = 30.0  # two texels at 100x
    fig = drawn(m)
    im = panel(fig, "Ps").images[0]
    assert im.norm.vmax < 0.31 and im.norm.vmin >= 0.0
    shown = np.ma.getdata(im.norm(m["ps"].mean(-1)[m["mask"]]))
    at_ends = (shown <= 0.0) | (shown >= 1.0)
    assert at_ends.mean() < 0.05
    assert 0.3 < np.median(shown) < 0.7


def test_a_constant_map_is_one_colour():
    m = maps()
    m["sigma"] = np.where(m["mask"], 0.25 + np.random.default_rng(2).normal(0, 1e-9, (H, W)), 0.0)
    m["ps"] = np.where(m["mask"][..., None], 0.3, 0.0)
    fig = drawn(m)
    for word in ("Ps", "sigma"):
        im = panel(fig, word).images[0]
        rgba = im.to_rgba(im.get_array())[m["mask"]]
        assert len(np.unique(np.round(rgba, 6), axis=0)) == 1, word
    assert panel(fig, "sigma").get_title() == "sigma (constant 0.25)"


def test_the_coverage_legend_is_inside_a_plainly_saved_figure():
    fig = drawn(maps())
    fig.savefig(io.BytesIO(), format="png")
    (legend,) = fig.legends
    box, frame = legend.get_window_extent(fig.canvas.get_renderer()), fig.bbox
    assert frame.x0 <= box.x0 and box.x1 <= frame.x1 and frame.y0 <= box.y0 and box.y1 <= frame.y1
    texts = [t.get_text() for t in legend.get_texts()]
    assert any(t.startswith(COVERAGE_NAMES[1]) and "(300)" in t for t in texts)  # code 1: the first 5 rows of 60
    assert len(legend.legend_handles) == 3  # the background, codes 1 and 2: one swatch each
    assert min(t.get_fontsize() for t in legend.get_texts()) >= 8


@pytest.mark.parametrize("word", ["Pd", "Ps", "sigma", "coverage"])
def test_texels_without_an_estimate_show_the_background(word):
    fig = drawn(maps())
    fig.canvas.draw()
    pixels = np.asarray(fig.canvas.buffer_rgba())[..., :3] / 255.0
    ax = panel(fig, word)

    def around(row, col, half=4):
        x, y = ax.transData.transform((col, row))
        r, c = int(round(fig.bbox.height - y)), int(round(x))
        return pixels[r - half : r + half + 1, c - half : c + half + 1].reshape(-1, 3)

    inside = around(19.5, 29.5)  # the centre of the 8 x 10 block without an estimate
    is_background = np.abs(inside - BACKGROUND).max(axis=1) < 2 / 255
    is_hatch = np.abs(inside - inside.mean(axis=1, keepdims=True)).max(axis=1) < 2 / 255  # grey hatch lines
    assert is_background.mean() > 0.5 and (is_background | is_hatch).all()
    assert (np.abs(around(30, 10) - BACKGROUND).max(axis=1) > 0.05).all()  # an estimated texel is not


def test_write_figure_saves_a_notebook_wide_png_without_touching_pyplot(tmp_path):
    import matplotlib.pyplot as plt
    from PIL import Image

    from torchrefl.report.figure import write_figure

    open_before = plt.get_fignums()
    write_figure(tmp_path / "figure.png", **maps(), sigma_max=0.6, title="a run")
    with Image.open(tmp_path / "figure.png") as im:
        assert im.size[0] == 1000  # 10 in at 100 dpi
    assert plt.get_fignums() == open_before
    assert [p.name for p in tmp_path.iterdir()] == ["figure.png"]  # no temporary file left


def test_the_panels_are_cropped_to_the_described_texels():
    m = maps()
    m["mask"][:] = False
    m["mask"][10:20, 30:40] = True
    m["coverage"] = np.where(m["mask"], 2, 0)
    m["coverage"][25, 45] = 4  # an untrusted texel is described too
    fig = drawn(m)
    ax = panel(fig, "coverage")
    assert ax.get_xlim() == (30 - 2 - 0.5, 45 + 2 + 0.5) and ax.get_ylim() == (25 + 2 + 0.5, 10 - 2 - 0.5)
