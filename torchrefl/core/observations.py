"""Observations: what the camera measured, per light configuration p and texel t.

Everything downstream of the loaders works on Surface + Observations only.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np
import torch

from torchrefl.errors import CaptureError


@dataclass
class Observations:
    """Measured intensities and the light/view geometry of each observation.

    intensity: (P, T, 3) float, linear sensor value as a fraction of the sensor's
        full range (0 = black, 1 = full scale); an 8-bit value v is v / 255, a 16-bit v is v / 65535.
    valid: (P, T) bool, usable for fitting: seen by the camera (n.v > 0), lit (n.l > 0),
        not in a cast shadow, not saturated, finite.
    saturated: (P, T) bool, some channel at or above the saturation level (excluded, counted).
    shadowed: (P, T) bool, the light is blocked by the object itself (cast shadow), at every lit texel whether the
        camera sees it or not (the interreflection levels light their emitters with it).
    light_dir: (P, T, 3) float, unit vector from the texel towards light p.
    falloff: (P, T) float, 1 / C^2 for a point light at distance C, 1 for a directional light.
    light_intensity: (P, 3) float, radiant intensity Y_p (RGB), > 0.
    view_dir: (T, 3) or (P, T, 3) float, unit vector from the texel towards the camera.
    kappa: (3,) float, camera calibration gain: i = kappa * L_o (pi reduces Torrance-Sparrow to eq. 2.9).
    light_positions: (P, 3) float world positions of point lights, or None for directional lights.
    lobe_spread: (P, T, 3) float, over the footprint each observation's value averages: the variance of its
        half-angle offset along and across the offset (radians^2) and the offset's shift (radians) by the specular
        weight's slope (capture.footprint_spread; the fitter's lobe is averaged over it, core.lobe_spread), or
        None: the lobe at the texel centre.
    light_names: one name per light configuration (image file names).
    """

    intensity: torch.Tensor
    valid: torch.Tensor
    saturated: torch.Tensor
    shadowed: torch.Tensor
    light_dir: torch.Tensor
    falloff: torch.Tensor
    light_intensity: torch.Tensor
    view_dir: torch.Tensor
    kappa: torch.Tensor
    light_positions: Optional[torch.Tensor] = None
    lobe_spread: Optional[torch.Tensor] = None
    light_names: list = field(default_factory=list)
    source: str = "<memory>"

    def __post_init__(self) -> None:
        self.validate()

    @property
    def num_lights(self) -> int:
        return int(self.intensity.shape[0])

    @property
    def num_texels(self) -> int:
        return int(self.intensity.shape[1])

    def validate(self) -> None:
        """Raise CaptureError naming the field when shapes or values are inconsistent."""
        P, T = self.num_lights, self.num_texels
        where = f"observations from {self.source}"
        expected = {
            "intensity": (P, T, 3),
            "valid": (P, T),
            "saturated": (P, T),
            "shadowed": (P, T),
            "light_dir": (P, T, 3),
            "falloff": (P, T),
            "light_intensity": (P, 3),
            "kappa": (3,),
        }
        if self.lobe_spread is not None:
            expected["lobe_spread"] = (P, T, 3)
        for name, shape in expected.items():
            got = tuple(getattr(self, name).shape)
            if got != shape:
                raise CaptureError(f"{where}: field '{name}' has shape {got}, expected {shape}")
        if tuple(self.view_dir.shape) not in ((T, 3), (P, T, 3)):
            raise CaptureError(
                f"{where}: field 'view_dir' has shape {tuple(self.view_dir.shape)}, expected ({T}, 3) or ({P}, {T}, 3)"
            )
        li = self.light_intensity
        if not torch.isfinite(li).all() or (li <= 0).any():
            rows = sorted(set(torch.nonzero(~torch.isfinite(li) | (li <= 0))[:, 0].tolist()))
            raise CaptureError(f"{where}: field 'light_intensity' must be finite and > 0; bad light rows {rows[:10]}")
        if self.light_names and len(self.light_names) != P:
            raise CaptureError(f"{where}: {len(self.light_names)} light names for {P} lights")

    def view_dirs_full(self) -> torch.Tensor:
        """(P, T, 3) view directions (broadcast when the camera is shared by all lights)."""
        if self.view_dir.dim() == 2:
            return self.view_dir.unsqueeze(0).expand(self.num_lights, -1, -1)
        return self.view_dir

    def subset_lights(self, keep) -> "Observations":
        """Observations restricted to the light indices in `keep` (a list or bool mask)."""
        idx = torch.as_tensor(
            np.flatnonzero(np.asarray(keep)) if np.asarray(keep).dtype == bool else np.asarray(keep), dtype=torch.long
        )
        vd = self.view_dir if self.view_dir.dim() == 2 else self.view_dir[idx]
        return Observations(
            intensity=self.intensity[idx],
            valid=self.valid[idx],
            saturated=self.saturated[idx],
            shadowed=self.shadowed[idx],
            light_dir=self.light_dir[idx],
            falloff=self.falloff[idx],
            light_intensity=self.light_intensity[idx],
            view_dir=vd,
            kappa=self.kappa,
            light_positions=None if self.light_positions is None else self.light_positions[idx],
            lobe_spread=None if self.lobe_spread is None else self.lobe_spread[idx],
            light_names=[self.light_names[i] for i in idx.tolist()] if self.light_names else [],
            source=self.source,
        )

    def to(self, dtype: torch.dtype) -> "Observations":
        """A copy with float tensors in `dtype`."""
        f = lambda x: None if x is None else x.to(dtype)
        return Observations(
            intensity=f(self.intensity),
            valid=self.valid,
            saturated=self.saturated,
            shadowed=self.shadowed,
            light_dir=f(self.light_dir),
            falloff=f(self.falloff),
            light_intensity=f(self.light_intensity),
            view_dir=f(self.view_dir),
            kappa=f(self.kappa),
            light_positions=f(self.light_positions),
            lobe_spread=f(self.lobe_spread),
            light_names=list(self.light_names),
            source=self.source,
        )
