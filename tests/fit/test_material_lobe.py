"""One lobe per material for texels without highlights (torchrefl.fit.material_lobe): texels join the grid neighbours of
their colour into clusters (a colour's smooth variation stays one cluster, a border splits two), and each cluster's
lobe is the least-squares lobe of all its observations with a Pd per texel, checked against a slow dense solve."""

import numpy as np
import pytest
import torch
from conftest import dome_scene, point_light_observations

from torchrefl.core.texel_grid import TexelGrid
from torchrefl.fit.material_lobe import MIN_CLUSTER, cluster_lobes, colour_clusters
from torchrefl.fit.profile_search import profile_search, profiled_fit, sigma_grid
from torchrefl.transport.local import local_terms, render_reference

H, W = 20, 30


def grid_index(h=H, w=W):
    return torch.arange(h * w)


def test_a_colour_with_smooth_variation_is_one_cluster_and_a_border_splits_two():
    rows, cols = np.meshgrid(np.arange(H), np.arange(W), indexing="ij")
    red = np.array([0.6, 0.2, 0.15]) * (1 + 0.15 * np.sin(cols / W * 2 * np.pi))[..., None]  # +-15 % along the row
    blue = np.broadcast_to(np.array([0.15, 0.25, 0.6]), (H, W, 3))
    pd = np.where((cols < 20)[..., None], red, blue).reshape(-1, 3)
    island = (rows >= 2) & (rows < 5) & (cols >= 24) & (cols < 27)  # 9 texels of a third colour inside the blue
    pd[island.ravel()] = [0.3, 0.6, 0.2]
    members = torch.ones(H * W, dtype=torch.bool)
    members[5] = False  # a texel with a measured lobe: in no cluster
    label = colour_clusters(TexelGrid(grid_index().numpy(), (H, W)), torch.from_numpy(pd), members)
    red_label, blue_label = label[W + 1], label[W + 25]
    assert red_label >= 0 and blue_label >= 0 and red_label != blue_label
    assert (label.reshape(H, W)[:, :20][~np.isin(np.arange(H * W), [5]).reshape(H, W)[:, :20]] == red_label).all()
    assert (label.reshape(H, W)[:, 20:][~island[:, 20:]] == blue_label).all()
    assert (label[island.ravel()] == -1).all()  # fewer than MIN_CLUSTER texels
    assert label[5] == -1
    assert island.sum() < MIN_CLUSTER


T = 60


def faint_lobe_scene(noise: float, seed: int = 3):
    """60 texels of one material on the dome seen under lights that give no highlight (every half-angle over 25
    degrees): a broad lobe (Ps 0.3, sigma 0.3) shows only in the tails, Pd varies per texel."""
    nrm, pos, lights, cam = dome_scene(T=T, seed=seed)
    obs = point_light_observations(nrm, pos, lights, cam, intensity=2.0e4)
    n = torch.as_tensor(nrm)
    terms = local_terms("torrance_sparrow", n, obs)
    obs.valid &= terms.theta_h > np.radians(25)
    g = torch.Generator().manual_seed(seed)
    pd = 0.3 + 0.3 * torch.rand(T, 3, generator=g, dtype=torch.float64)
    ps = torch.full((T, 3), 0.3, dtype=torch.float64)
    sigma = torch.full((T,), 0.3, dtype=torch.float64)
    intensity = render_reference("torrance_sparrow", n, obs, pd, ps, sigma)
    intensity = intensity + noise * torch.randn(intensity.shape, generator=g, dtype=torch.float64)
    return n, obs, terms, intensity


def dense_pooled_lobe(normals, obs, intensity, sigmas):
    """The slow reference: at each sigma one least-squares solve per channel of all observations for a Pd per texel
    and one Ps (numpy lstsq on the stacked system), the model from brdf.cosine_weighted_brdf."""
    zeros, ones = torch.zeros(T, 3, dtype=torch.float64), torch.ones(T, 3, dtype=torch.float64)
    diffuse = render_reference("torrance_sparrow", normals, obs, ones, zeros, torch.full((T,), 0.1).double()).numpy()
    valid = obs.valid.numpy()
    p_idx, t_idx = np.nonzero(valid)
    best = (np.inf, None, None)
    for s in sigmas:
        spec = render_reference("torrance_sparrow", normals, obs, zeros, ones, torch.full((T,), float(s))).numpy()
        err, ps = 0.0, []
        for c in range(3):
            A = np.zeros((len(p_idx), T + 1))
            A[np.arange(len(p_idx)), t_idx] = diffuse[p_idx, t_idx, c]
            A[:, T] = spec[p_idx, t_idx, c]
            b = intensity.numpy()[p_idx, t_idx, c]
            x, *_ = np.linalg.lstsq(A, b, rcond=None)
            err += float(((A @ x - b) ** 2).sum())
            ps.append(x[T])
        if err < best[0]:
            best = (err, float(s), ps)
    return best[1], np.array(best[2])


