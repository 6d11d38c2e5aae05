"""The relit frame's interreflection (torchrefl.report.relight_indirect) against the reference path tracer.

A concave glossy scene with known parameters: the 90 degree fold of conftest.fold_surface (a floor and a wall, one
glossy material) written as a radiosity-level and a photon-level run with its true parameters, relit from a pinhole
camera under a point light with and without interreflection. The reference (tests/reference/path_tracer.py; it
shares no code with torchrefl; the radiosity level against its mode 'diffuse', the all-diffuse paths, the photon
level against 'full', every path with the full BRDF) renders the same pixels: each pixel centre's ray met analytically
with the exact floor and wall (two quads), the exact normal, the material. Compared over the pixels whose 3 x 3
block lies on the surface, away from the sheet's border and the fold's texel rows (where the grid's triangulation
cuts the corner).
"""

import json

import numpy as np
import pytest
from conftest import fold_surface, write_grid_run
from reference.path_tracer import ReferenceRenderer
from reference.png_reader import read_png

from torchrefl import render
from torchrefl.capture.cameras import Cameras
from torchrefl.errors import CaptureError
from torchrefl.report.relight import Light
from torchrefl.report.render_specs import parse_camera
from torchrefl.report.run_marker import write_marker
from torchrefl.report.run_result import load_run
from torchrefl.report.turntable import encoded
from torchrefl.synthetic.views_layout import look_at

H, W, L = 16, 32, 60.0  # the fold's texel grid; half the sheet's width (mm)
PD, PS, SIGMA = (0.7, 0.6, 0.5), 0.35, 0.15
LIGHT = np.array([-45.0, 10.0, 55.0])
INTENSITY = 2.5e3
CAMERA = np.array([-110.0, -60.0, 90.0])
TARGET = np.array([-18.0, 0.0, 18.0])
SIZE = 32  # image side (px)
SAMPLES = 256  # reference paths per pixel
#: the run's level settings (few rays and photons: the test's size)
LEVEL = {
    "radiosity": {"patch_size": 2, "hemisphere_samples": 512, "solve_samples": None},
    "photon": {"photons_per_light": 40000, "specular_gather": 16},
}
#: with interreflection the mean difference from the reference is at most this share of the difference without
MARGIN = 0.25


def fold_run(folder, model: str):
    """The fold as a run folder fitted at `model` with the true parameters."""
    s = fold_surface(H, W, L)
    write_grid_run(folder, s.to_grid(s.positions.numpy()), s.to_grid(s.normals.numpy()), pd=PD, ps=PS, sigma=SIGMA)
    metrics = json.loads((folder / "metrics.json").read_text())
    (folder / "metrics.json").write_text(json.dumps({**metrics, "model": model}))
    config = {"geometry": {"shadow_offset_mm": 0.05}, "fit": {"model": model}, "threads": 2, **LEVEL}
    (folder / "config.yaml").write_text(json.dumps(config))
    write_marker(folder)
    return load_run(folder)


def camera() -> Cameras:
    cam = look_at("view", CAMERA, TARGET, SIZE, SIZE, 40.0)
    return Cameras.from_arrays(
        ["view"],
        [SIZE],
        [SIZE],
        [cam.fx],
        [cam.fy],
        [cam.cx],
        [cam.cy],
        np.zeros((1, 5)),
        cam.R[None],
        cam.t[None],
        source="test camera",
    )


def pixel_hits(cam: Cameras):
    """Each pixel centre's ray met with the exact fold: points (N, 3), normals (N, 3), views (N, 3), pixel (N,)."""
    K, R = cam.K[0].numpy(), cam.R[0].numpy()
    u, v = np.meshgrid(np.arange(SIZE, dtype=float), np.arange(SIZE, dtype=float))
    d = np.stack([(u.ravel() - K[0, 2]) / K[0, 0], (v.ravel() - K[1, 2]) / K[1, 1], np.ones(u.size)], -1) @ R
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_floor, t_wall = -CAMERA[2] / d[:, 2], -CAMERA[0] / d[:, 0]
    x_floor, x_wall = CAMERA + t_floor[:, None] * d, CAMERA + t_wall[:, None] * d
    margin = 2.0 * L / W  # two texels from the border and the fold
    on_floor = (t_floor > 0) & (x_floor[:, 0] < -margin) & (x_floor[:, 0] > -L + margin)
    on_wall = (t_wall > 0) & (x_wall[:, 2] > margin) & (x_wall[:, 2] < L - margin)
    on_floor &= np.abs(x_floor[:, 1]) < L / 2 - margin
    on_wall &= np.abs(x_wall[:, 1]) < L / 2 - margin
    floor_first = on_floor & (~on_wall | (t_floor < t_wall))
    hit = floor_first | on_wall
    x = np.where(floor_first[:, None], x_floor, x_wall)[hit]
    n = np.where(floor_first[:, None], [0.0, 0.0, 1.0], [-1.0, 0.0, 0.0])[hit]
    return x, n, -d[hit], np.flatnonzero(hit)


