"""The automatic density kernel (photon.smoothing / specular_smoothing: null): the same noise at any resolution."""

import numpy as np
import pytest
import torch

from torchrefl.transport.photon_density import KERNEL_PHOTONS, kernel_std, smoothing_matrix


def smoothed_noise(rows: int, cols: int, photons: int, seed: int = 0) -> float:
    """Relative std of the smoothed photon count of a uniformly lit rows x cols grid (interior texels)."""
    rng = np.random.default_rng(seed)
    T = rows * cols
    counts = np.bincount(rng.integers(0, T, size=photons), minlength=T).astype(np.float64)
    std = kernel_std(photons, T, KERNEL_PHOTONS)
    M = smoothing_matrix(np.arange(T), (rows, cols), std)
    smooth = torch.sparse.mm(M, torch.from_numpy(counts)[:, None]).numpy()[:, 0].reshape(rows, cols)
    pad = int(np.ceil(3 * std))
    inner = smooth[pad:-pad, pad:-pad]
    return float(inner.std() / inner.mean())


def test_the_automatic_kernel_gives_the_same_noise_at_any_resolution():
    """Four times the texels at the same photon count: the kernel doubles in texels (the same width on the
    object), so the smoothed irradiance is as noisy as before; a fixed kernel in texels would be twice as noisy."""
    coarse = smoothed_noise(60, 60, 400_000)
    fine = smoothed_noise(120, 120, 400_000)
    assert kernel_std(400_000, 120 * 120, KERNEL_PHOTONS) == pytest.approx(
        2 * kernel_std(400_000, 60 * 60, KERNEL_PHOTONS)
    )
    assert fine == pytest.approx(coarse, rel=0.2)
    # Poisson counts under a normalised Gaussian: relative std 1 / sqrt(n 4 pi std^2) = 1 / sqrt(KERNEL_PHOTONS)
    assert coarse == pytest.approx(1 / np.sqrt(KERNEL_PHOTONS), rel=0.15)


def test_more_photons_narrow_the_automatic_kernel():
    assert kernel_std(1_600_000, 34_449, KERNEL_PHOTONS) == pytest.approx(
        kernel_std(400_000, 34_449, KERNEL_PHOTONS) / 2
    )
