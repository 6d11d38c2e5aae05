"""`auto`: the cheapest transport level that explains the data (docs/methods.md, "auto").

Rules, in order, each with the numbers behind it:
1. the capture has no depth (no mesh) or no texel sees another (no form factor above zero)
   -> local;
2. the predicted diffuse interreflection, kappa Pd / pi * H at the initial Pd, stays below the
   noise floor (its 99.9th percentile over fitted observations, in 8-bit DN) -> local;
3. the predicted specular interreflection (the same gather of the light the patches reflect
   specularly, estimated from their Ps with a directional albedo of Ps) stays below the noise
   floor -> radiosity; otherwise photon (with photon_available=False, for callers that cannot run
   the photon level, radiosity with the reason saying so).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from torchrefl.transport.radiosity import nonzeros, row_sums
from torchrefl.transport.radiosity_level import reflected_indirect


@dataclass
class LevelChoice:
    level: str
    reason: str
    numbers: dict


def choose_level(
    has_mesh: bool,
    F,
    indirect_dn: torch.Tensor | None,
    specular_dn: torch.Tensor | None,
    noise_floor_dn: float,
    photon_available: bool = True,
) -> LevelChoice:
    """Apply the rules to precomputed quantities.

    F: form factors (Q, Q) or None; indirect_dn / specular_dn: predicted diffuse / specular
    interreflection of the fitted observations in 8-bit DN (1-D tensors) or None.
    """
    numbers: dict = {"noise_floor_dn": noise_floor_dn}
    if not has_mesh:
        return LevelChoice("local", "no depth in the capture: interreflection cannot be modelled", numbers)
    nnz = nonzeros(F)
    rows = row_sums(F).double()
    numbers.update(form_factor_nonzeros=nnz, max_form_factor_row_sum=float(rows.max()) if rows.numel() else 0.0)
    if nnz == 0:
        return LevelChoice("local", "no texel sees another (all form factors are zero)", numbers)
    q = lambda x: float(torch.quantile(x.double().flatten()[:10_000_000], 0.999)) if x.numel() else 0.0
    diff = q(indirect_dn)
    numbers["diffuse_interreflection_dn_p999"] = diff
    if diff < noise_floor_dn:
        return LevelChoice(
            "local",
            f"predicted diffuse interreflection {diff:.3g} DN (99.9th percentile) is below the "
            f"noise floor {noise_floor_dn} DN",
            numbers,
        )
    spec = q(specular_dn)
    numbers["specular_interreflection_dn_p999"] = spec
    if spec < noise_floor_dn:
        return LevelChoice(
            "radiosity",
            f"diffuse interreflection up to {diff:.3g} DN, specular interreflection "
            f"{spec:.3g} DN is below the noise floor {noise_floor_dn} DN",
            numbers,
        )
    if photon_available:
        return LevelChoice("photon", f"specular interreflection up to {spec:.3g} DN exceeds the noise floor", numbers)
    return LevelChoice(
        "radiosity",
        f"specular interreflection up to {spec:.3g} DN exceeds the noise floor "
        f"{noise_floor_dn} DN and calls for the photon level, which is not "
        "available here: falling back to radiosity",
        numbers,
    )


def specular_albedo_estimate(ps: torch.Tensor) -> torch.Tensor:
    """(T, C) fraction of incident light a texel reflects specularly, estimated as Ps (the lobe's
    directional albedo is about Ps for the normalised lobes; an upper estimate for the others)."""
    return ps.clamp_min(0.0)


def predicted_interreflection_dn(terms, kappa, pd, ps, indirect_fn, fit_mask) -> tuple[torch.Tensor, torch.Tensor]:
    """(diffuse, specular) interreflection of the fitted observations in 8-bit DN.

    diffuse: kappa Pd / pi * H(Pd); specular: the same gather with the patches emitting their
    specularly reflected direct light (reflectance replaced by the specular albedo estimate).
    """
    with torch.no_grad():
        H = indirect_fn(pd)
        diffuse = reflected_indirect(kappa, pd, H) * 255.0
        Hs = indirect_fn(specular_albedo_estimate(ps).expand_as(pd).contiguous())
        specular = reflected_indirect(kappa, pd, Hs) * 255.0
    m = fit_mask[..., None].expand_as(diffuse)
    return diffuse[m], specular[m]
