"""Transport levels: local (Method I), radiosity (Method II), photon (Method III), behind one TransportLevel
interface."""

from torchrefl.transport.form_factors import form_factors_for_surface  # noqa: E402
from torchrefl.transport.levels.base import LevelInputs, TransportLevel  # noqa: E402
from torchrefl.transport.levels.local import LocalLevel  # noqa: E402
from torchrefl.transport.levels.photon import PhotonLevel  # noqa: E402
from torchrefl.transport.levels.radiosity import RadiosityLevel  # noqa: E402

__all__ = ["LevelInputs", "LocalLevel", "PhotonLevel", "RadiosityLevel", "TransportLevel", "form_factors_for_surface"]
