"""The texel Surface every method works on.

A Surface is a grid of texels (H, W) of which T are valid; only valid texels are
stored. Texels carry a 3-D position, a unit normal and an area; the triangle mesh
that rays are traced against travels with it (None when the capture has no depth,
as in photometric stereo). `neighbours` says which texel is next to which on the surface (core/texel_neighbours.py):
the capture kind hands it over (the scan's grid wrapping on a full turn, a mesh atlas's charts and seams); the
default is the plain grid. `hits` says which texel a point of the mesh belongs to (core/texel_hits.py), for the
interreflection levels' rays: a mesh's atlas hands its uv map over; None is the scan's range mesh (vertex k = grid
point k; transport/range_mesh_hits.py).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np
import torch

from torchrefl.core.texel_grid import TexelGrid
from torchrefl.core.texel_hits import TexelHits
from torchrefl.core.texel_neighbours import TexelNeighbours
from torchrefl.errors import GeometryError

UNIT_TOLERANCE = 1e-3


@dataclass
class Surface:
    """Texel geometry.

    grid_shape: (H, W) of the texel grid (the parameter maps).
    texel_index: (T,) int64, flat index (row * W + col) of each valid texel, increasing.
    positions: (T, 3) float, world frame, millimetres (or the capture's units).
    normals: (T, 3) float, world frame, unit length.
    areas: (T,) float, surface area of each texel (mm^2); ones where unknown.
    mesh_vertices / mesh_faces: the triangle mesh rays are traced against
        ((V, 3) float, (F, 3) int) or None when the capture has no depth.
    units: length unit of positions.
    neighbours: the texels' neighbours on the surface (core/texel_neighbours.py), given by the capture kind;
        None: the plain grid, TexelGrid(texel_index, grid_shape).
    hits: which texel a point of the mesh belongs to (core/texel_hits.py), given by the capture kind; None: the
        range mesh's layout (mesh vertex k is grid point k; transport/range_mesh_hits.RangeMeshHits).
    """

    grid_shape: tuple[int, int]
    texel_index: torch.Tensor
    positions: torch.Tensor
    normals: torch.Tensor
    areas: torch.Tensor
    mesh_vertices: Optional[np.ndarray] = None
    mesh_faces: Optional[np.ndarray] = None
    units: str = "mm"
    source: str = "<memory>"
    extras: dict = field(default_factory=dict)
    neighbours: Optional[TexelNeighbours] = None
    hits: Optional[TexelHits] = None

    def __post_init__(self) -> None:
        self.validate()
        if self.hits is not None and (
            self.hits.num_texels != self.num_texels or not self.has_mesh or self.hits.num_faces != len(self.mesh_faces)
        ):
            raise GeometryError(
                f"surface from {self.source}: field 'hits' covers {self.hits.num_texels} texels and "
                f"{self.hits.num_faces} faces, expected {self.num_texels} texels and the mesh's "
                f"{len(self.mesh_faces) if self.has_mesh else 0} faces"
            )
        if self.neighbours is None:
            self.neighbours = TexelGrid(self.texel_index.cpu().numpy(), self.grid_shape)
        elif self.neighbours.num_texels != self.num_texels or tuple(self.neighbours.grid_shape) != tuple(
            self.grid_shape
        ):
            raise GeometryError(
                f"surface from {self.source}: field 'neighbours' covers {self.neighbours.num_texels} texels on a "
                f"{tuple(self.neighbours.grid_shape)} grid, expected {self.num_texels} on {tuple(self.grid_shape)}"
            )

    @property
    def num_texels(self) -> int:
        return int(self.texel_index.shape[0])

    @property
    def has_mesh(self) -> bool:
        return self.mesh_vertices is not None and self.mesh_faces is not None

    def validate(self) -> None:
        """Raise GeometryError naming the field when the geometry is unusable."""
        H, W = self.grid_shape
        T = self.num_texels
        where = f"surface from {self.source}"
        if T == 0:
            raise GeometryError(f"{where}: the mask selects no texel (expected at least one valid texel)")
        if self.texel_index.min() < 0 or self.texel_index.max() >= H * W:
            raise GeometryError(f"{where}: texel_index out of range for grid {H}x{W}")
        for name, shape in (("positions", (T, 3)), ("normals", (T, 3)), ("areas", (T,))):
            value = getattr(self, name)
            if tuple(value.shape) != shape:
                raise GeometryError(f"{where}: field '{name}' has shape {tuple(value.shape)}, expected {shape}")
            if not torch.isfinite(value).all():
                bad = int((~torch.isfinite(value)).reshape(T, -1).any(dim=1).sum())
                raise GeometryError(f"{where}: field '{name}' has NaN or inf values at {bad} texels")
        lengths = self.normals.norm(dim=-1)
        off = (lengths - 1).abs() > UNIT_TOLERANCE
        if off.any():
            raise GeometryError(
                f"{where}: field 'normals' must be unit vectors; {int(off.sum())} texels have length "
                f"outside 1 +- {UNIT_TOLERANCE} (e.g. {float(lengths[off][0]):.4g})"
            )

    def mask(self) -> np.ndarray:
        """(H, W) bool: True at valid texels."""
        H, W = self.grid_shape
        m = np.zeros(H * W, dtype=bool)
        m[self.texel_index.cpu().numpy()] = True
        return m.reshape(H, W)

    def to_grid(self, values, fill: float = 0.0) -> np.ndarray:
        """Scatter per-texel values (T, ...) into a (H, W, ...) numpy array filled with `fill`."""
        values = values.detach().cpu().numpy() if isinstance(values, torch.Tensor) else np.asarray(values)
        H, W = self.grid_shape
        out = np.full((H * W,) + values.shape[1:], fill, dtype=values.dtype if values.dtype != bool else bool)
        out[self.texel_index.cpu().numpy()] = values
        return out.reshape((H, W) + values.shape[1:])

    def from_grid(self, grid) -> torch.Tensor:
        """Gather a (H, W, ...) grid at the valid texels into (T, ...)."""
        grid = torch.as_tensor(np.asarray(grid))
        H, W = self.grid_shape
        return grid.reshape((H * W,) + tuple(grid.shape[2:]))[self.texel_index.cpu()]

    def to(self, dtype: torch.dtype) -> "Surface":
        """A copy with float tensors in `dtype`."""
        return Surface(
            grid_shape=self.grid_shape,
            texel_index=self.texel_index,
            positions=self.positions.to(dtype),
            normals=self.normals.to(dtype),
            areas=self.areas.to(dtype),
            mesh_vertices=self.mesh_vertices,
            mesh_faces=self.mesh_faces,
            units=self.units,
            source=self.source,
            extras=self.extras,
            neighbours=self.neighbours,
            hits=self.hits,
        )
