"""The mesh_views loader on capture folders written by hand from the documented format (docs/capture-formats.md)."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from torchrefl.capture.images import write_png
from torchrefl.capture.mesh_views import MeshViewsLoader
from torchrefl.config import load_config
from torchrefl.errors import CaptureError
from torchrefl.geometry.mesh_file import read_mesh
from torchrefl.report.outputs import mesh_of_maps

ROOT = Path(__file__).resolve().parents[2]
S = 32  # capture.texture_size of the hand-made folder
W, H, F = 96, 80, 150.0  # image size and focal length of both cameras
Y = 4000.0  # the lights' radiant intensity

# a 40 x 40 mm plate in z = 0 facing +z on UVs [0, 0.5]^2; a 10 x 10 mm occluder in z = 15 facing +z on
# [0.75, 1]^2; a 10 x 10 mm card in z = -5 facing -z (behind the plate: no camera sees it) on [0.75, 1] x [0.5, 0.75]
PLATE = ([-20, -20, 0], [20, -20, 0], [20, 20, 0], [-20, 20, 0]), ([0, 0], [0.5, 0], [0.5, 0.5], [0, 0.5])
OCCLUDER = ([-5, -5, 15], [5, -5, 15], [5, 5, 15], [-5, 5, 15]), ([0.75, 0.75], [1, 0.75], [1, 1], [0.75, 1])
CARD = ([-5, -5, -5], [-5, 5, -5], [5, 5, -5], [5, -5, -5]), ([0.75, 0.5], [0.75, 0.75], [1, 0.75], [1, 0.5])

# camera A at (0, 0, 100) looking down -z; camera B at (60, 0, 80) looking at the origin, with k1 distortion
R_A = [[1, 0, 0], [0, -1, 0], [0, 0, -1]]
R_B = [[0.8, 0, -0.6], [0, -1, 0], [-0.6, 0, -0.8]]
CAMERAS = {
    "A": dict(width=W, height=H, fx=F, fy=F, cx=47.5, cy=39.5, R=R_A, t=[0, 0, 100]),
    "B": dict(width=W, height=H, fx=F, fy=F, cx=48.0, cy=40.0, k1=0.05, R=R_B, t=[0, 0, 100]),
}
LIGHTS = {
    "top": dict(position=[0, -40, 80], intensity=[Y, Y, Y]),
    "side": dict(position=[-50, 0, 30], intensity=[Y, 0.8 * Y, 0.6 * Y]),
}
IMAGES = [
    dict(file="images/A_top.png", camera="A", light="top"),
    dict(file="images/A_side.png", camera="A", light="side", exposure=2.0),
    dict(file="images/B_top.png", camera="B", light="top"),
    dict(file="images/B_side.png", camera="B", light="side"),
]


def ramp(k: int, u, v) -> np.ndarray:
    """The value image k holds at pixel (u, v) (a plane in u and v per channel, as fractions of full range)."""
    base = 0.15 + 0.05 * k
    return np.stack([base + 0.004 * u + 0.002 * v, base + 0.003 * u + 0.003 * v, base + 0.002 * u + 0.004 * v], -1)


def write_obj(path: Path, parts) -> None:
    lines, faces = [], []
    for k, (verts, uvs) in enumerate(parts):
        lines += [f"v {x} {y} {z}" for x, y, z in verts]
        lines += [f"vt {u} {v}" for u, v in uvs]
        o = 4 * k + 1
        faces += [f"f {o}/{o} {o + 1}/{o + 1} {o + 2}/{o + 2}", f"f {o}/{o} {o + 2}/{o + 2} {o + 3}/{o + 3}"]
    path.write_text("\n".join(lines + faces) + "\n")


def write_folder(folder: Path, cameras=CAMERAS, lights=LIGHTS, images=IMAGES, mesh=True) -> Path:
    (folder / "images").mkdir(parents=True, exist_ok=True)
    if mesh:
        write_obj(folder / "mesh.obj", [PLATE, OCCLUDER, CARD])
    (folder / "scene.yaml").write_text("units: mm\n")
    (folder / "cameras.json").write_text(json.dumps(cameras))
    (folder / "lights.json").write_text(json.dumps(lights))
    doc = {"encoding": "linear", "saturation_level": 0.995, "kappa": [math.pi] * 3, "images": images}
    (folder / "images.json").write_text(json.dumps(doc))
    u, v = np.meshgrid(np.arange(W), np.arange(H))
    for k, entry in enumerate(e for e in images if "file" in e):
        write_png(folder / entry["file"], np.rint(ramp(k, u, v) * 65535).astype(np.uint16), bits=16)
    return folder


def config(folder: Path, *more: str):
    return load_config(None, ["capture.kind=mesh_views", f"capture.path={folder}", f"capture.texture_size={S}", *more])


def load(folder: Path, *more: str):
    return MeshViewsLoader().load(folder, config(folder, *more), lambda msg: None)


@pytest.fixture(scope="module")
def hand(tmp_path_factory):
    folder = write_folder(tmp_path_factory.mktemp("mv") / "hand")
    return folder, load(folder)


def texel(cap, row: int, col: int) -> int:
    return int(np.flatnonzero(cap.surface.texel_index.numpy() == row * S + col)[0])


def plate_point(row: int, col: int) -> np.ndarray:
    """The texel centre of plate texel (row, col): uv = ((col + 0.5) / S, 1 - (row + 0.5) / S) on the plate's UVs."""
    u, v = (col + 0.5) / S, 1 - (row + 0.5) / S
    return np.array([-20 + 80 * u, -20 + 80 * v, 0.0])


