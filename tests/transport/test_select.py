"""auto: the rules that pick the transport level, and the numbers they report."""

import torch

from torchrefl.transport.select import choose_level


def test_no_mesh_is_local():
    c = choose_level(False, None, None, None, 0.5)
    assert c.level == "local" and "no depth" in c.reason


def test_no_form_factors_is_local():
    c = choose_level(True, torch.zeros(4, 4), torch.zeros(3), torch.zeros(3), 0.5)
    assert c.level == "local" and c.numbers["form_factor_nonzeros"] == 0


def test_interreflection_below_noise_is_local():
    F = torch.full((4, 4), 0.1)
    c = choose_level(True, F, torch.full((100,), 0.1), torch.full((100,), 0.01), 0.5)
    assert c.level == "local" and c.numbers["diffuse_interreflection_dn_p999"] < 0.5


def test_diffuse_only_is_radiosity_and_specular_asks_for_photon():
    F = torch.full((4, 4), 0.1).to_sparse()
    c = choose_level(True, F, torch.full((100,), 3.0), torch.full((100,), 0.1), 0.5)
    assert c.level == "radiosity" and "below the noise floor" in c.reason
    c = choose_level(True, F, torch.full((100,), 3.0), torch.full((100,), 2.0), 0.5, photon_available=True)
    assert c.level == "photon"
    c = choose_level(True, F, torch.full((100,), 3.0), torch.full((100,), 2.0), 0.5, photon_available=False)
    assert c.level == "radiosity" and "photon level" in c.reason
