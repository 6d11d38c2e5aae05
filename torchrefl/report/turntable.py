"""Relit images as files: one PNG, or a turntable (N frames of the object turning under a fixed light, PNGs and an
animated GIF), and the checks of their output paths.

Encodings: `srgb8` (8-bit sRGB, for looking at: report.display.srgb of the values times the exposure, clipped at
full range) or `linear16` (16-bit linear, the photographs' convention: round(65535 v), clipped; compare with a
capture's images). A turntable turns the object by 360 k / N degrees about the vertical (+y) axis through its centre
for frame k (the camera and the light stay where they are: report.relight_camera.turned / turn_point).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from torchrefl.capture.images import write_png
from torchrefl.core.progress import bar
from torchrefl.errors import CaptureError, OutputError
from torchrefl.report.display import srgb
from torchrefl.report.relight import Light, RelightScene, RelitImage, relight
from torchrefl.report.relight_camera import turn_point, turned

ENCODINGS = ("srgb8", "linear16")
FRAME = "frame_{:03d}.png"
GIF = "turntable.gif"
#: the GIF's frame time (s)
GIF_FRAME_S = 0.08


@dataclass
class TurntableFiles:
    """The files of a turntable: frames (N PNGs, in order) and the animated GIF."""

    frames: list[Path]
    gif: Path


def check_output_file(path, overwrite: bool = False) -> Path:
    """An image's output path: OutputError naming it when it is not a .png, is a folder, its folder is missing or
    not a folder, or it exists and overwrite is False."""
    path = Path(path)
    if path.is_dir():
        raise OutputError(f"--out {path}: is a folder; expected an image file (.png) to write")
    if path.suffix.lower() != ".png":
        raise OutputError(f"--out {path}: expected a .png file (without --turntable)")
    if not path.parent.is_dir():
        raise OutputError(f"--out {path}: its folder {path.parent} does not exist (or is not a folder)")
    if path.exists() and not overwrite:
        raise OutputError(f"--out {path}: exists; pass --overwrite to replace it")
    return path


def check_output_folder(path, overwrite: bool = False) -> Path:
    """A turntable's output folder: OutputError naming it when it is a file, its parent is missing, or it holds a
    turntable already and overwrite is False (it is made when absent)."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise OutputError(f"--out {path}: is a file; a turntable is written into a folder (frames and {GIF})")
    if not path.parent.is_dir():
        raise OutputError(f"--out {path}: its parent folder {path.parent} does not exist (or is not a folder)")
    if (path / GIF).exists() and not overwrite:
        raise OutputError(f"--out {path}: holds a turntable already; pass --overwrite to replace it")
    return path


def encoded(image: np.ndarray, encoding: str = "srgb8", exposure: float = 1.0) -> np.ndarray:
    """(H, W, 3) uint8 (srgb8) or uint16 (linear16) of relit values (H, W, 3) times exposure (module doc)."""
    v = np.clip(np.asarray(image, dtype=np.float64) * exposure, 0.0, 1.0)
    if encoding == "srgb8":
        return np.rint(srgb(v) * 255).astype(np.uint8)
    if encoding == "linear16":
        return np.rint(v * 65535).astype(np.uint16)
    raise OutputError(f"--encoding {encoding!r}: expected one of {', '.join(ENCODINGS)}")


def write_image(path, image: np.ndarray, encoding: str = "srgb8", exposure: float = 1.0) -> Path:
    """Write relit values (H, W, 3) as a PNG (module doc)."""
    write_png(path, encoded(image, encoding, exposure), 8 if encoding == "srgb8" else 16)
    return Path(path)


def turntable(
    run, camera, light: Light, frames: int, scene: RelightScene, *, progress: bool = False, **options
) -> list[RelitImage]:
    """N = frames RelitImages of the object turned by 360 k / N degrees (module doc); options: relight's."""
    if int(frames) < 1:
        raise OutputError(f"--turntable {frames}: expected a number of frames >= 1")
    if scene.mesh is None:
        raise CaptureError(f"--turntable: the run {run.folder} is photometric stereo (no depth): it cannot turn")
    out = []
    index = options.pop("index", 0)
    with bar(int(frames), "turntable", enabled=progress, unit="frame") as pbar:
        for k in range(int(frames)):
            angle = 360.0 * k / int(frames)
            cam = turned(camera, index, scene.centre, angle)
            if light.position is not None:
                lit = Light(light.intensity, position=turn_point(light.position, scene.centre, angle))
            else:
                towards = turn_point(scene.centre + light.direction, scene.centre, angle) - scene.centre
                lit = Light(light.intensity, direction=towards)
            out.append(relight(run, cam, lit, scene=scene, progress=False, **options))
            pbar.update(1)
    return out


def write_turntable(folder, images: list[RelitImage], encoding: str = "srgb8", exposure: float = 1.0) -> TurntableFiles:
    """Write frames as FRAME PNGs and an animated GIF (8-bit sRGB, looping) into folder (made when absent)."""
    import imageio.v3 as iio

    folder = Path(folder)
    folder.mkdir(exist_ok=True)
    paths = [write_image(folder / FRAME.format(k), im.image, encoding, exposure) for k, im in enumerate(images)]
    gif = [encoded(im.image, "srgb8", exposure) for im in images]
    iio.imwrite(folder / GIF, np.stack(gif), duration=int(GIF_FRAME_S * 1000), loop=0)
    return TurntableFiles(paths, folder / GIF)