def reference_image(cam: Cameras, kappa, mode: str) -> tuple[np.ndarray, np.ndarray]:
    """The reference's values (N, 3) in `mode` at the pixels pixel_hits finds, and those pixels."""
    V = np.array([[-L, -L / 2, 0], [0, -L / 2, 0], [0, L / 2, 0], [-L, L / 2, 0], [0, -L / 2, L], [0, L / 2, L]])
    F = np.array([[0, 1, 2], [0, 2, 3], [1, 4, 5], [1, 5, 2]])
    vn = np.array([[0, 0, 1], [-1, 0, 1], [-1, 0, 1], [0, 0, 1], [-1, 0, 0], [-1, 0, 0]], float)
    nv = len(V)
    mat = (np.tile(PD, (nv, 1)), np.full((nv, 3), PS), np.full(nv, SIGMA))
    renderer = ReferenceRenderer(V, F, vn, *mat, offset=0.01, seed=3)
    x, n, v, pixel = pixel_hits(cam)
    N = len(x)
    values, _ = renderer.render(
        x,
        n,
        v,
        np.tile(PD, (N, 1)),
        np.full((N, 3), PS),
        np.full(N, SIGMA),
        np.broadcast_to(LIGHT, (1, N, 3)),
        np.full((1, 3), INTENSITY),
        kappa,
        mode,
        SAMPLES,
    )
    return values[0], pixel


@pytest.fixture(scope="module")
def photon_fold(tmp_path_factory):
    return fold_run(tmp_path_factory.mktemp("fold_photon") / "run", "photon")


@pytest.mark.parametrize("model, mode", [("radiosity", "diffuse"), ("photon", "full")])
def test_interreflection_brings_the_relit_fold_to_the_reference(tmp_path, photon_fold, model, mode):
    run, cam = photon_fold if model == "photon" else fold_run(tmp_path / "run", model), camera()
    light = Light(INTENSITY, position=LIGHT)
    ref, pixel = reference_image(cam, run.kappa, mode)
    diffs = {}
    for interreflection in (None, False):  # the default: the run's level's
        im = run.render(camera=cam, light=light, interreflection=interreflection)
        assert im.estimated.reshape(-1)[pixel].all()
        diffs[interreflection] = float(np.abs(im.image.reshape(-1, 3)[pixel] - ref).mean() * 255)
    # the fold's interreflection is several DN here: without it the frame is visibly too dark
    assert diffs[False] > 5.0, diffs
    assert diffs[None] < MARGIN * diffs[False], diffs
    values = run.scene.indirect.last[1]  # another sampling of the same light and camera reuses the level's values
    run.render(camera=cam, light=light, interpolation="nearest", supersample=2)
    assert run.scene.indirect.last[1] is values


def test_interreflection_follows_the_run_level(tmp_path, photon_fold):
    local = fold_run(tmp_path / "local", "local")
    cam, light = camera(), Light(INTENSITY, position=LIGHT)
    default = local.render(camera=cam, light=light).image
    assert np.array_equal(default, local.render(camera=cam, light=light, interreflection=False).image)
    with pytest.raises(CaptureError, match="'model'"):
        local.render(camera=cam, light=light, interreflection=True)
    with pytest.raises(CaptureError, match="point light"):
        photon_fold.render(camera=cam, light=Light(1.0, direction=(-1.0, 0.0, 1.0)))


def test_the_command_line_leaves_the_interreflection_out_when_asked(tmp_path, photon_fold):
    out, orbit, point = tmp_path / "local.png", "orbit -45 20 150", "point " + " ".join(map(str, LIGHT))
    args = ["--camera", orbit, "--light", point, "--intensity", str(INTENSITY), "--size", "24x24", "--supersample", "1"]
    assert (
        render.main(
            [
                str(photon_fold.folder),
                *args,
                "--no-interreflection",
                "--encoding",
                "linear16",
                "--quiet",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    cam = parse_camera(orbit, photon_fold, photon_fold.scene, 24, 24)
    local = photon_fold.render(camera=cam, light=Light(INTENSITY, position=LIGHT), interreflection=False).image
    assert np.array_equal(read_png(out)[0], encoded(local, "linear16"))
