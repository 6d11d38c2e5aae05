"""The start's per-texel sigma search (torchrefl.fit.initialise): searched at the texels with specular evidence only,
under the images that observe them, it gives those texels what the search over every texel and image gives."""

import torch
from test_profile_search import T, scene

from torchrefl.fit.initialise import _searched
from torchrefl.fit.profile_search import profile_search, sigma_grid


def test_the_search_of_the_texels_with_evidence_equals_the_whole_search_there():
    terms, intensity, mask, _ = scene(noise=0.01)
    mask = mask.clone()
    evidence = torch.arange(T) % 3 != 0
    mask[0, evidence] = False  # image 0 observes only texels without evidence: the subset search leaves it out
    mask[1, :] = False  # image 1 observes nothing
    grid = sigma_grid(0.01, 0.6, 16)
    whole = profile_search(terms, intensity, mask, grid, 3, ps_max=2.0)
    part = _searched(terms, intensity, mask, evidence, grid, 3, 2.0)
    for w, p in zip(whole, part):
        torch.testing.assert_close(p[evidence], w[evidence], rtol=1e-9, atol=1e-12)
    assert torch.isinf(part[3][~evidence]).all()  # never taken: no texel without evidence reads a search value
