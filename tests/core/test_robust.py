"""robust_std: the normal std of a sample's bulk, by hand on a small case and on a contaminated normal sample."""

import torch

from torchrefl.core.robust import robust_std


def test_a_small_case_by_hand():
    x = torch.tensor([1.0, 2.0, 3.0, 4.0, 100.0], dtype=torch.float64)
    # median 3, absolute deviations 2 1 0 1 97, their median 1
    assert float(robust_std(x)) == 1.4826


def test_the_std_of_a_normal_sample_despite_outliers_along_a_dim():
    g = torch.Generator().manual_seed(0)
    x = torch.randn(20000, 3, generator=g, dtype=torch.float64) * torch.tensor([0.5, 1.0, 2.0], dtype=torch.float64)
    x[:400] = 1e3  # 2 % outliers (they move the MAD by about 3 %, the std a thousandfold)
    assert torch.allclose(robust_std(x, 0), torch.tensor([0.5, 1.0, 2.0], dtype=torch.float64), rtol=0.05)