def test_the_cluster_lobe_is_the_dense_least_squares_lobe():
    normals, obs, terms, intensity = faint_lobe_scene(noise=0.002)
    profile = profiled_fit(terms, intensity, obs.valid, ps_channels=3)
    cluster = np.zeros(T, dtype=np.int64)
    ps, sigma, determined = cluster_lobes(profile.parts, cluster, sigma_grid(0.05, 0.6, 64), 3, ps_max=2.0)
    assert determined.all()
    ref_sigma, ref_ps = dense_pooled_lobe(normals, obs, intensity, np.exp(np.linspace(np.log(0.25), np.log(0.36), 150)))
    assert abs(float(sigma[0]) / ref_sigma - 1) < 0.01
    assert np.abs(ps[0].numpy() / ref_ps - 1).max() < 0.02


@pytest.mark.parametrize("ps_channels", [1, 3])
def test_pooling_recovers_a_lobe_each_texel_alone_cannot(ps_channels):
    """Noise of about a third of the mean intensity: each texel's own Ps is 17-23 % off in the median."""
    normals, obs, terms, intensity = faint_lobe_scene(noise=0.02)
    grid = sigma_grid(0.05, 0.6, 64)
    _, ps_t, sg_t, _ = profile_search(terms, intensity, obs.valid, grid, ps_channels, ps_max=2.0)
    assert (ps_t / 0.3 - 1).abs().median() > 0.15
    profile = profiled_fit(terms, intensity, obs.valid, ps_channels=ps_channels, ps_max=2.0)
    two = np.where(np.arange(T) < T // 2, 0, 1)  # two clusters of the same material: each recovers it
    ps, sigma, _ = cluster_lobes(profile.parts, two, grid, ps_channels, ps_max=2.0)
    assert ps.shape == (2, ps_channels)
    assert (sigma / 0.3 - 1).abs().max() < 0.04
    assert (ps / 0.3 - 1).abs().max() < 0.1


@pytest.mark.parametrize("offset", [-0.3, 0.3])
def test_the_lobe_between_grid_values_is_the_parabolas_vertex_on_either_side_of_a_grid_value(offset):
    """Sums whose error is exactly quadratic in log sigma with its minimum `offset` grid steps from a grid value,
    and whose least-squares Ps is linear in log sigma: the vertex and Ps are found exactly, on either side; a
    cluster whose observations carry no specular light (vv = 0) is reported as not determined."""
    grid = sigma_grid(0.05, 0.6, 16)
    step = float(grid.log()[1] - grid.log()[0])
    x0 = float(grid.log()[7]) + offset * step  # the true log sigma

    def parts(s):
        x = float(torch.log(s))
        ps = 0.3 + 0.2 * (x - x0)  # least-squares Ps at this sigma: uv / vv
        vv = torch.tensor([[2.0, 2.0, 2.0], [0.0, 0.0, 0.0]], dtype=torch.float64)
        uv = ps * vv
        err = 1.0 + 5.0 * (x - x0) ** 2  # what is left at that Ps: uu - uv^2 / vv per cluster, over 3 channels
        uu = (err / 3 + uv * uv / vv.clamp_min(1e-30)) * (vv > 0) + torch.tensor([[0.0] * 3, [1.0] * 3]) * (vv == 0)
        return uu, uv, vv

    ps, sigma, determined = cluster_lobes(parts, np.array([0, 1]), grid, ps_channels=3, ps_max=2.0)
    assert determined.tolist() == [True, False]
    assert float(sigma[0].log()) == pytest.approx(x0, abs=1e-9)
    assert torch.allclose(ps[0], torch.full((3,), 0.3, dtype=torch.float64), atol=1e-9)
