"""Which texels an outer iteration leaves alone: quiet texels (predicted interreflection below the noise floor on all
their fitted observations) and the texels whose indirect terms moved by more than it."""

import torch

from torchrefl.fit.outer_skip import IndirectMemory, quiet_texels
from torchrefl.transport.levels.base import IndirectTerms


def terms_of(diffuse: torch.Tensor, specular: torch.Tensor) -> IndirectTerms:
    """Indirect terms whose specular factor is specular (P, T, 3) times the texel's sigma."""
    return IndirectTerms(diffuse, lambda s: specular * torch.as_tensor(s)[..., None])


def test_quiet_texels_are_those_below_the_floor_on_every_fitted_observation():
    diffuse = torch.zeros(2, 3, 3)
    specular = torch.zeros(2, 3, 3)
    diffuse[0, 0, 1] = 0.4 / 255  # texel 0: 0.4 DN at Pd 1
    diffuse[1, 1, 2] = 0.6 / 255  # texel 1: 0.6 DN, but not a fitted observation
    specular[0, 2, 0] = 1.0 / 255  # texel 2: 1 DN per unit Ps at sigma 1
    mask = torch.tensor([[True, True, True], [True, False, True]])
    pd, ps = torch.ones(3, 3), torch.full((3, 1), 0.5)
    sigma = torch.tensor([1.0, 1.0, 0.8])
    quiet = quiet_texels(terms_of(diffuse, specular), pd, ps, sigma, mask, 0.5)
    assert quiet.tolist() == [True, True, True]  # texel 2: 0.5 Ps x 0.8 DN = 0.4
    quiet = quiet_texels(terms_of(diffuse, specular), pd, ps, sigma * 1.25, mask, 0.5)
    assert quiet.tolist() == [True, True, False]  # 0.5 DN: not below the floor
    mask[1, 1] = True
    assert quiet_texels(terms_of(diffuse, specular), pd, ps, sigma, mask, 0.5).tolist() == [True, False, True]


def test_changed_texels_are_those_whose_indirect_light_moved_beyond_the_floor():
    diffuse = torch.full((2, 3, 3), 2.0 / 255)
    specular = torch.full((2, 3, 3), 1.0 / 255)
    sigma = torch.tensor([0.1, 0.2, 0.3])
    memory = IndirectMemory.of(terms_of(diffuse, specular), sigma)
    mask = torch.ones(2, 3, dtype=torch.bool)
    pd, ps = torch.full((3, 3), 0.5), torch.ones(3, 1)
    moved_d, moved_s = diffuse.clone(), specular.clone()
    moved_d[1, 0, 0] += 1.2 / 255  # texel 0: 0.6 DN at Pd 0.5
    moved_s[0, 1, 2] += 4.0 / 255  # texel 1: 0.8 DN at Ps 1 and its remembered sigma 0.2
    moved_s[0, 2, 1] += 1.0 / 255  # texel 2: 0.3 DN
    now = terms_of(moved_d, moved_s)
    assert memory.changed(now, pd, ps, mask, 0.5).tolist() == [True, True, False]
    mask[1, 0] = False
    assert memory.changed(now, pd, ps, mask, 0.5).tolist() == [False, True, False]
