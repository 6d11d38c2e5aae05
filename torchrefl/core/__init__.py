"""Core: the texel Surface, Observations, the BRDF, ray casting, point-light geometry, texel-grid operations.

Imports nothing from the other torchrefl packages: every stage builds on it.
"""

from torchrefl.core.observations import Observations  # noqa: E402
from torchrefl.core.params import TexelParams  # noqa: E402
from torchrefl.core.point_light import PointLight, point_light  # noqa: E402
from torchrefl.core.progress import Stages, bar  # noqa: E402
from torchrefl.core.rays import RayTracer, aimed_rays, raw_embree_rate  # noqa: E402
from torchrefl.core.surface import Surface  # noqa: E402

__all__ = [
    "Observations",
    "PointLight",
    "RayTracer",
    "Stages",
    "Surface",
    "TexelParams",
    "aimed_rays",
    "bar",
    "point_light",
    "raw_embree_rate",
]
