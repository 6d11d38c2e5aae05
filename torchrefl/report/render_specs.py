"""The render command's camera and light specifications (python -m torchrefl.render --camera SPEC --light SPEC).

Cameras:
    orbit AZ EL [DIST]     a pinhole camera at azimuth AZ, elevation EL (degrees; azimuth from +z towards +x,
                           elevation towards +y) and distance DIST (the run's units; default 4 x the object's
                           radius) from the object's centre, looking at it (report.relight_camera.orbit_camera)
    FILE.json:NAME         camera NAME of a cameras.json file (the mesh_views format, in the run's units);
                           FILE.json alone when it holds one camera
    photographs            the orthographic camera of a photometric-stereo run's photographs
Lights:
    point X Y Z            a point light at (X, Y, Z) (world frame, the run's units)
    dir X Y Z              a directional light towards (X, Y, Z)
    orbit AZ EL [DIST]     a point light placed like an orbit camera
    FILE.json:NAME         light NAME of a lights.json file (its intensity unless one is given)
The intensity is one or three numbers (RGB) or, without one, report.relight.default_intensity.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from torchrefl.capture.cameras_json import read_cameras_json
from torchrefl.capture.lights_json import read_lights_json
from torchrefl.errors import CaptureError
from torchrefl.report.relight import Light, RelightScene, default_intensity, photographs_camera
from torchrefl.report.relight_camera import one_camera, orbit_camera
from torchrefl.synthetic.views_layout import direction

#: an orbit preset without a distance stands this many object radii from the centre
ORBIT_RADII = 4.0
CAMERA_FORMS = "'orbit AZ EL [DIST]', 'FILE.json:NAME' (a cameras.json entry) or 'photographs'"
LIGHT_FORMS = "'point X Y Z', 'dir X Y Z', 'orbit AZ EL [DIST]' or 'FILE.json:NAME' (a lights.json entry)"


def _numbers(spec: str, words: list[str], counts: tuple[int, ...], what: str) -> list[float]:
    try:
        values = [float(w) for w in words]
    except ValueError:
        values = None
    if values is None or len(values) not in counts or not np.isfinite(values).all():
        raise CaptureError(
            f"{what} {spec!r}: expected {' or '.join(map(str, counts))} finite numbers after '{spec.split()[0]}'"
        )
    return values


def _file_entry(spec: str, what: str) -> tuple[Path, str | None]:
    path, _, name = spec.partition(".json:")
    return (Path(path + ".json"), name) if name else (Path(spec), None)


def _orbit_position(spec: str, words: list[str], scene: RelightScene, what: str) -> tuple[float, float, float]:
    az, el, *rest = _numbers(spec, words, (2, 3), what)
    return az, el, rest[0] if rest else ORBIT_RADII * scene.radius


def parse_camera(spec: str, run, scene: RelightScene, width: int = 512, height: int = 512):
    """The camera of a --camera SPEC (module doc); width, height: an orbit camera's image size."""
    words = spec.split()
    if not words:
        raise CaptureError(f"--camera is empty, expected {CAMERA_FORMS}")
    if words[0] == "orbit":
        az, el, dist = _orbit_position(spec, words[1:], scene, "--camera")
        return orbit_camera(scene.centre, scene.radius, az, el, dist, width, height)
    if spec == "photographs":
        if run.units != "px":
            raise CaptureError(f"--camera photographs: the run {run.folder} is not photometric stereo")
        return photographs_camera(run)
    if spec.endswith(".json") or ".json:" in spec:
        path, name = _file_entry(spec, "--camera")
        cams = read_cameras_json(path)
        return one_camera(cams, _entry_index(spec, "--camera", path, name, cams.names, "camera"))
    raise CaptureError(f"--camera {spec!r}: expected {CAMERA_FORMS}")


def _entry_index(spec: str, flag: str, path, name, names, what: str) -> int:
    """The index of entry `name` among a file's `names` (the only one when name is None); CaptureError naming the
    flag, the file and the entries otherwise."""
    if name is None and len(names) != 1:
        raise CaptureError(f"{flag} {spec}: {path} holds {len(names)} {what}s; name one as {path}:NAME")
    if name is not None and name not in names:
        raise CaptureError(f"{flag} {spec}: {path} has no {what} '{name}' (it has {', '.join(names)})")
    return 0 if name is None else list(names).index(name)


def parse_light(spec: str, run, scene: RelightScene, intensity=None) -> Light:
    """The Light of a --light SPEC (module doc); intensity: one or three numbers, None for the light file's or
    default_intensity."""
    words = spec.split()
    if not words:
        raise CaptureError(f"--light is empty, expected {LIGHT_FORMS}")
    position = towards = file_intensity = None
    if words[0] == "point":
        position = np.array(_numbers(spec, words[1:], (3,), "--light"))
    elif words[0] == "dir":
        towards = np.array(_numbers(spec, words[1:], (3,), "--light"))
    elif words[0] == "orbit":
        az, el, dist = _orbit_position(spec, words[1:], scene, "--light")
        position = scene.centre + dist * direction(az, el)
    elif spec.endswith(".json") or ".json:" in spec:
        path, name = _file_entry(spec, "--light")
        lights = read_lights_json(path)
        k = _entry_index(spec, "--light", path, name, lights.names, "light")
        position, towards = (lights.position[k], None) if lights.point[k] else (None, lights.direction[k])
        file_intensity = lights.intensity[k]
    else:
        raise CaptureError(f"--light {spec!r}: expected {LIGHT_FORMS}")
    if intensity is None:
        intensity = file_intensity if file_intensity is not None else default_intensity(run, scene, position)
    return Light(np.asarray(intensity, dtype=np.float64), position=position, direction=towards)
