"""torchrefl.transport.final_traces: one trace's photon variance measured from a two-trace average, the images'
noise, and the number of fresh traces the final images need."""

import torch

from torchrefl.transport.final_traces import (
    FINAL_TRACES,
    PHOTON_NOISE_SHARE,
    fresh_traces,
    image_variance,
    trace_variance,
)


def test_a_two_trace_average_gives_one_traces_variance():
    g = torch.Generator().manual_seed(0)
    P, T = 20, 500
    truth = torch.rand(P, T, 3, generator=g, dtype=torch.float64)
    std = torch.tensor([0.2, 0.5, 1.0], dtype=torch.float64) / 255  # one trace's photon noise per channel
    a = truth + std * torch.randn(P, T, 3, generator=g, dtype=torch.float64)
    b = truth + std * torch.randn(P, T, 3, generator=g, dtype=torch.float64)
    mask = torch.rand(P, T, generator=g) < 0.7
    v = trace_variance(0.5 * (a + b), b, mask)
    torch.testing.assert_close(v, (std * 255) ** 2, rtol=0.05, atol=0)
    assert torch.isinf(trace_variance(a, b, torch.zeros(P, T, dtype=torch.bool))).all()


def test_the_images_noise_is_the_residuals_robust_spread():
    g = torch.Generator().manual_seed(1)
    images = torch.rand(10, 300, 3, generator=g, dtype=torch.float64)
    noisy = images + 0.4 / 255 * torch.randn(images.shape, generator=g, dtype=torch.float64)
    noisy[0, :5] = 1.0  # outliers do not move a robust spread
    s2 = image_variance(images, noisy, torch.ones(10, 300, dtype=torch.bool))
    torch.testing.assert_close(s2, torch.full((3,), 0.16, dtype=torch.float64), rtol=0.1, atol=0)


def test_fresh_traces_follow_the_photon_noise():
    noise = torch.full((3,), 0.2, dtype=torch.float64)  # DN^2
    share = PHOTON_NOISE_SHARE * 0.2
    assert fresh_traces(torch.full((3,), 0.5 * share), noise, 2) == 0  # the kept average is enough
    assert fresh_traces(torch.full((3,), 2.9 * share), noise, 2) == 1  # 2.9 / 3 traces <= the share
    assert fresh_traces(torch.tensor([0.1 * share, 3.5 * share, 0.0]), noise, 2) == 2  # the worst channel decides
    assert fresh_traces(torch.full((3,), 100 * share), noise, 2) == FINAL_TRACES - 1  # at most FINAL_TRACES caches
    assert fresh_traces(torch.full((3,), 0.5 * share), noise, 1) == 0
    assert fresh_traces(None, None, 1) == FINAL_TRACES - 1  # not measured: all of them
    assert fresh_traces(torch.full((3,), float("inf")), noise, 2) == FINAL_TRACES - 1
