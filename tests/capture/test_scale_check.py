"""The one scale check (capture/scale_check.py) on plain arrays: a mesh with positioned cameras and point lights
(the mesh_views situation), the bands of each kind of length, and which side a verdict blames."""

import math

import numpy as np
import pytest

from torchrefl.capture.scale_check import (
    ObjectSize,
    Positions,
    Reference,
    bounding_sphere,
    check_scale,
    scene_scale_check,
    unit_name,
)
from torchrefl.errors import CaptureError, GeometryError


def sphere_vertices(radius_mm, centre=(0.0, 0.0, 0.0), n=400, seed=0):
    v = np.random.default_rng(seed).normal(size=(n, 3))
    return radius_mm * v / np.linalg.norm(v, axis=-1, keepdims=True) + np.asarray(centre)


def ring(radius_mm, n, height=0.0, centre=(0.0, 0.0, 0.0)):
    a = 2 * math.pi * np.arange(n) / n
    return np.stack([radius_mm * np.cos(a), np.full(n, height), radius_mm * np.sin(a)], -1) + np.asarray(centre)


def mesh_views(vertices, cameras, lights):
    """The call a mesh_views loader makes: one line, plain arrays."""
    return scene_scale_check(
        vertices,
        "scene/mesh.ply",
        "give scene.yaml units: m (x {factor:g})",
        cameras=Positions("scene/cameras.json", "cameras[{i}].position_mm", cameras),
        lights=Positions("scene/lights.json", "lights[{i}].position_mm", lights),
    )


# a 50 mm-radius object about the world origin (where a calibration puts it: positions 1000x too small collapse onto
# the origin, inside the object), 8 cameras at 400 mm and 12 lights at 600 mm around it
CENTRE = (5.0, 10.0, -5.0)
MESH = sphere_vertices(50.0, CENTRE)
CAMERAS = ring(400.0, 8, height=50.0, centre=CENTRE)
LIGHTS = ring(600.0, 12, height=200.0, centre=CENTRE)


def test_bounding_sphere_of_a_sphere():
    centre, radius = bounding_sphere(np.vstack([MESH, [[np.nan, 0.0, 0.0]]]))
    np.testing.assert_allclose(centre, CENTRE, atol=5.0)
    assert 49.0 < radius < 56.0


def test_a_consistent_scene_passes_without_warning():
    check = mesh_views(MESH, CAMERAS, LIGHTS)
    assert check.findings == [] and check.enforce() == []


def test_a_mesh_in_metres_is_refused_naming_the_mesh_and_the_unit():
    with pytest.raises(GeometryError) as exc:
        mesh_views(MESH * 0.001, CAMERAS, LIGHTS).enforce()
    msg = str(exc.value)
    assert msg.startswith("scene/mesh.ply: ") and "look like metres" in msg and "units: m (x 1000)" in msg
    assert "cameras[" in msg and "lights[" in msg


def test_a_mesh_in_micrometres_is_refused():
    mesh = sphere_vertices(50.0) * 1000.0  # a 50 mm object about the origin written in um, the rest in mm
    with pytest.raises(GeometryError, match=r"look like micrometres \(x 0\.001 gives mm\)"):
        mesh_views(mesh, ring(400.0, 8), ring(600.0, 12)).enforce()


def test_cameras_in_metres_are_refused_naming_their_file():
    with pytest.raises(CaptureError, match=r"cameras\[\*\]\.position_mm in scene/cameras\.json look like metres"):
        mesh_views(MESH, CAMERAS * 0.001, LIGHTS).enforce()


def test_lights_in_metres_are_refused_naming_their_file():
    with pytest.raises(CaptureError, match=r"lights\[\*\]\.position_mm in scene/lights\.json look like metres"):
        mesh_views(MESH, CAMERAS, LIGHTS * 0.001).enforce()


def test_one_light_inside_the_object_is_refused_by_its_index():
    lights = LIGHTS.copy()
    lights[5] = np.asarray(CENTRE) + [10.0, 0.0, 0.0]  # 10 mm from the centre of a 50 mm sphere
    with pytest.raises(CaptureError, match=r"lights\[5\]\.position_mm is 1\d\.\d+ mm from the object's centre: 0\.2"):
        mesh_views(MESH, CAMERAS, lights).enforce()


def test_a_mesh_in_centimetres_is_warned_not_refused():
    warnings = mesh_views(MESH * 0.1, CAMERAS, LIGHTS).enforce()
    assert len(warnings) == 1 and "look like centimetres" in warnings[0] and "lights[" in warnings[0]


@pytest.mark.parametrize(
    ("kind", "ratio", "severity"),
    [
        ("light", 2.0, None),
        ("light", 0.8, "warning"),  # inside the bounding sphere: a hollow object only
        ("light", 0.3, "error"),  # inside any object that is not hollow there
        ("light", 40.0, "warning"),  # fall-off under 14 % across the object: nearly directional
        ("light", 2000.0, "error"),  # fall-off under one 8-bit step across the object
        ("camera", 50.0, None),  # a camera may stand farther than a light (a longer lens)
        ("camera", 200.0, "warning"),
        ("camera", 5000.0, "error"),
        ("step", 1 / 20, None),  # the radius spans 20 steps
        ("step", 1 / 2, "warning"),  # 2 steps: the 5-sample fitting window does not fit across the object
        ("step", 2.0, "error"),  # the object is smaller than one step
        ("step", 1 / 50000, "warning"),
        ("step", 1 / 500000, "error"),
    ],
)
def test_the_bands_of_each_kind(kind, ratio, severity):
    obj = ObjectSize(10.0, "obj.ply", "the vertices", "x {factor:g}")
    check = check_scale(obj, [Reference.of(kind, "rig.yaml", "length", 10.0 * ratio)])
    assert [f.severity for f in check.findings] == ([severity] if severity else [])


def test_a_step_out_of_band_alone_blames_the_step_not_the_geometry():
    obj = ObjectSize(60.0, "range.npy", "the ranges", "x {factor:g}", "the rotation axis")
    refs = [
        Reference.of("camera", "scan.yaml", "camera.distance_mm", 300.0),
        Reference.of("light", "scan.yaml", "lights[{i}].position_mm", [300.0, 320.0, 350.0]),
        Reference.of("step", "scan.yaml", "grid.height_step_mm", 0.00056),  # 0.56 mm written in metres
    ]
    check = check_scale(obj, refs)
    assert [ref for ref, _ in check.suspects] == [refs[2]]
    with pytest.raises(CaptureError, match=r"grid\.height_step_mm in scan\.yaml look like metres"):
        check.enforce()


def test_a_degenerate_object_is_a_geometry_error():
    with pytest.raises(GeometryError, match=r"empty\.ply: the object's radius is 0\.0"):
        check_scale(ObjectSize(0.0, "empty.ply", "the vertices", ""), [])


@pytest.mark.parametrize(
    ("factor", "unit"),
    [(900.0, "metres"), (8.0, "centimetres"), (25.0, "inches"), (0.0012, "micrometres")],
)
def test_unit_names(factor, unit):
    assert unit_name(factor) == unit
