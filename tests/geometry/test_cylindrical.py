"""Eq. 2.1 points and eq. 2.3 outward normals of a cylindrical range image (torchrefl.geometry.cylindrical)."""

import math

import pytest
import torch

from torchrefl.errors import GeometryError
from torchrefl.geometry.cylindrical import cylindrical_normals, cylindrical_points

DS = math.radians(0.7)  # the seed scanner (Table 2.1), as in test_range_image
DT = 0.56


def axes(H, W, s0, t0, ds=DS, dt=DT, dtype=torch.float64):
    s = s0 + ds * torch.arange(W, dtype=dtype)
    t = t0 + dt * torch.arange(H, dtype=dtype)
    return s, t


def test_normals_formula_against_finite_difference_cross_product():
    """cylindrical_normals for arbitrary r, r_s, r_t is the outward S_t x S_s of eq. 2.3 (not eq. 2.4 as printed)."""
    gen = torch.Generator().manual_seed(2)
    s, t = axes(6, 7, s0=0.3, t0=-2.0)
    r = 40 + 10 * torch.rand(6, 7, generator=gen, dtype=torch.float64)
    r_s = 30 * torch.randn(6, 7, generator=gen, dtype=torch.float64)
    r_t = torch.randn(6, 7, generator=gen, dtype=torch.float64)
    n = cylindrical_normals(r, r_s, r_t, s, t)
    S = torch.stack([-r * torch.sin(s), (-t)[:, None].expand(6, 7), -r * torch.cos(s)], -1)
    S_s = torch.stack(
        [-r_s * torch.sin(s) - r * torch.cos(s), torch.zeros_like(r), -r_s * torch.cos(s) + r * torch.sin(s)], -1
    )
    S_t = torch.stack([-r_t * torch.sin(s), -torch.ones_like(r), -r_t * torch.cos(s)], -1)
    c = torch.linalg.cross(S_s, S_t)
    c = c / c.norm(dim=-1, keepdim=True)
    torch.testing.assert_close(n.abs(), c.abs(), atol=1e-12, rtol=0)  # parallel to the cross product
    radial_part = (n * (S * torch.tensor([1.0, 0.0, 1.0], dtype=torch.float64))).sum(-1)
    assert (radial_part > 0).all()  # and outward
    torch.testing.assert_close(n.norm(dim=-1), torch.ones(6, 7, dtype=torch.float64), atol=1e-12, rtol=0)
    torch.testing.assert_close(cylindrical_points(r, s, t), S, atol=0, rtol=0)


def _r():
    return torch.full((12, 12), 50.0, dtype=torch.float64)


BAD = [
    ("s", lambda: cylindrical_points(_r(), torch.zeros(11, dtype=torch.float64), torch.zeros(12))),
    ("t", lambda: cylindrical_points(_r(), torch.zeros(12, dtype=torch.float64), torch.zeros(12, 1))),
    ("r", lambda: cylindrical_points(_r().float().int(), torch.zeros(12), torch.zeros(12))),
    (
        "r_s",
        lambda: cylindrical_normals(
            _r(),
            torch.zeros(12, 11, dtype=torch.float64),
            torch.zeros(12, 12, dtype=torch.float64),
            torch.zeros(12),
            torch.zeros(12),
        ),
    ),
]


@pytest.mark.parametrize("name,call", BAD, ids=[f"{i}-{b[0]}" for i, b in enumerate(BAD)])
def test_bad_input_raises_geometry_error_naming_the_argument(name, call):
    with pytest.raises(GeometryError, match=f"'{name}'"):
        call()
