"""Method I: direct light with cast shadows (torchrefl.transport.local)."""

from __future__ import annotations

from torchrefl.transport.levels.base import LevelInputs, TransportLevel


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
