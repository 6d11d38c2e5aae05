"""Method I: direct light with cast shadows (torchrefl.transport.local)."""

from __future__ import annotations

from typing import Optional

import torch

from torchrefl.transport.levels.base import LevelInputs, TransportLevel
from torchrefl.transport.texel_model import TexelModel

#: texels rendered at once by LocalLevel.render
RENDER_TEXELS = 1 << 16


class LocalLevel(TransportLevel):
    name = "local"

    def __init__(self, inputs: LevelInputs, reason: str = "fit.model is 'local': direct light with cast shadows"):
        super().__init__(inputs)
        self._reason = reason
        self._predict = inputs.local_predict()

    @property
    def reason(self) -> str:
        return self._reason

    def predict(self, pd, ps, sigma):
        return self._predict(pd, ps, sigma)

    def render(self, pd, ps, sigma):
        """predict, RENDER_TEXELS texels at a time into one (P, T, 3) tensor (the temporaries a block's)."""
        T = pd.shape[0]
        out = None
        for a in range(0, T, RENDER_TEXELS):
            index = torch.arange(a, min(T, a + RENDER_TEXELS), device=pd.device)
            part = self.inputs.local_predict(index)(pd[index], ps[index], sigma[index])
            if out is None:
                out = part.new_empty(part.shape[0], T, part.shape[2])
            out[:, a : a + len(index)] = part
        return out

    def texel_model(self, pd: torch.Tensor, texels: Optional[torch.Tensor] = None) -> TexelModel:
        """predict, which is the local model: of the texels (n,) long only where given."""
        return TexelModel(self.inputs.local_terms(texels))
