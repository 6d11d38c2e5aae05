"""Cameras, point lights and their pairing for synthetic mesh_views scenes, in the capture format's conventions.

Cameras are pinhole cameras in the OpenCV convention: X_cam = R X_world + t, +z forward, y down,
pixel (u, v) = (fx x / z + cx, fy y / z + cy), the centre of the top-left pixel at (0, 0); no distortion.
They stand on rings about the object's centre (one ring per elevation, staggered in azimuth) and look at it.
Lights are point lights in the world frame at [azimuth, elevation] about the centre (azimuth from +z towards
+x, world y up). Each camera is paired with the lights_per_view lights closest to it in direction from the centre, so
that several lights light each view and (with more cameras than lights) each light several views.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from torchrefl.errors import ConfigError, GeometryError


@dataclass
class ViewCamera:
    """A pinhole camera: name, image width and height (px), focal lengths fx, fy and principal point cx, cy
    (px), world-to-camera rotation R (3, 3) and translation t (3,) (module doc)."""

    name: str
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    R: np.ndarray
    t: np.ndarray

    @property
    def centre(self) -> np.ndarray:
        """(3,) the camera centre in the world frame, -R^T t."""
        return -self.R.T @ self.t

    def rays(self, supersample: int, pixels: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Camera rays through supersample^2 stratified sub-pixel points of each pixel (a regular grid at the
        centres of the pixel's strata): origins (N, 3), unit directions (N, 3), pixel (N,) the flat pixel index
        row * width + col, each pixel's rays contiguous. pixels: flat indices to trace (None: all, row-major)."""
        k = int(supersample)
        offs = (np.arange(k) + 0.5) / k - 0.5
        du, dv = (a.ravel() for a in np.meshgrid(offs, offs))
        pix = np.arange(self.width * self.height) if pixels is None else np.asarray(pixels, dtype=np.int64)
        pixel = np.repeat(pix, k * k)
        u = (pixel % self.width) + np.tile(du, len(pix))
        v = (pixel // self.width) + np.tile(dv, len(pix))
        d_cam = np.stack([(u - self.cx) / self.fx, (v - self.cy) / self.fy, np.ones_like(u)], -1)
        d = d_cam @ self.R  # R^T d_cam, row-wise
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        return np.broadcast_to(self.centre, d.shape).copy(), d, pixel

    def to_json(self) -> dict:
        """The camera's entry in cameras.json (keyed by its name there; no distortion)."""
        return {
            "width": int(self.width),
            "height": int(self.height),
            "fx": float(self.fx),
            "fy": float(self.fy),
            "cx": float(self.cx),
            "cy": float(self.cy),
            "k1": 0.0,
            "k2": 0.0,
            "p1": 0.0,
            "p2": 0.0,
            "k3": 0.0,
            "R": [[float(x) for x in row] for row in self.R],
            "t": [float(x) for x in self.t],
        }


@dataclass
class ViewLight:
    """A point light: name, world position (3,) mm, RGB radiant intensity (3,) (full range x mm^2 per kappa)."""

    name: str
    position: np.ndarray
    intensity: np.ndarray

    def to_json(self) -> dict:
        """The light's entry in lights.json (keyed by its name there)."""
        return {
            "position": [float(x) for x in self.position],
            "intensity": [float(x) for x in self.intensity],
        }


@dataclass
class ViewImage:
    """One photograph: its file (relative to the folder), camera and light names, exposure factor."""

    file: str
    camera: str
    light: str
    exposure: float

    def to_json(self) -> dict:
        return {"file": self.file, "camera": self.camera, "light": self.light, "exposure": float(self.exposure)}


def direction(azimuth_deg: float, elevation_deg: float) -> np.ndarray:
    """(3,) unit vector at an azimuth (from +z towards +x) and an elevation (towards +y), degrees."""
    a, e = np.radians(azimuth_deg), np.radians(elevation_deg)
    return np.array([np.cos(e) * np.sin(a), np.sin(e), np.cos(e) * np.cos(a)])


def look_at(name: str, position, target, width: int, height: int, focal_px: float, up=(0.0, 1.0, 0.0)) -> ViewCamera:
    """A camera at `position` looking at `target` with the world's `up` pointing up in the image (y down), the
    principal point at the image centre ((width - 1) / 2, (height - 1) / 2)."""
    position, target, up = (np.asarray(x, dtype=np.float64) for x in (position, target, up))
    z = target - position
    x = np.cross(z, up)
    if np.linalg.norm(z) == 0 or np.linalg.norm(x) < 1e-9 * np.linalg.norm(z):
        raise GeometryError(f"camera {name}: looks along the up direction (or at itself): no image orientation")
    z /= np.linalg.norm(z)
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z])
    return ViewCamera(name, width, height, focal_px, focal_px, (width - 1) / 2.0, (height - 1) / 2.0, R, -R @ position)


def ring_cameras(
    target, distance: float, elevations_deg, per_ring: int, width: int, height: int, focal_px: float
) -> list[ViewCamera]:
    """per_ring cameras on a ring at each elevation about `target`, evenly spaced in azimuth, ring r turned by
    r / (rings) of the spacing; named cam00, cam01, ..."""
    if per_ring < 1 or not len(elevations_deg):
        raise ConfigError(f"cameras: {per_ring} per ring on {len(elevations_deg)} rings, expected at least one")
    cams = []
    for r, elev in enumerate(elevations_deg):
        for k in range(per_ring):
            az = 360.0 * (k + r / len(elevations_deg)) / per_ring
            pos = np.asarray(target) + distance * direction(az, elev)
            cams.append(look_at(f"cam{len(cams):02d}", pos, target, width, height, focal_px))
    return cams


def pair_images(
    cameras: list[ViewCamera], lights: list[ViewLight], per_view: int, exposures, target
) -> list[ViewImage]:
    """Each camera with the per_view lights closest to it in direction from `target` (the lit side faces the
    camera), in order of closeness; exposures cycled over the images in order."""
    if not 1 <= per_view <= len(lights):
        raise ConfigError(f"lights_per_view is {per_view}, expected 1..{len(lights)} (the number of lights)")
    if not len(exposures) or min(exposures) <= 0:
        raise ConfigError(f"exposures {list(exposures)}: expected a non-empty list of positive factors")
    unit = lambda x: (x - target) / np.linalg.norm(x - target)  # noqa: E731
    towards = np.stack([unit(light.position) for light in lights])
    images = []
    for cam in cameras:
        for j in np.argsort(-(towards @ unit(cam.centre)), kind="stable")[:per_view]:
            exposure = float(exposures[len(images) % len(exposures)])
            light = lights[j]
            images.append(ViewImage(f"images/{cam.name}_{light.name}.png", cam.name, light.name, exposure))
    return images
