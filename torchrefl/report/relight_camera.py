"""Cameras of a relit image: a calibrated pinhole (capture.cameras.Cameras, OpenCV convention) or an orthographic
camera, their pixel rays, and the named presets (an orbit about the object, a turntable).

Pinhole: X_cam = R X_world + t, +z forward, y down, pixel (u, v) = (fx x / z + cx, fy y / z + cy) (after OpenCV's
distortion, undone here by kornia's undistort_points), the centre of the top-left pixel at (0, 0). Orthographic:
the same frame, pixel (u, v) = (x / pixel_size + cx, y / pixel_size + cy), rays along +z from the plane z = 0 of
the camera frame. Presets look at a target with the world's +y up in the image (azimuth from +z towards +x,
elevation towards +y: synthetic.views_layout.direction, the mesh_views scenes' convention).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from torchrefl.capture.cameras import Cameras
from torchrefl.errors import CaptureError
from torchrefl.synthetic.views_layout import direction, look_at

#: the fixed-point iterations of kornia's undistort_points (sub-micropixel for the distortions cameras have)
UNDISTORT_ITERATIONS = 20
#: an orbit preset's image: the object's bounding sphere spans this fraction of the shorter image side
ORBIT_FILL = 0.8


@dataclass(frozen=True)
class OrthographicCamera:
    """An orthographic camera: world-to-camera rotation R (3, 3) (orthonormal, det +1) and translation t (3,);
    width, height (px); pixel_size: world units per pixel (> 0); cx, cy: the pixel on the optical axis."""

    R: np.ndarray
    t: np.ndarray
    width: int
    height: int
    pixel_size: float
    cx: float
    cy: float

    def __post_init__(self) -> None:
        if not (np.isfinite(self.pixel_size) and self.pixel_size > 0):
            raise CaptureError(f"orthographic camera: pixel_size = {self.pixel_size!r}, expected > 0 (units per pixel)")
        as_pinhole(self)  # the pinhole checks: an orthonormal R with det +1, a size > 0


def as_pinhole(cam: OrthographicCamera) -> Cameras:
    """A one-camera Cameras with cam's pose, size and (1 / pixel_size) as its focal length: the shared checks
    (capture.cameras.Cameras.validate) name a non-orthonormal R or a non-positive size."""
    f = 1.0 / cam.pixel_size
    return Cameras.from_arrays(
        ["orthographic"],
        [cam.width],
        [cam.height],
        [f],
        [f],
        [cam.cx],
        [cam.cy],
        np.zeros((1, 5)),
        cam.R,
        cam.t,
        source="orthographic camera",
    )


def pixel_grid(width: int, height: int, supersample: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sub-pixel sample positions: u, v (N,) at the centres of supersample^2 strata of each pixel, and their flat
    pixel index (N,) row * width + col, each pixel's samples contiguous, pixels row-major."""
    k = int(supersample)
    offs = (np.arange(k) + 0.5) / k - 0.5
    du, dv = (a.ravel() for a in np.meshgrid(offs, offs))
    pixel = np.repeat(np.arange(width * height), k * k)
    return (pixel % width) + np.tile(du, width * height), (pixel // width) + np.tile(dv, width * height), pixel


def camera_rays(camera, index: int = 0, supersample: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(origins (N, 3), unit directions (N, 3), pixel (N,)) of camera (Cameras: camera `index`; or an
    OrthographicCamera), supersample^2 rays per pixel (pixel_grid)."""
    if isinstance(camera, OrthographicCamera):
        u, v, pixel = pixel_grid(camera.width, camera.height, supersample)
        local = np.stack([(u - camera.cx) * camera.pixel_size, (v - camera.cy) * camera.pixel_size, 0 * u], -1)
        origins = (local - camera.t) @ camera.R  # R^T (X_cam - t), row-wise
        d = np.broadcast_to(camera.R[2], origins.shape).copy()
        return origins, d, pixel
    if not isinstance(camera, Cameras):
        raise CaptureError(
            f"render camera: got {type(camera).__name__}, expected a capture.cameras.Cameras (pinhole, OpenCV) or "
            "an OrthographicCamera"
        )
    W, H = int(camera.width[index]), int(camera.height[index])
    u, v, pixel = pixel_grid(W, H, supersample)
    K = camera.K[index].numpy()
    dist = camera.distortion[index]
    if bool((dist != 0).any()):
        from kornia.geometry.calibration import undistort_points

        pts = torch.from_numpy(np.stack([u, v], -1))[None]
        xy = undistort_points(
            pts, camera.K[index][None], dist[None], torch.eye(3, dtype=torch.float64)[None], UNDISTORT_ITERATIONS
        )[0].numpy()
    else:
        xy = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1]], -1)
    d_cam = np.concatenate([xy, np.ones((len(xy), 1))], -1)
    R = camera.R[index].numpy()
    d = d_cam @ R  # R^T d_cam, row-wise
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    centre = camera.centres()[index].numpy()
    return np.broadcast_to(centre, d.shape).copy(), d, pixel


def image_size(camera, index: int = 0) -> tuple[int, int]:
    """(height, width) of the camera's image."""
    if isinstance(camera, OrthographicCamera):
        return camera.height, camera.width
    return int(camera.height[index]), int(camera.width[index])


def orbit_camera(
    target,
    radius: float,
    azimuth_deg: float,
    elevation_deg: float,
    distance: float,
    width: int = 512,
    height: int = 512,
    name: str = "orbit",
) -> Cameras:
    """A pinhole camera `distance` from target (3,) at an azimuth and elevation (degrees; module doc) looking at
    it, its focal length chosen so that a sphere of `radius` about the target fills ORBIT_FILL of the shorter
    image side. CaptureError for a distance inside that sphere or an elevation of +-90 degrees (no up)."""
    if not distance > radius:
        raise CaptureError(
            f"camera preset orbit: distance {distance:g} lies inside the object's bounding sphere (radius "
            f"{radius:.4g}), expected a distance > {radius:.4g}"
        )
    if not abs(elevation_deg) < 90.0:
        raise CaptureError(f"camera preset orbit: elevation {elevation_deg:g} deg, expected within (-90, 90)")
    half = np.arcsin(radius / distance)  # the sphere's angular radius
    focal = ORBIT_FILL * min(width, height) / 2.0 / np.tan(half)
    position = np.asarray(target, dtype=np.float64) + distance * direction(azimuth_deg, elevation_deg)
    cam = look_at(name, position, target, int(width), int(height), float(focal))
    return Cameras.from_arrays(
        [name],
        [cam.width],
        [cam.height],
        [cam.fx],
        [cam.fy],
        [cam.cx],
        [cam.cy],
        np.zeros((1, 5)),
        cam.R,
        cam.t,
        source=f"camera preset orbit {azimuth_deg:g} {elevation_deg:g} {distance:g}",
    )


def turned(camera, index: int, centre, angle_deg: float):
    """camera (Cameras: camera `index`, or OrthographicCamera) moved as if the object turned by angle_deg about the
    vertical (+y) axis through centre (3,): the camera turns by -angle_deg about it."""
    Ry = _turn(angle_deg)
    c = np.asarray(centre, dtype=np.float64)
    if isinstance(camera, OrthographicCamera):
        R = camera.R @ Ry.T
        t = camera.t + camera.R @ c - R @ c
        return OrthographicCamera(R, t, camera.width, camera.height, camera.pixel_size, camera.cx, camera.cy)
    R0, t0 = camera.R[index].numpy(), camera.t[index].numpy()
    # X_cam = R0 (Ry^T (X - c) + c) + t0
    R = R0 @ Ry.T
    return one_camera(camera, index, R, t0 + R0 @ c - R @ c)


def one_camera(cameras: Cameras, index: int, R=None, t=None) -> Cameras:
    """Camera `index` of cameras as a one-camera Cameras, with the pose R (3, 3), t (3,) when given."""
    one = lambda x: x[index : index + 1].numpy()
    return Cameras.from_arrays(
        [cameras.names[index]],
        one(cameras.width),
        one(cameras.height),
        one(cameras.fx),
        one(cameras.fy),
        one(cameras.cx),
        one(cameras.cy),
        one(cameras.distortion),
        one(cameras.R) if R is None else np.asarray(R)[None],
        one(cameras.t) if t is None else np.asarray(t)[None],
        source=cameras.source,
    )


def turn_point(point, centre, angle_deg: float) -> np.ndarray:
    """point (3,) turned by -angle_deg about the vertical axis through centre (the turntable's light)."""
    c = np.asarray(centre, dtype=np.float64)
    return c + _turn(angle_deg) @ (np.asarray(point, dtype=np.float64) - c)


def _turn(angle_deg: float) -> np.ndarray:
    """(3, 3) the rotation by -angle_deg about +y (a point of the world seen from an object turned by angle_deg)."""
    a = np.radians(-angle_deg)
    return np.array([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]])
