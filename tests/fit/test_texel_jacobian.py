"""torchrefl.fit.texel_jacobian: the closed-form Jacobian of a TexelModel against reverse-mode autograd of its images
(float64, glossy non-uniform texels, indirect light, one or three Ps channels, both lobes, sigma at its clamp), its
information and leverages against the dense products, and float32 against float64."""

import pytest
import torch
from conftest import noisy_glossy_scene as glossy_scene

from torchrefl.core.brdf import SIGMA_EPS, specular_lobe
from torchrefl.fit.texel_jacobian import ChannelJacobian, DenseJacobian, dense_jacobian, jacobian
from torchrefl.transport.local import LocalTerms
from torchrefl.transport.texel_model import TexelModel


def texel_model(brdf="torrance_sparrow", indirect=True, T=12, seed=3, dtype=torch.float64):
    """A TexelModel of the glossy dome's texels; with indirect light: a random diffuse factor and a specular factor
    summed over random entries (a lobe-weighted sum, as the photon level's)."""
    obs, terms, (pd, ps, sigma) = glossy_scene(T=T, seed=seed, noise=0.0)
    terms = LocalTerms(brdf, *(getattr(terms, k).to(dtype) for k in ("theta_h", "cos_l", "cos_v", "diffuse")),
                       terms.specular.to(dtype))  # fmt: skip
    if not indirect:
        return TexelModel(terms), (pd.to(dtype), ps.to(dtype), sigma.to(dtype))
    g = torch.Generator().manual_seed(seed)
    P = terms.theta_h.shape[0]
    diffuse = (0.05 * torch.rand(P, T, 3, generator=g, dtype=torch.float64)).to(dtype)
    E = 3 * P * T
    at = torch.randint(0, P * T, (E,), generator=g)
    theta = (0.6 * torch.rand(E, generator=g, dtype=torch.float64)).to(dtype)
    weight = (0.02 * torch.rand(E, 3, generator=g, dtype=torch.float64)).to(dtype)

    def specular(s):
        D = specular_lobe(brdf, theta, s[at % T])
        return torch.zeros(P * T, 3, dtype=dtype).index_add(0, at, D[:, None] * weight).view(P, T, 3)

    return TexelModel(terms, diffuse, specular), (pd.to(dtype), ps.to(dtype), sigma.to(dtype))


def autograd_jacobian(model, pd, ps, sigma):
    """(P, T, 3, K) d(255 i_ptc) / d theta_t by reverse mode: one backward pass per image and channel of the summed
    images (each texel's images depend on its own parameters only)."""
    x = [q.clone().requires_grad_(True) for q in (pd, ps, sigma)]
    out = model(*x) * 255.0
    P, T, _ = out.shape
    J = torch.zeros(P, T, 3, 4 + ps.shape[1], dtype=out.dtype)
    for p in range(P):
        for c in range(3):
            g = torch.autograd.grad(out[p, :, c].sum(), x, retain_graph=True)
            J[p, :, c] = torch.cat([g[0], g[1], g[2][:, None]], 1)
    return J


@pytest.mark.parametrize("brdf", ["torrance_sparrow", "ward"])
@pytest.mark.parametrize("indirect", [False, True])
@pytest.mark.parametrize("C", [1, 3])
def test_the_closed_form_is_autograds(brdf, indirect, C):
    model, (pd, ps, sigma) = texel_model(brdf, indirect)
    ps = ps if C == 3 else ps.mean(1, keepdim=True)
    sigma = sigma.clone()
    sigma[0] = 0.5 * SIGMA_EPS  # under the clamp: no derivative, as autograd's clamp
    J = jacobian(model, pd, ps, sigma)
    assert isinstance(J, ChannelJacobian)
    torch.testing.assert_close(J.dense(), autograd_jacobian(model, pd, ps, sigma), rtol=1e-10, atol=1e-10)


def test_information_and_leverage_equal_the_dense_products():
    model, (pd, ps, sigma) = texel_model()
    J = jacobian(model, pd, ps, sigma)
    dense = DenseJacobian(J.dense())
    g = torch.Generator().manual_seed(0)
    P, T = J.values.shape[2:]
    weight = torch.rand(P, T, 3, generator=g, dtype=torch.float64) * (torch.rand(P, T, 1, generator=g) > 0.3)
    noise = torch.tensor([0.5, 1.0, 2.0], dtype=torch.float64)
    info = J.information(weight).scaled(noise)
    torch.testing.assert_close(info, dense.information(weight).scaled(noise), rtol=1e-12, atol=1e-9)
    ref = torch.einsum("ptck,ptc,ptcl->tkl", dense.values, weight / noise**2, dense.values)
    torch.testing.assert_close(info, ref, rtol=1e-12, atol=1e-9)
    cov = torch.linalg.inv(info + torch.eye(7, dtype=torch.float64))
    torch.testing.assert_close(J.quadratic(cov), dense.quadratic(cov), rtol=1e-10, atol=1e-12)
    half = J.texels(slice(None, None, 2))
    torch.testing.assert_close(half.dense(), J.dense()[:, ::2])


def test_the_jvp_jacobian_of_a_plain_model_is_dense_and_autograds():
    model, (pd, ps, sigma) = texel_model(indirect=True)
    plain = lambda a, b, c: model(a, b, c)  # not a TexelModel: forward-mode passes
    J = jacobian(plain, pd, ps, sigma)
    assert isinstance(J, DenseJacobian)
    torch.testing.assert_close(J.values, dense_jacobian(model, pd, ps, sigma).values)
    torch.testing.assert_close(J.values, autograd_jacobian(model, pd, ps, sigma), rtol=1e-10, atol=1e-10)


def test_float32_agrees_with_float64():
    m64, x64 = texel_model(dtype=torch.float64)
    m32, x32 = texel_model(dtype=torch.float32)
    J64, J32 = jacobian(m64, *x64), jacobian(m32, *x32)
    assert J32.values.dtype == torch.float32 and torch.isfinite(J32.values).all()
    scale = J64.values.abs().amax()
    assert float((J32.values.double() - J64.values).abs().max() / scale) < 1e-5
    w = torch.ones(*J64.values.shape[2:], 3, dtype=torch.float64)
    s = torch.ones(3, dtype=torch.float64)
    i64, i32 = J64.information(w).scaled(s), J32.information(w).scaled(s)
    assert i32.dtype == torch.float64  # summed in float64 whatever J's dtype
    assert float((i32 - i64).abs().max() / i64.abs().max()) < 1e-5


def test_extremes_stay_finite():
    """sigma at both ends of its range and far beyond, Ps zero: finite derivatives."""
    model, (pd, ps, sigma) = texel_model(brdf="ward")
    for s in (1e-6, 0.01, 0.6, 5.0):
        J = jacobian(model, pd, torch.zeros_like(ps), torch.full_like(sigma, s))
        assert torch.isfinite(J.values).all()
        assert float(J.values[:, 2].abs().max()) == 0.0  # Ps = 0: i does not depend on sigma