def project(cam: dict, X: np.ndarray) -> tuple[float, float]:
    """The camera formula of the format: X_cam = R X + t, (x', y') = (x / z, y / z), k1 radial distortion."""
    x, y, z = np.asarray(cam["R"], dtype=float) @ X + np.asarray(cam["t"], dtype=float)
    x, y = x / z, y / z
    radial = 1 + cam.get("k1", 0.0) * (x * x + y * y)
    return cam["fx"] * x * radial + cam["cx"], cam["fy"] * y * radial + cam["cy"]


@pytest.mark.parametrize("image", range(4))
def test_an_observation_is_the_pixel_at_the_texels_projection_over_its_exposure(hand, image):
    folder, cap = hand
    row, col = 22, 12  # on the plate, away from its edges and from the occluder's shadow and image
    t = texel(cap, row, col)
    X = plate_point(row, col)
    np.testing.assert_allclose(cap.surface.positions[t].numpy(), X, atol=1e-9)
    cam = CAMERAS["AB"[image // 2]]
    u, v = project(cam, X)
    exposure = IMAGES[image].get("exposure", 1.0)
    assert bool(cap.obs.valid[image, t])
    np.testing.assert_allclose(cap.obs.intensity[image, t].numpy(), ramp(image, u, v) / exposure, atol=2e-4)
    L = np.array(LIGHTS[IMAGES[image]["light"]]["position"], dtype=float)
    d = np.linalg.norm(L - X)
    np.testing.assert_allclose(float(cap.obs.falloff[image, t]), 1 / d**2, rtol=1e-5)
    np.testing.assert_allclose(cap.obs.light_dir[image, t].numpy(), (L - X) / d, atol=1e-6)
    centre = -np.asarray(cam["R"], dtype=float).T @ np.asarray(cam["t"], dtype=float)
    np.testing.assert_allclose(cap.obs.view_dir[image, t].numpy(), (centre - X) / np.linalg.norm(centre - X), atol=1e-6)
    assert cap.obs.light_names[image] == Path(IMAGES[image]["file"]).name


def test_a_texel_behind_the_occluder_is_not_valid_in_the_camera_it_hides_from(hand):
    _, cap = hand
    t = texel(cap, 24, 8)  # at (1.25, -1.25, 0), behind the occluder as camera A sees it
    np.testing.assert_allclose(cap.surface.positions[t].numpy(), [1.25, -1.25, 0], atol=1e-9)
    assert not cap.obs.valid[:2, t].any()  # camera A
    assert cap.obs.valid[2:, t].all()  # camera B sees it past the occluder


def test_silhouette_texels_are_left_out_and_texels_no_camera_sees_are_counted(hand):
    _, cap = hand
    rows, cols = np.divmod(cap.surface.texel_index.numpy(), S)
    plate = (rows >= 16) & (cols < 16)
    rim = plate & ((rows == 16) | (rows == 31) | (cols == 0) | (cols == 15))
    assert rim.sum() == 60 and not cap.obs.valid[:, rim].any()  # the plate's outline in every image
    card = (rows >= 8) & (rows < 16) & (cols >= 24)
    assert card.sum() == 64 and not cap.obs.valid[:, card].any()
    unseen = ~cap.obs.valid.any(0).numpy()
    assert cap.stats["texels_seen_by_no_image"] >= card.sum() + rim.sum()
    assert cap.stats["texels_seen_by_no_image"] <= unseen.sum()
    assert cap.stats["images"] == 4 and cap.stats["cameras"] == 2 and cap.stats["texels"] == cap.surface.num_texels


def test_a_mesh_without_uvs_is_written_with_its_atlas_into_the_run_folder(tmp_path):
    folder = tmp_path / "box"
    write_folder(folder, mesh=False)
    box = trimesh.creation.box(extents=(30.0, 30.0, 30.0))
    box.apply_translation((0.0, 0.0, -16.0))  # its top face at z = -1, facing both cameras
    box.export(folder / "mesh.ply")
    cap = load(folder)
    assert cap.mesh_parametrised and cap.mesh.uvs is not None
    run = tmp_path / "run"
    run.mkdir()
    assert mesh_of_maps(run, cap) == "mesh.obj"
    back = read_mesh(run / "mesh.obj")
    np.testing.assert_allclose(back.vertices[back.faces], cap.mesh.vertices[cap.mesh.faces], atol=1e-6)
    np.testing.assert_allclose(back.uvs, cap.mesh.uvs, atol=1e-6)


@pytest.mark.parametrize(
    "change, words",
    [
        (dict(cameras={**CAMERAS, "A": {**CAMERAS["A"], "width": W + 2}}), ["A_top.png", "camera 'A'", f"{W + 2}x{H}"]),
        (dict(images=[*IMAGES[:3], {**IMAGES[3], "camera": "C"}]), ["images[3]", "camera 'C'"]),
        (dict(images=[{**IMAGES[0], "light": "flash"}, *IMAGES[1:]]), ["images[0]", "light 'flash'"]),
        (
            dict(images=[*IMAGES, dict(file="images/missing.png", camera="A", light="top")]),
            ["images[4]", "missing.png"],
        ),
    ],
    ids=["image size", "missing camera", "missing light", "missing image"],
)
def test_bad_folders_are_named_errors(tmp_path, change, words):
    folder = write_folder(tmp_path / "bad", **{k: v for k, v in change.items()})
    if any(e.get("file") == "images/missing.png" for e in change.get("images", [])):
        (folder / "images" / "missing.png").unlink()
    with pytest.raises(CaptureError) as err:
        load(folder)
    for word in words:
        assert word in str(err.value)


def test_a_light_inside_the_object_is_refused(tmp_path):
    folder = tmp_path / "inside"
    write_folder(folder, mesh=False, lights={**LIGHTS, "side": {**LIGHTS["side"], "position": [0.0, 0.0, -16.0]}})
    box = trimesh.creation.box(extents=(30.0, 30.0, 30.0))
    box.apply_translation((0.0, 0.0, -16.0))
    box.export(folder / "mesh.ply")
    with pytest.raises(CaptureError, match="light 'side' .* is inside the object"):
        load(folder)


def test_mesh_and_cameras_in_different_frames_say_so(tmp_path):
    far = {name: {**c, "t": [c["t"][0] + 5000.0, c["t"][1], c["t"][2]]} for name, c in CAMERAS.items()}
    folder = write_folder(tmp_path / "frames", cameras=far)
    with pytest.raises(CaptureError, match="nothing projects onto the object.*not in the same frame"):
        load(folder)


def test_a_truth_file_on_another_atlas_size_is_refused(tmp_path):
    folder = write_folder(tmp_path / "truth")
    np.savez(folder / "truth.npz", pd=np.zeros((16, 16, 3)), ps=np.zeros((16, 16, 3)), sigma=np.zeros((16, 16)))
    with pytest.raises(CaptureError, match=f"16x16 atlas, but capture.texture_size is {S}"):
        load(folder)


def test_the_bundled_config_runs_end_to_end_on_a_tiny_scene(tmp_path):
    out = tmp_path / "run"
    overrides = [
        f"output.dir={out}",
        "output.progress=false",
        "capture.texture_size=16",
        "views.width=64",
        "views.height=48",
        "views.focal_px=110",
        "views.cameras_per_ring=2",
        "views.camera_elevations_deg=[0.0, 35.0]",
        "views.lights_per_view=2",
        "views.supersample=1",
        "fit.holdout=[1]",
        "fit.iterations=1",
    ]
    cmd = [sys.executable, "-m", "torchrefl.train", str(ROOT / "configs" / "mesh_views.yaml"), *overrides]
    done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    with np.load(out / "params.npz") as p:
        assert str(p["mesh"]) == "capture/mesh.obj" and p["pd"].shape == (16, 16, 3)
    assert (out / "capture" / "mesh.obj").is_file()
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["capture"]["kind"] == "synthetic_mesh_views" and metrics["capture"]["images"] == 8


def _behind_occluder(X: np.ndarray, source: np.ndarray) -> bool:
    """The segment from the plate point X to source (a light or a camera centre) crosses the occluder (z = 15,
    |x|, |y| <= 5)."""
    hit = X + (15.0 - X[2]) / (source[2] - X[2]) * (source - X)
    return bool(abs(hit[0]) <= 5 and abs(hit[1]) <= 5)


STEPS = ((0, 1), (0, -1), (1, 0), (-1, 0))
PLATE_CELLS = [(r, c) for r in range(16, 32) for c in range(16)]  # the plate's texels (row, col) on the atlas


def light_and_camera(image: int) -> tuple[np.ndarray, np.ndarray]:
    """Image `image`'s light position and camera centre (-R^T t), world mm."""
    cam = CAMERAS[IMAGES[image]["camera"]]
    light = np.array(LIGHTS[IMAGES[image]["light"]]["position"], dtype=float)
    return light, -np.asarray(cam["R"], dtype=float).T @ np.asarray(cam["t"], dtype=float)


@pytest.mark.parametrize("image", [0, 2])  # the top light: the occluder's shadow falls on the plate
def test_a_texel_beside_the_occluders_shadow_is_left_out_and_counted(hand, image):
    # the shadow worked out from the geometry: a lit texel whose neighbour one step along a texel axis is in
    # shadow may have part of its footprint in shadow; one two steps from the shadow (and from the occluder's
    # outline in the image) keeps its observation
    _, cap = hand
    light, centre = light_and_camera(image)
    cells = PLATE_CELLS
    dark = {rc: _behind_occluder(plate_point(*rc), light) for rc in cells}
    hidden = {rc: _behind_occluder(plate_point(*rc), centre) for rc in cells}
    inner = [(r, c) for r in range(18, 30) for c in range(2, 14)]  # away from the plate's outline
    edge = [rc for rc in inner if not dark[rc] and any(dark[(rc[0] + a, rc[1] + b)] for a, b in STEPS)]
    near = lambda rc, flags: any(flags[(rc[0] + a, rc[1] + b)] for a in range(-2, 3) for b in range(-2, 3))  # noqa: E731
    clear = [rc for rc in inner if not near(rc, dark) and not near(rc, hidden)]
    assert len(edge) >= 8 and len(clear) >= 40
    valid = cap.obs.valid[image].numpy()
    assert not any(valid[texel(cap, *rc)] for rc in edge)
    assert not any(valid[texel(cap, *rc)] for rc in inner if dark[rc])
    assert all(valid[texel(cap, *rc)] for rc in clear)
    assert cap.stats["shadow_edge_observations"] >= len(edge)


@pytest.mark.parametrize("image", range(4))
def test_every_lit_texel_has_its_cast_shadow_whether_the_camera_sees_it_or_not(hand, image):
    # the interreflection levels light every texel as an emitter with obs.shadowed: a texel the camera does not see
    # (here: under the occluder in camera A's view) still has its shadow from the light, worked out from the geometry
    _, cap = hand
    light, centre = light_and_camera(image)
    cells = PLATE_CELLS
    shadowed = cap.obs.shadowed[image].numpy()
    dark = [rc for rc in cells if _behind_occluder(plate_point(*rc), light)]
    assert [rc for rc in cells if shadowed[texel(cap, *rc)]] == dark
    if IMAGES[image] == IMAGES[0]:  # camera A under the top light: some shadowed texels are hidden from the camera
        hidden = [rc for rc in dark if _behind_occluder(plate_point(*rc), centre)]
        assert len(hidden) >= 4 and not any(cap.obs.valid[image, texel(cap, *rc)] for rc in hidden)


def test_a_few_narrow_texels_are_not_named_an_atlas_too_fine(hand):
    """The hand-made folder at 16 x 16 (every texel over 4 px where seen) and at 32 x 32 (its occluder's 64 texels
    about 2.2 px, under views_sampling.NARROW_PX) gives no capture.texture_size warning (views_sampling.narrow_warning:
    above half of the texels the images face)."""
    folder, cap = hand
    for quiet in (load(folder, "capture.texture_size=16"), cap):
        assert not [w for w in quiet.warnings if "texture_size" in w]
    assert cap.stats["not_seen_narrow_observations"] > 0
