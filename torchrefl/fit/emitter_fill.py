"""What texels without a fitted observation reflect when they light the rest of the object.

Silhouette texels (geometry.edge_width), crease texels (geometry.crease_angle_deg) and texels no light
reaches are not fitted, so their parameters are whatever the start gave them (Pd 0). The interreflection
levels need them anyway: they are real surface that the fitted texels see. Left black, they take their
share of the interreflected light with them, and the fitted texels that see them come out too bright
(Object E at full size: 5 % of the texels, mostly the plates' rims; Method II's lower plate far from the
fold came out +0.37 % black, +0.19 % filled).

`nearest_fitted` maps every texel to the nearest fitted texel in 3-D (itself when fitted), so an
emitter's parameters are an index away from the fitted tensors: differentiable, and tied to the texel
whose observations determine them.
"""

from __future__ import annotations

import numpy as np
import torch
from scipy.spatial import cKDTree


def nearest_fitted(positions: torch.Tensor, fitted: torch.Tensor) -> torch.Tensor:
    """(T,) long: for each texel the index of the nearest texel (Euclidean, in 3-D) where `fitted` (T,) is
    True, the texel itself where it is. With no fitted texel at all every texel maps to itself."""
    fitted = fitted.detach().cpu().bool()
    if positions.shape[0] != fitted.shape[0]:
        raise ValueError(f"nearest_fitted: {positions.shape[0]} positions but {fitted.shape[0]} fitted flags")
    T = fitted.shape[0]
    index = torch.arange(T)
    if fitted.all() or not fitted.any():
        return index
    pos = positions.detach().cpu().double().numpy()
    src = np.flatnonzero(fitted.numpy())
    todo = np.flatnonzero(~fitted.numpy())
    _, nearest = cKDTree(pos[src]).query(pos[todo])
    index[torch.from_numpy(todo)] = torch.from_numpy(src[nearest])
    return index
