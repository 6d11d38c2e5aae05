"""Synthetic mesh_views scenes: the folder format, the truth on the atlas, determinism in the seed, and a pixel of a
written image against a hand computation."""

import json
import math

import numpy as np
import pytest
import trimesh

from torchrefl.capture.images import read_image
from torchrefl.geometry.atlas_surface import load_atlas_geometry
from torchrefl.synthetic.mesh_views import MeshViewsConfig, MeshViewsScene, write_capture, write_scene
from torchrefl.synthetic.objects import MeshObject
from torchrefl.synthetic.uv_objects import ViewsObject
from torchrefl.synthetic.views_layout import ViewImage, ViewLight, look_at
from torchrefl.synthetic.views_render import ViewsRenderer

SMALL = dict(
    width=64,
    height=48,
    focal_px=100.0,
    camera_elevations_deg=[0.0, 35.0],
    cameras_per_ring=2,
    supersample=1,
    exposures=[1.0, 0.8],
)
S_SMALL = 32  # the truth atlas's side (capture.texture_size)


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    folder = tmp_path_factory.mktemp("mv") / "ellipsoid"
    return write_capture(folder, MeshViewsConfig(**SMALL), texture_size=S_SMALL, seed=3)


def test_the_folder_holds_exactly_the_documented_files_and_keys(small):
    folder = small.folder
    cams = json.loads((folder / "cameras.json").read_text())
    lights = json.loads((folder / "lights.json").read_text())
    images = json.loads((folder / "images.json").read_text())
    cam_keys = {"width", "height", "fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "R", "t"}
    assert len(cams) == 4 and len(lights) == 3  # name -> camera, name -> light (docs/capture-formats.md)
    for c in cams.values():
        assert set(c) == cam_keys
        R = np.array(c["R"])
        assert R.shape == (3, 3) and len(c["t"]) == 3
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(R) > 0
        # the object's centre (the origin) projects near the image centre: u = fx x / z + cx, v = fy y / z + cy
        x = R @ np.zeros(3) + np.array(c["t"])
        assert x[2] > 0
        assert abs(c["fx"] * x[0] / x[2] + c["cx"] - (c["width"] - 1) / 2) < 1e-6
        assert abs(c["fy"] * x[1] / x[2] + c["cy"] - (c["height"] - 1) / 2) < 1e-6
    for light in lights.values():
        assert set(light) == {"position", "intensity"}
        assert len(light["position"]) == 3 and len(light["intensity"]) == 3
    assert set(images) == {"encoding", "saturation_level", "kappa", "images"}
    assert images["encoding"] == "linear" and len(images["kappa"]) == 3
    names = cams
    light_names = set(lights)
    per_view, per_light = {}, {}
    for im in images["images"]:
        assert set(im) == {"file", "camera", "light", "exposure"}
        assert im["camera"] in names and im["light"] in light_names
        per_view[im["camera"]] = per_view.get(im["camera"], 0) + 1
        per_light[im["light"]] = per_light.get(im["light"], 0) + 1
        pixels, bits = read_image(folder / im["file"])
        assert bits == 16 and pixels.shape == (names[im["camera"]]["height"], names[im["camera"]]["width"], 3)
        assert pixels.max() > 0.05  # the object is lit and seen
    assert max(per_view.values()) >= 2 and max(per_light.values()) >= 2
    assert {im["exposure"] for im in images["images"]} == {1.0, 0.8}
    assert (folder / "scene.yaml").read_text().strip() == "units: mm"
    mesh = trimesh.load(folder / "mesh.obj", process=False)
    assert len(mesh.faces) == len(small.scene.object.mesh.faces)
    uv = np.asarray(mesh.visual.uv)
    assert uv.min() >= 0 and uv.max() <= 1
    with np.load(folder / "truth.npz") as npz:
        truth = {k: npz[k] for k in npz.files}
    assert set(truth) == {"pd", "ps", "sigma", "region", "brdf"}
    S = S_SMALL
    assert truth["pd"].shape == (S, S, 3) and truth["ps"].shape == (S, S, 3)
    assert truth["sigma"].shape == (S, S) and truth["region"].shape == (S, S)
    assert np.isfinite(truth["pd"]).all()  # the UV ellipsoid's atlas fills the square: no gutter
    assert len(np.unique(truth["region"])) == 5 and np.ptp(truth["sigma"]) > 0.1 and truth["ps"].min() > 0.2


def test_texel_truth_is_the_material_at_the_texels_atlas_position(small):
    # independent of the writer's rasteriser: texel (row, col) centre uv -> the ellipsoid's parametrisation
    S = S_SMALL
    row, col = np.meshgrid(np.arange(S), np.arange(S), indexing="ij")
    u, v = (col + 0.5) / S, 1 - (row + 0.5) / S
    theta, phi = np.pi * (1 - v), 2 * np.pi * u
    a = np.asarray(small.scene.object.mesh.info["axes"])
    p = a * np.stack([np.sin(theta) * np.sin(phi), np.cos(theta), np.sin(theta) * np.cos(phi)], -1).reshape(-1, 3)
    m = small.scene.object.mesh.material(p, np.zeros(len(p), dtype=int))
    assert np.array_equal(m["region"].reshape(S, S), small.truth["region"])
    np.testing.assert_allclose(m["pd"].reshape(S, S, 3), small.truth["pd"], atol=2e-3)


def test_the_writer_is_deterministic_in_its_seed(small, tmp_path):
    again = write_capture(tmp_path / "a", MeshViewsConfig(**SMALL), texture_size=S_SMALL, seed=3)
    other = write_capture(tmp_path / "b", MeshViewsConfig(**SMALL), texture_size=S_SMALL, seed=4)
    for name in ("cameras.json", "lights.json", "images.json", "mesh.obj"):
        assert (again.folder / name).read_bytes() == (small.folder / name).read_bytes()
    files = [im.file for im in small.scene.images]
    assert all((again.folder / f).read_bytes() == (small.folder / f).read_bytes() for f in files)
    assert any((other.folder / f).read_bytes() != (small.folder / f).read_bytes() for f in files)
    for key in ("pd", "sigma"):
        assert np.array_equal(again.truth[key], small.truth[key], equal_nan=True)


def _quad(pd) -> ViewsObject:
    """A 100 mm square in the plane z = 0 facing +z, Lambertian with reflectance pd."""
    v = np.array([[-50.0, -50.0, 0.0], [50.0, -50.0, 0.0], [50.0, 50.0, 0.0], [-50.0, 50.0, 0.0]])
    f = np.array([[0, 1, 2], [0, 2, 3]])

    def material(points, tri):
        n = len(tri)
        return {"pd": np.tile(pd, (n, 1)), "ps": np.zeros((n, 3)), "sigma": np.full(n, 0.1), "region": np.zeros(n, int)}

    normal = lambda points, tri: np.tile([0.0, 0.0, 1.0], (len(tri), 1))  # noqa: E731
    mesh = MeshObject("quad", v, f, normal, material, (-50.0, 50.0), {})
    return ViewsObject(mesh, (v[:, :2] + 50) / 100, np.tile([0.0, 0.0, 1.0], (4, 1)), concave=False)


def test_a_pixel_of_a_lambertian_quad_matches_the_hand_computation(tmp_path):
    pd = np.array([0.5, 0.3, 0.2])
    Y = np.array([50000.0, 40000.0, 30000.0])
    kappa = (math.pi, 2.0, 3.0)
    exposure = 0.8
    L = np.array([-60.0, 80.0, 200.0])
    obj = _quad(pd)
    cam = look_at("cam00", [30.0, 20.0, 250.0], [0.0, 0.0, 0.0], 64, 48, 80.0)
    scene = MeshViewsScene(obj, [cam], [ViewLight("L00", L, Y)], [ViewImage("images/q.png", "cam00", "L00", exposure)])
    renderer = ViewsRenderer(obj, kappa=kappa, supersample=2, noise_dn=0.0)
    write_scene(tmp_path, scene, renderer, 16)
    c = json.loads((tmp_path / "cameras.json").read_text())["cam00"]
    R, t = np.array(c["R"]), np.array(c["t"])
    img, _ = read_image(tmp_path / "images" / "q.png")

    def pixel_of(X):
        x = R @ X + t
        return c["fx"] * x[0] / x[2] + c["cx"], c["fy"] * x[1] / x[2] + c["cy"]

    def surface_at(u, v):  # the pixel centre's ray from the camera centre, met with the plane z = 0
        d = R.T @ np.array([(u - c["cx"]) / c["fx"], (v - c["cy"]) / c["fy"], 1.0])
        o = -R.T @ t
        return o - o[2] / d[2] * d

    checked = 0
    for X in ([0.0, 0.0, 0.0], [20.0, -30.0, 0.0], [-35.0, 25.0, 0.0]):
        u, v = (int(round(a)) for a in pixel_of(np.array(X)))
        P = surface_at(u, v)
        np.testing.assert_allclose(pixel_of(P), (u, v), atol=1e-9)  # the inverse of the camera formula
        assert np.linalg.norm(P - X) < 4.0  # within about a pixel's footprint (3 mm) of the projected point
        to = L - P
        d2 = to @ to
        L_o = pd / math.pi * Y * to[2] / math.sqrt(d2) / d2
        expected = np.asarray(kappa) * exposure * L_o
        assert expected.min() > 0.05
        np.testing.assert_allclose(img[v, u] * 65535, expected * 65535, atol=1.0)
        checked += 1
    assert checked == 3
    u, v = pixel_of(np.array([50.0, 50.0, 0.0]))  # beyond the quad's corner (+x, +y): background
    far = (int(math.floor(u)) + 3, int(math.floor(v)) - 3)
    P = surface_at(*far)
    assert P[0] > 51 and P[1] > 51
    assert (img[far[1], far[0]] == 0).all()


def test_a_mesh_without_uvs_is_written_as_ply_with_its_truth_on_the_loaders_atlas(tmp_path):
    cfg = MeshViewsConfig(object="ellipsoid_no_uv", **SMALL)
    written = write_capture(tmp_path, cfg, texture_size=64, seed=0)
    assert written.mesh_file == "mesh.ply" and not (tmp_path / "mesh.obj").exists()
    assert getattr(trimesh.load(tmp_path / "mesh.ply", process=False).visual, "uv", None) is None
    geom = load_atlas_geometry(tmp_path / "mesh.ply", 64)  # what the loader does with a mesh without UVs
    assert geom.parametrised
    finite = np.flatnonzero(np.isfinite(written.truth["sigma"]).ravel())
    assert np.array_equal(finite, geom.texels.texel_index)
    assert (written.truth["region"].ravel()[finite] >= 0).all() and (written.truth["region"] == -1).any()
    m = written.scene.object.mesh.material(geom.surface.positions.numpy(), geom.texels.face)
    np.testing.assert_allclose(written.truth["pd"].reshape(-1, 3)[finite], m["pd"], rtol=1e-9)


def test_the_bowls_inside_and_outside_lie_on_their_documented_atlas_rows(tmp_path):
    cfg = MeshViewsConfig(object="bowl", **{**SMALL, "indirect_samples": 1})
    truth = write_capture(tmp_path, cfg, texture_size=S_SMALL, seed=0).truth
    S = S_SMALL
    rows = np.arange(S)[:, None] * np.ones(S, dtype=int)[None]
    region = truth["region"]
    inside = (region >= 0) & (region <= 4)
    assert (rows[inside] < S * 11 / 16).all() and (rows[region == 5] >= S * 11 / 16).all()
    assert inside.sum() > 0.6 * S * S and (region == 5).sum() > 0.1 * S * S
    paint = truth["pd"][region == 5]
    assert np.ptp(paint, axis=0).max() == 0  # the outside: one uniform matte paint
    assert np.ptp(truth["sigma"][inside]) > 0.1
