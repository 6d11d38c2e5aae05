"""Lobes of unmeasured texels from measured texels of their colour (torchrefl.fit.material_fill): a texel takes the
lobe of the nearest measured texels of its own colour, not of the nearest measured texels; a colour no measured texel
has is left alone; lobes measured from too few highlights are not lent."""

import torch

from torchrefl.fit.material_fill import COLOUR_TOLERANCE, LENDER_HIGHLIGHTS, NEIGHBOURS, colour_matched_lobes

H, W = 20, 60
T = H * W
RED, BLUE, GREEN = (0.6, 0.2, 0.15), (0.15, 0.25, 0.6), (0.3, 0.6, 0.2)
LOBES = {RED: (0.35, 0.1), BLUE: (0.2, 0.3), GREEN: (0.5, 0.05)}


def strip_scene():
    """A 20 x 60 texel sheet (1 mm texels): red in columns 0-19 and 40-59, blue in 20-39, each with its lobe measured
    (three highlights) except red columns 0-19, whose lobes are unknown (NaN) and whose nearest measured texels are
    blue. Returns positions, pd, ps, sigma, known, highlights."""
    rows, cols = torch.meshgrid(torch.arange(H), torch.arange(W), indexing="ij")
    positions = torch.stack([cols.flatten(), rows.flatten(), torch.zeros(T, dtype=torch.long)], 1).double()
    col = cols.flatten()
    colour = [BLUE if 20 <= c < 40 else RED for c in col.tolist()]
    pd = torch.tensor(colour, dtype=torch.float64)
    pd = pd * (1 + 0.03 * torch.sin(positions[:, :1] / 7))  # smooth variation within a material
    ps = torch.tensor([[LOBES[c][0]] * 3 for c in colour], dtype=torch.float64)
    sigma = torch.tensor([LOBES[c][1] for c in colour], dtype=torch.float64)
    known = col >= 20
    ps[~known], sigma[~known] = float("nan"), float("nan")
    highlights = torch.where(known, LENDER_HIGHLIGHTS, 0)
    return positions, pd, ps, sigma, known, highlights


def test_an_unmeasured_texel_takes_the_lobe_of_its_own_colour_not_of_its_nearest_neighbours():
    positions, pd, ps, sigma, known, highlights = strip_scene()
    todo = ~known
    ps_f, sigma_f, matched = colour_matched_lobes(positions, pd, ps, sigma, known, todo, highlights)
    assert matched.equal(todo)
    assert torch.allclose(ps_f[todo], torch.full_like(ps_f[todo], LOBES[RED][0]))
    assert torch.allclose(sigma_f[todo], torch.full_like(sigma_f[todo], LOBES[RED][1]))
    assert ps_f[known].equal(ps[known]) and sigma_f[known].equal(sigma[known])


def test_among_texels_of_its_colour_the_nearest_lend_their_lobe():
    """The measured red texels carry a gradient of sigma along the rows: each unmeasured texel takes the sigma of
    the measured texels next to it in space (its own row, give or take the NEIGHBOURS nearest)."""
    positions, pd, ps, sigma, known, highlights = strip_scene()
    red_measured = known & (positions[:, 0] >= 40)
    sigma = sigma.clone()
    sigma[red_measured] = 0.05 + 0.01 * positions[red_measured, 1]
    _, sigma_f, _ = colour_matched_lobes(positions, pd, ps, sigma, known, ~known, highlights)
    top = (~known) & (positions[:, 1] < 3)
    bottom = (~known) & (positions[:, 1] > H - 4)
    assert float(sigma_f[top].max()) <= 0.05 + 0.01 * 7  # the red median is 0.145
    assert float(sigma_f[bottom].min()) > 0.05 + 0.01 * (H - 8)


