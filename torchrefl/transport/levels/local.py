"""Method I: direct light with cast shadows (torchrefl.transport.local)."""

from __future__ import annotations

from typing import Optional

import torch

from torchrefl.transport.levels.base import LevelInputs, TransportLevel
from torchrefl.transport.texel_model import TexelModel


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

    def texel_model(self, pd: torch.Tensor, texels: Optional[torch.Tensor] = None) -> TexelModel:
        """predict, which is the local model: of the texels (n,) long only where given."""
        return TexelModel(self.inputs.local_terms(texels))
