"""Light selection: measurability conditions and the greedy max-D / max-S rule on known masks."""

import math

import numpy as np
import pytest

from torchrefl.errors import ConfigError
from torchrefl.planning.light_selection import (
    Measurability,
    coverage_figure,
    greedy_select,
    measurability,
    plot_coverage,
)


def test_measurability_thresholds():
    th = np.radians([[70.0, 60.0, 25.0, 20.0, 10.0, 10.0]])
    meas = np.array([[True, True, True, True, True, False]])
    d, s = measurability(th, meas, 60.0, 20.0)
    assert d.tolist() == [[True, False, False, False, False, False]]
    assert s.tolist() == [[False, False, False, True, True, False]]


def toy():
    # 6 texels, 5 candidates
    D = np.array(
        [
            [1, 1, 1, 0, 0, 0],
            [0, 0, 0, 1, 1, 0],
            [1, 1, 1, 1, 1, 1],  # the best diffuse light covers everything
            [0, 0, 0, 0, 0, 0],
            [0, 0, 0, 0, 0, 0],
        ],
        dtype=bool,
    )
    S = np.array(
        [
            [0, 0, 0, 0, 0, 0],
            [1, 1, 0, 0, 0, 0],
            [0, 0, 0, 0, 0, 0],
            [1, 1, 1, 1, 0, 0],
            [1, 1, 1, 1, 1, 0],
        ],
        dtype=bool,
    )
    return Measurability(D, S, np.ones(6, dtype=bool))


def test_greedy_picks_max_gain_and_stops_at_full_coverage():
    m = toy()
    r = greedy_select(m, stop_ratio=1.0, max_lights=10)
    assert r.chosen[0] == 2 and r.roles[0] == "diffuse"  # covers all 6 texels diffusely
    assert r.chosen[1] == 4 and r.roles[1] == "specular"  # 5 texels need specular, light 4 gives 5
    assert r.all_diffuse == 1.0
    assert math.isclose(r.all_specular, 4 / 6)  # texels 0-3 can reach two specular observations
    assert math.isclose(r.specular_curve[-1], r.all_specular)
    assert r.diffuse_curve[-1] == 1.0
    assert len(r.chosen) == len(set(r.chosen))


def test_stop_ratio_stops_early():
    m = toy()
    full = greedy_select(m, stop_ratio=1.0)
    early = greedy_select(m, stop_ratio=0.01)
    assert len(early.chosen) <= len(full.chosen)
    assert early.specular_curve[-1] >= 0.01 * early.all_specular


def test_num_lights_forces_the_count():
    m = toy()
    r = greedy_select(m, num_lights=5)
    assert sorted(r.chosen) == [0, 1, 2, 3, 4]
    with pytest.raises(ConfigError, match="selection.num_lights"):
        greedy_select(m, num_lights=9)


def test_unseen_texels_do_not_count():
    m = toy()
    m.seen[5] = False
    r = greedy_select(m, stop_ratio=1.0)
    assert r.seen_texels == 5 and r.all_diffuse == 1.0


def test_plot_and_table(tmp_path):
    m = toy()
    r = greedy_select(m, stop_ratio=1.0)
    plot_coverage(r, tmp_path / "c.png")
    assert (tmp_path / "c.png").stat().st_size > 1000
    t = r.table()
    assert t["lights_selected"] == len(r.chosen) and t["candidates"] == 5


def test_the_coverage_figure_marks_each_pick_and_keeps_its_legend_inside(tmp_path):
    import matplotlib

    m = toy()
    r = greedy_select(m, stop_ratio=1.0)
    backend = matplotlib.get_backend()
    matplotlib.use("svg")  # a backend other than the Agg a file writer might pick
    try:
        plot_coverage(r, tmp_path / "c.png")
        assert matplotlib.get_backend() == "svg"  # writing the plot leaves a notebook's backend alone
    finally:
        matplotlib.use(backend)
    fig = coverage_figure(r)
    fig.savefig(tmp_path / "c.png")
    (legend,) = fig.legends
    box, frame = legend.get_window_extent(), fig.bbox
    assert frame.x0 <= box.x0 and box.x1 <= frame.x1 and frame.y0 <= box.y0 and box.y1 <= frame.y1
    for ax in fig.axes:  # one marker per pick, in the style of its role
        marked = {line.get_marker(): len(line.get_xdata()) for line in ax.lines if line.get_marker() in ("o", "^")}
        assert marked == {"o": r.roles.count("diffuse"), "^": r.roles.count("specular")}


def test_counts_over_cameras_gain_only_what_a_texel_still_needs():
    # candidate 0: three specular observations of texel 0 (three cameras); candidate 1: one of each texel
    S = np.array([[3, 0, 0], [1, 1, 1]])
    m = Measurability(np.zeros_like(S), S, np.ones(3, dtype=bool))
    r = greedy_select(m, stop_ratio=1.0, max_lights=1)
    # a texel needs two: candidate 0 adds 2 observations that count, candidate 1 adds 3
    assert r.chosen == [1] and r.roles == ["specular"]
    assert math.isclose(r.all_specular, 1 / 3)  # only texel 0 reaches two (4 in all)