def test_a_colour_no_measured_texel_has_is_left_to_the_window_fill():
    positions, pd, ps, sigma, known, highlights = strip_scene()
    pd = pd.clone()
    pd[~known] = torch.tensor(GREEN, dtype=torch.float64)
    _, _, matched = colour_matched_lobes(positions, pd, ps, sigma, known, ~known, highlights)
    assert not matched.any()
    # a colour just within the tolerance of red is still red
    pd[~known] = torch.tensor(RED, dtype=torch.float64) * (1 + 0.5 * COLOUR_TOLERANCE)
    _, _, matched = colour_matched_lobes(positions, pd, ps, sigma, known, ~known, highlights)
    assert matched.equal(~known)


def test_lobes_measured_from_too_few_highlights_are_not_lent():
    """Red lobes measured from fewer than LENDER_HIGHLIGHTS highlights (a wrong lobe here) near the unmeasured red
    texels, correct ones further away: the unmeasured texels take the correct ones."""
    positions, pd, ps, sigma, known, highlights = strip_scene()
    ps, sigma, highlights = ps.clone(), sigma.clone(), highlights.clone()
    near = (positions[:, 0] >= 20) & (positions[:, 0] < 25)  # the blue columns next to them made red
    pd = pd.clone()
    pd[near] = torch.tensor(RED, dtype=torch.float64)
    ps[near], sigma[near], highlights[near] = 0.02, 0.5, LENDER_HIGHLIGHTS - 1
    assert int(near.sum()) >= NEIGHBOURS
    ps_f, sigma_f, _ = colour_matched_lobes(positions, pd, ps, sigma, known, ~known, highlights)
    assert torch.allclose(sigma_f[~known], torch.full_like(sigma_f[~known], LOBES[RED][1]))
    assert torch.allclose(ps_f[~known], torch.full_like(ps_f[~known], LOBES[RED][0]))


def test_nothing_to_fill_or_nothing_measured_leaves_the_lobes():
    positions, pd, ps, sigma, known, highlights = strip_scene()
    none = torch.zeros(T, dtype=torch.bool)
    for todo, kn in ((none, known), (~known, none)):
        ps_f, sigma_f, matched = colour_matched_lobes(positions, pd, ps, sigma, kn, todo, highlights)
        assert not matched.any()
        assert torch.allclose(ps_f, ps, equal_nan=True) and torch.allclose(sigma_f, sigma, equal_nan=True)


def test_the_start_fills_by_colour_first_then_by_window_then_by_the_median_lobe():
    """initialise.fill_lobes on the strip scene with a green strip no measured texel shares between the unmeasured red
    texels and the measured blue ones: the red texels take the red lobe, the green texels within the window's reach
    of the blue ones (two passes of a 5 x 5 window: 4 columns) the blue lobe, the others the median lobe (flagged as
    the object's lobe); measured texels keep theirs."""
    from torchrefl.core.surface import Surface
    from torchrefl.fit.initialise import fill_lobes

    positions, pd, ps, sigma, known, highlights = strip_scene()
    cols = positions[:, 0].long()
    pd = pd.clone()
    green = (cols >= 12) & (cols < 20)
    pd[green] = torch.tensor(GREEN, dtype=torch.float64)
    up = torch.zeros(T, 3, dtype=torch.float64)
    up[:, 2] = 1.0
    surface = Surface((H, W), torch.arange(T), positions, up, torch.ones(T, dtype=torch.float64))
    defined = torch.ones(T, dtype=torch.bool)
    ps_f, sigma_f, object_lobe, matched = fill_lobes(surface, pd, ps, sigma, known, defined, highlights, 5, 0.01, 0.6)
    red = ~known & ~green
    assert matched.equal(red)
    assert torch.allclose(sigma_f[red], torch.full_like(sigma_f[red], LOBES[RED][1]))
    assert object_lobe.equal(green & (cols < 16))
    window = green & (cols >= 16)
    assert torch.allclose(sigma_f[window], torch.full_like(sigma_f[window], LOBES[BLUE][1]))
    assert torch.allclose(sigma_f[known], sigma[known])
    assert torch.isfinite(sigma_f).all() and torch.isfinite(ps_f).all()
