"""Calibrated perspective cameras in the OpenCV convention, and the projection of world points into them.

A camera maps a world point X to its camera frame by X_cam = R X + t (world-to-camera; +x right, +y down,
+z forward), to the normalised image plane by (x', y') = (x / z, y / z), through OpenCV's
radial-tangential distortion (k1, k2, p1, p2, k3) to (x'', y''), and to pixels by u = fx x'' + cx,
v = fy y'' + cy, with the centre of the top-left pixel at (0, 0). The distortion is OpenCV's (the same as
kornia's distort_points, written out for speed). Lengths are in the capture's world unit (mm unless it says
otherwise).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import torch

from torchrefl.errors import CaptureError

#: OpenCV's distortion coefficients in the order of Cameras.distortion
DISTORTION = ("k1", "k2", "p1", "p2", "k3")
#: largest |R^T R - I| element accepted for a rotation (6 written decimals are well inside); R is then
#: replaced by the nearest rotation
ORTHONORMAL_TOLERANCE = 1e-4
#: camera x point pairs projected at once (4 or 8 MB per temporary)
CHUNK_PAIRS = 1 << 20


@dataclass(frozen=True)
class Projection:
    """World points seen by cameras.

    uv: (..., P, 2) pixel coordinates (u right, v down; the centre of the top-left pixel at (0, 0)), NaN where
        the point is not in front of the camera (depth <= 0) or lies beyond the radius where the camera's
        distortion folds back (Cameras.max_radius2).
    depth: (..., P) z of the point in the camera frame (world unit), along the optical axis.
    """

    uv: torch.Tensor
    depth: torch.Tensor


@dataclass
class Cameras:
    """N calibrated cameras (float64 tensors).

    names: N distinct names (cameras.json's keys; for a COLMAP model, the images' names).
    width, height: (N,) int64 image size in pixels.
    K: (N, 3, 3) intrinsic matrices [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], pixels.
    distortion: (N, 5) OpenCV coefficients k1, k2, p1, p2, k3 (zeros: no distortion).
    R: (N, 3, 3) world-to-camera rotations (replaced by the nearest rotation, see ORTHONORMAL_TOLERANCE).
    t: (N, 3) world-to-camera translations, world unit: X_cam = R X + t.
    source: the file or folder the cameras came from (named in errors).
    """

    names: tuple[str, ...]
    width: torch.Tensor
    height: torch.Tensor
    K: torch.Tensor
    distortion: torch.Tensor
    R: torch.Tensor
    t: torch.Tensor
    source: str = "<memory>"

    def __post_init__(self) -> None:
        self.validate()
        u, _, vh = torch.linalg.svd(self.R)
        self.R = u @ vh

    @classmethod
    def from_arrays(cls, names, width, height, fx, fy, cx, cy, distortion, R, t, source: str) -> "Cameras":
        """Cameras from per-camera sequences / arrays: width, height, fx, fy, cx, cy (N,), distortion (N, 5),
        R (N, 3, 3), t (N, 3)."""
        f64 = lambda x: torch.as_tensor(np.asarray(x, dtype=np.float64))
        n = len(names)
        K = torch.zeros(n, 3, 3, dtype=torch.float64)
        K[:, 0, 0], K[:, 1, 1], K[:, 0, 2], K[:, 1, 2], K[:, 2, 2] = f64(fx), f64(fy), f64(cx), f64(cy), 1.0
        return cls(
            names=tuple(names),
            width=torch.as_tensor(np.asarray(width, dtype=np.int64)),
            height=torch.as_tensor(np.asarray(height, dtype=np.int64)),
            K=K,
            distortion=f64(distortion).reshape(n, len(DISTORTION)),
            R=f64(R).reshape(n, 3, 3),
            t=f64(t).reshape(n, 3),
            source=source,
        )

    def __len__(self) -> int:
        return len(self.names)

    @property
    def fx(self) -> torch.Tensor:
        return self.K[:, 0, 0]

    @property
    def fy(self) -> torch.Tensor:
        return self.K[:, 1, 1]

    @property
    def cx(self) -> torch.Tensor:
        return self.K[:, 0, 2]

    @property
    def cy(self) -> torch.Tensor:
        return self.K[:, 1, 2]

    def scaled(self, factor: float) -> "Cameras":
        """The same cameras in a world unit `factor` times smaller (t x factor; e.g. a mesh's unit to mm)."""
        return replace(self, t=self.t * factor)

    def index(self, name: str) -> int:
        """The index of the camera called `name`; KeyError when there is none."""
        return self.names.index(name)

    def validate(self) -> None:
        """CaptureError naming the source and the camera for a size, focal length or rotation that cannot be a
        camera's, or a repeated name."""
        n = len(self.names)
        shapes = {"width": (n,), "height": (n,), "K": (n, 3, 3), "distortion": (n, 5), "R": (n, 3, 3), "t": (n, 3)}
        for field, shape in shapes.items():
            if tuple(getattr(self, field).shape) != shape:
                raise CaptureError(
                    f"{self.source}: camera field '{field}' has shape {tuple(getattr(self, field).shape)}, "
                    f"expected {shape}"
                )
        seen = set()
        for name in self.names:
            if name in seen:
                raise CaptureError(f"{self.source}: camera name '{name}' used twice (each camera needs its own name)")
            seen.add(name)
        for field in ("K", "distortion", "R", "t"):
            bad = ~torch.isfinite(getattr(self, field)).reshape(n, -1).all(dim=1)
            if bad.any():
                name = self.names[int(bad.nonzero()[0])]
                raise CaptureError(f"{self.source}: camera '{name}': {field} is not finite")
        self._check_values()

    def _check_values(self) -> None:
        for i, name in enumerate(self.names):
            where = f"{self.source}: camera '{name}'"
            if self.width[i] < 1 or self.height[i] < 1:
                raise CaptureError(f"{where}: size {int(self.width[i])}x{int(self.height[i])}, expected positive")
            structure = self.K[i].clone()
            structure[0, 0] = structure[1, 1] = structure[0, 2] = structure[1, 2] = 0.0
            if not torch.equal(structure, torch.tensor([[0.0, 0, 0], [0, 0, 0], [0, 0, 1]], dtype=structure.dtype)):
                raise CaptureError(
                    f"{where}: K is {self.K[i].tolist()}, expected [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]"
                )
            if self.K[i, 0, 0] <= 0 or self.K[i, 1, 1] <= 0:
                raise CaptureError(
                    f"{where}: focal length fx = {float(self.K[i, 0, 0])!r}, fy = {float(self.K[i, 1, 1])!r} px, "
                    "expected > 0"
                )
            r = self.R[i]
            error = float((r.T @ r - torch.eye(3, dtype=r.dtype)).abs().max())
            if error > ORTHONORMAL_TOLERANCE:
                raise CaptureError(
                    f"{where}: R is not orthonormal (largest |R^T R - I| element {error:.3g}, tolerance "
                    f"{ORTHONORMAL_TOLERANCE:g}); R must be the world-to-camera rotation"
                )
            if float(torch.linalg.det(r)) < 0:
                raise CaptureError(f"{where}: R has determinant -1, a reflection; expected a rotation (det +1)")

    def max_radius2(self) -> torch.Tensor:
        """(N,) the squared normalised radius r^2 = x'^2 + y'^2 up to which the radial distortion
        r (1 + k1 r^2 + k2 r^4 + k3 r^6) still grows with r (inf when it always does). Beyond it the model
        folds back, so a point far outside the field of view could land inside the image: project leaves it out."""
        out = torch.full((len(self),), torch.inf, dtype=torch.float64)
        for i, (k1, k2, _, _, k3) in enumerate(self.distortion.tolist()):
            # d/dr of r (1 + k1 s + k2 s^2 + k3 s^3), s = r^2: 1 + 3 k1 s + 5 k2 s^2 + 7 k3 s^3
            roots = np.roots(np.trim_zeros([7.0 * k3, 5.0 * k2, 3.0 * k1, 1.0], "f"))
            real = [r.real for r in roots if abs(r.imag) < 1e-12 and r.real > 0]
            if real:
                out[i] = min(real)
        return out

    def centres(self) -> torch.Tensor:
        """(N, 3) camera centres in the world: -R^T t."""
        return -(self.R.transpose(1, 2) @ self.t[:, :, None])[:, :, 0]

    def project(self, points: torch.Tensor, camera: int | None = None) -> Projection:
        """Project world points (P, 3) into every camera (uv (N, P, 2), depth (N, P)) or into camera index
        `camera` (uv (P, 2), depth (P,)). Computed in the points' floating dtype (float64 for sub-micropixel
        work, float32 for bulk: about 1e-4 px at 2000 px focal lengths), in chunks of CHUNK_PAIRS camera x point
        pairs, on the points' device."""
        points = torch.as_tensor(points)
        if points.ndim != 2 or points.shape[1] != 3:
            raise ValueError(f"points must be (P, 3), got {tuple(points.shape)}")
        if not points.is_floating_point():
            points = points.to(torch.float64)
        idx = torch.arange(len(self)) if camera is None else torch.tensor([camera])
        n, p = len(idx), points.shape[0]
        uv = torch.empty(n, p, 2, dtype=points.dtype, device=points.device)
        depth = torch.empty(n, p, dtype=points.dtype, device=points.device)
        step = max(1, CHUNK_PAIRS // max(n, 1))
        tensors = (self.R, self.t, self.K, self.distortion, self.max_radius2())
        params = [x[idx].to(points.device, points.dtype) for x in tensors]
        for start in range(0, p, step):
            stop = min(start + step, p)
            _project_chunk(points[start:stop], *params, uv[:, start:stop], depth[:, start:stop])
        if camera is not None:
            return Projection(uv=uv[0], depth=depth[0])
        return Projection(uv=uv, depth=depth)

    def in_frame(self, uv: torch.Tensor, camera: int | None = None) -> torch.Tensor:
        """(..., P) bool: pixel coordinates uv from `project` (same `camera` argument) that fall on the image,
        u in [-0.5, width - 0.5], v in [-0.5, height - 0.5] (NaN: False)."""
        idx = slice(None) if camera is None else camera
        w = self.width[idx].to(uv.dtype)
        h = self.height[idx].to(uv.dtype)
        if camera is None:
            w, h = w[:, None], h[:, None]
        u, v = uv[..., 0], uv[..., 1]
        return (u >= -0.5) & (u <= w - 0.5) & (v >= -0.5) & (v <= h - 0.5)


def _project_chunk(points, R, t, K, distortion, max_r2, uv_out, depth_out) -> None:
    """Write the pixels (n, p, 2) and depths (n, p) of points (p, 3) in n cameras into uv_out, depth_out
    (pixels NaN behind the camera or beyond the distortion's turning radius, max_r2 (n,)).

    OpenCV's 5-coefficient model written out with in-place ops on (n, p) rows (the same formula as kornia's
    distort_points, which pads every camera to 14 coefficients and a rational radial term, several times the
    work on the loader's 1e6 x 48 pairs; tests/capture/test_cameras.py checks that the two agree)."""
    n = R.shape[0]
    cam = torch.baddbmm(t[:, :, None], R, points.T.expand(n, 3, -1))  # (n, 3, p): X_cam = R X + t
    z = cam[:, 2]
    x, y = cam[:, 0].div_(z), cam[:, 1].div_(z)
    k1, k2, p1, p2, k3 = (distortion[:, i, None] for i in range(5))
    r2 = (x * x).addcmul_(y, y)
    radial = torch.addcmul(k2, k3, r2).mul_(r2).add_(k1).mul_(r2).add_(1.0)
    xy2 = (x * y).mul_(2.0)
    xd = (x * radial).addcmul_(p1, xy2).addcmul_(p2, torch.addcmul(r2, x, x, value=2.0))
    yd = (y * radial).addcmul_(p2, xy2).addcmul_(p1, torch.addcmul(r2, y, y, value=2.0))
    behind = (z <= 0) | (r2 > max_r2[:, None])
    uv_out[..., 0] = xd.mul_(K[:, 0, 0, None]).add_(K[:, 0, 2, None]).masked_fill_(behind, torch.nan)
    uv_out[..., 1] = yd.mul_(K[:, 1, 1, None]).add_(K[:, 1, 2, None]).masked_fill_(behind, torch.nan)
    depth_out.copy_(z)
