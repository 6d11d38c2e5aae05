"""Local transport: the precomputed fast path against the BRDF evaluated directly; gradchecks."""

import pytest
import torch
from conftest import dome_scene, point_light_observations

from torchrefl.transport.local import local_terms, predict, render_reference


def params(T, C=3, seed=0, dtype=torch.float64):
    g = torch.Generator().manual_seed(seed)
    pd = torch.rand(T, 3, generator=g, dtype=dtype)
    ps = torch.rand(T, C, generator=g, dtype=dtype) * 0.5
    sigma = 0.05 + 0.3 * torch.rand(T, generator=g, dtype=dtype)
    return pd, ps, sigma


@pytest.mark.parametrize("model", ["torrance_sparrow", "ward", "ward_normalised", "lambertian"])
@pytest.mark.parametrize("C", [1, 3])
def test_fast_path_matches_reference(model, C):
    nrm, pos, lights, cam = dome_scene(T=300)
    obs = point_light_observations(nrm, pos, lights, cam)
    obs.shadowed[3, :50] = True  # cast shadows zero the direct term
    pd, ps, sigma = params(300, C)
    n = torch.as_tensor(nrm)
    fast = predict(local_terms(model, n, obs), pd, ps, sigma)
    slow = render_reference(model, n, obs, pd, ps, sigma)
    torch.testing.assert_close(fast, slow, rtol=1e-10, atol=1e-13)
    assert (fast[3, :50] == 0).all()


@pytest.mark.parametrize("k", [0.7, 1.25])
def test_fast_path_matches_reference_with_a_minnaert_diffuse_part(k):
    nrm, pos, lights, cam = dome_scene(T=200)
    obs = point_light_observations(nrm, pos, lights, cam)
    pd, ps, sigma = params(200)
    n = torch.as_tensor(nrm)
    terms = local_terms("torrance_sparrow", n, obs, diffuse_exponent=k)
    assert terms.diffuse_exponent == k
    torch.testing.assert_close(
        predict(terms, pd, ps, sigma),
        render_reference("torrance_sparrow", n, obs, pd, ps, sigma, k),
        rtol=1e-10,
        atol=1e-13,
    )
    lam = predict(local_terms("torrance_sparrow", n, obs), pd, ps * 0, sigma)
    assert not torch.allclose(predict(terms, pd, ps * 0, sigma), lam)


def test_gradcheck_predict():
    nrm, pos, lights, cam = dome_scene(T=4)
    obs = point_light_observations(nrm, pos, lights[::10], cam)
    terms = local_terms("torrance_sparrow", torch.as_tensor(nrm), obs)
    pd, ps, sigma = params(4)
    args = [pd.requires_grad_(), ps.requires_grad_(), sigma.requires_grad_()]
    assert torch.autograd.gradcheck(lambda a, b, c: predict(terms, a, b, c), args)


def test_gradcheck_predict_on_some_texels():
    """LocalTerms.texels (the model of the texels the LM refits still evaluate): float64 gradients, and the values
    are the whole model's rows of those texels."""
    nrm, pos, lights, cam = dome_scene(T=6)
    obs = point_light_observations(nrm, pos, lights[::10], cam)
    terms = local_terms("torrance_sparrow", torch.as_tensor(nrm), obs)
    index = torch.tensor([4, 1])
    pd, ps, sigma = params(6)
    torch.testing.assert_close(
        predict(terms.texels(index), pd[index], ps[index], sigma[index]), predict(terms, pd, ps, sigma)[:, index]
    )
    args = [x[index].clone().requires_grad_() for x in (pd, ps, sigma)]
    assert torch.autograd.gradcheck(lambda a, b, c: predict(terms.texels(index), a, b, c), args)


def test_light_one_millimetre_from_surface_is_finite():
    nrm, pos, lights, cam = dome_scene(T=50)
    near = torch.as_tensor(pos[:1]) + 1.0 * torch.as_tensor(nrm[:1])  # 1 mm above texel 0
    obs = point_light_observations(nrm, pos, near.numpy(), cam)
    pd, ps, sigma = params(50)
    for s in (1e-4, 0.01, 0.6):
        sg = torch.full_like(sigma, s).requires_grad_()
        out = predict(local_terms("torrance_sparrow", torch.as_tensor(nrm), obs), pd, ps, sg)
        assert torch.isfinite(out).all()
        out.sum().backward()
        assert torch.isfinite(sg.grad).all()
