"""Which corner of a hit face a ray reaches, where the face bridges a fold or a crease.

A range mesh cuts a fold's corner with a strip of faces from one side's last texel row to the other side's
first. Each face belongs to texels of both sides (its corners), and the usual choice of corner (the face's
owner for form factors, the largest barycentric weight for photons and gather rays) hands a ray from one
side a texel of its own side, lit like itself. On the object that ray reaches the other side. The rule:
on a mixed face (its corners' normals disagree by more than about 25 degrees, MIXED_COS) keep the usual
corner if its normal faces the ray (n . d < 0), else take, among the corners that face it, the one with
the best score. One rule for the radiosity level's form factors (torchrefl.transport.form_factors) and
the photon level's gather rays (torchrefl.transport.photon_trace.hit_texels). Photon hits do not use it: a photon
density must be collected by the region whose area divides it, the nearest corner's.
"""

from __future__ import annotations

import numpy as np

#: corners whose texel normals' cosine is below this make their face mixed
MIXED_COS = 0.9


def mixed_faces(corner_normals: np.ndarray) -> np.ndarray:
    """(F,) bool: faces two of whose corners' unit normals (F, 3, 3) have a cosine below MIXED_COS."""
    n = np.asarray(corner_normals)
    cos = lambda a, b: np.einsum("fi,fi->f", n[:, a], n[:, b])
    return (cos(0, 1) < MIXED_COS) | (cos(0, 2) < MIXED_COS) | (cos(1, 2) < MIXED_COS)


def facing_corner(
    corner: np.ndarray,
    corner_normals: np.ndarray,
    direction: np.ndarray,
    score: np.ndarray,
    usable: np.ndarray | None = None,
) -> np.ndarray:
    """(n,) corner index (0-2) of each hit on a mixed face: `corner` (n,) where that corner's normal faces the
    ray, else the facing corner with the largest score (n, 3); unchanged where no usable corner faces it.
    corner_normals (n, 3, 3), direction (n, 3) the rays' directions, usable (n, 3) bool (None: all)."""
    facing = np.einsum("ni,nci->nc", np.asarray(direction, dtype=np.float64), corner_normals) < 0
    if usable is not None:
        facing &= usable
    out = np.array(corner, dtype=np.int64, copy=True)
    turn = np.flatnonzero(~facing[np.arange(len(out)), out] & facing.any(1))
    if turn.size:
        out[turn] = np.where(facing[turn], score[turn], -np.inf).argmax(1)
    return out
