"""torchrefl.report.export_material: the fitted sigma -> (roughness, specular) conversion, checked with the glTF BRDF
written from the specification (tests/reference/gltf_brdf.py), not with the module's own GGX."""

import math

import numpy as np
import pytest
from reference.gltf_brdf import gltf_brdf

from torchrefl.report.export_material import SPECULAR_COLOR_FACTOR, gltf_material, lobe_table, match_lobe


def torrance_sparrow_spec(n, l, v, ps, sigma):
    """The seed's eq. 2.9 lobe, f_s = Ps exp(-theta_h^2 / (2 sigma^2)) / (pi cos_l cos_v), written out here."""
    h = (l + v) / np.linalg.norm(l + v, axis=-1, keepdims=True)
    th = np.arccos(np.clip(np.sum(n * h, -1), -1, 1))
    cl, cv = np.sum(n * l, -1), np.sum(n * v, -1)
    return ps * (np.exp(-th * th / (2 * sigma * sigma)) / (math.pi * cl * cv))[..., None]


def lobe_pairs(sigma, count=4000, seed=0):
    """Random (l, v) pairs around the mirror direction (half vectors within 3 sigma, views up to 60 degrees),
    both above the horizon; n = +z."""
    rng = np.random.default_rng(seed)
    tv = np.radians(rng.uniform(0, 60, count))
    pv = rng.uniform(0, 2 * math.pi, count)
    v = np.stack([np.sin(tv) * np.cos(pv), np.sin(tv) * np.sin(pv), np.cos(tv)], -1)
    th = rng.uniform(0, 3 * sigma, count)
    ph = rng.uniform(0, 2 * math.pi, count)
    h = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], -1)
    l = 2 * np.sum(v * h, -1, keepdims=True) * h - v
    keep = l[:, 2] > 0.05
    return np.array([0.0, 0.0, 1.0]), l[keep], v[keep]


def spec_error(formula, sigma, ps=0.4):
    """Relative RMS of the glTF specular part (the specification's BRDF with base colour 0) against the fitted
    lobe, cosine-weighted, over lobe_pairs."""
    n, l, v = lobe_pairs(sigma)
    m = gltf_material(np.zeros((1, 1, 3)), np.full((1, 1, 1), ps), np.full((1, 1), sigma), "torrance_sparrow", formula)
    f = gltf_brdf(
        n, l, v, np.zeros(3), m.roughness[0, 0], 0.0, m.specular[0, 0], SPECULAR_COLOR_FACTOR * m.specular_color[0, 0]
    )
    ref = torrance_sparrow_spec(n, l, v, ps, sigma)
    cl = l[:, 2:3]
    return math.sqrt(np.mean(((f - ref) * cl) ** 2) / np.mean((ref * cl) ** 2))


@pytest.mark.parametrize("sigma", [0.05, 0.15, 0.35])
def test_fitted_conversion_beats_the_one_line_formula_under_the_gltf_brdf(sigma):
    fitted, one_line = spec_error("fitted", sigma), spec_error("one_line", sigma)
    assert fitted < one_line
    assert fitted < 0.35  # a Gaussian lobe and GGX differ in their tails: not a perfect match


def test_the_table_interpolates_the_least_squares_match():
    table = lobe_table("torrance_sparrow")
    assert np.all(np.diff(table.alpha) >= 0) and np.all(np.diff(table.gain) > 0)  # wider lobes, rougher glTF
    assert table.alpha[-1] <= 1.0  # glTF roughness is at most 1
    for sigma in (0.021, 0.13, 0.47):  # between the table's nodes
        alpha, gain, _ = match_lobe("torrance_sparrow", sigma)
        a, k = table.lookup(np.array(sigma))
        assert a == pytest.approx(alpha, rel=0.02) and k == pytest.approx(gain, rel=0.03)


def test_specular_colour_and_strength_split_ps():
    ps = np.array([[[0.2, 0.1, 0.0], [0.0, 0.0, 0.0]]])
    m = gltf_material(np.full((1, 2, 3), 0.5), ps, np.full((1, 2), 0.1), "torrance_sparrow")
    _, gain = lobe_table("torrance_sparrow").lookup(np.array(0.1))
    np.testing.assert_allclose(m.specular[0], [0.2 * gain, 0.0])
    np.testing.assert_allclose(m.specular_color[0, 0], [1.0, 0.5, 0.0])
    np.testing.assert_allclose(m.base_color, 0.5)
    lam = gltf_material(np.full((1, 1, 3), 0.5), np.full((1, 1, 1), 0.3), np.full((1, 1), 0.1), "lambertian")
    assert lam.specular[0, 0] == 0


def test_grey_ps_has_no_fresnel_rise():
    """f0 = f90 = specular for grey Ps: the glTF specular part does not grow towards grazing (the fitted lobes
    have no Fresnel term); with specular colour 0.04 (glTF's default dielectric) it would."""
    m = gltf_material(np.zeros((1, 1, 3)), np.full((1, 1, 1), 0.3), np.full((1, 1), 0.2), "torrance_sparrow")
    n = np.array([0.0, 0.0, 1.0])
    grazing = np.radians(80)
    v = np.array([math.sin(grazing), 0, math.cos(grazing)])
    l = np.array([-math.sin(grazing), 0, math.cos(grazing)])  # mirror: h = n, v.h = cos 80
    args = (n, l, v, np.zeros(3), m.roughness[0, 0], 0.0, m.specular[0, 0])
    flat = gltf_brdf(*args, SPECULAR_COLOR_FACTOR * m.specular_color[0, 0])
    dielectric = gltf_brdf(*args, np.ones(3))
    s = m.specular[0, 0]
    assert dielectric[0] / flat[0] == pytest.approx((0.04 * s + (s - 0.04 * s) * (1 - math.cos(grazing)) ** 5) / s)
