"""Photometric stereo loader (DiLiGenT layout): exact contents on tiny fake folders, every error case
naming its file, and the real DiLiGenT ball checked against its ground-truth normals."""

import math
import time
from pathlib import Path

import numpy as np
import pytest
import scipy.io
import torch
from PIL import Image

import torchrefl
from torchrefl.capture.images import write_png
from torchrefl.capture.photometric_stereo import load_photometric_stereo
from torchrefl.errors import CaptureError, DataMissingError, GeometryError

ROOT = Path(__file__).resolve().parents[2]
SHARED = ROOT / ".." / "shared"
BALL = SHARED / "data" / "diligent_ball"

H, W, P = 6, 8, 4
DIRS = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.0, -0.6, 0.8], [-0.48, 0.36, 0.8]])
INTENSITIES = np.array([[1.0, 1.5, 2.0], [0.9, 1.1, 1.3], [1.2, 1.2, 1.2], [2.0, 1.0, 0.5]])


def fake_normals() -> np.ndarray:
    """(H, W, 3) unit normals of a cap bulging towards the camera; zeros outside the object."""
    rows, cols = np.mgrid[0:H, 0:W]
    x, y = (cols - W / 2 + 0.5) / 5.0, (H / 2 - 0.5 - rows) / 5.0
    n = np.stack([x, y, np.ones_like(x)], axis=-1)
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


def fake_mask() -> np.ndarray:
    m = np.zeros((H, W), bool)
    m[1:5, 1:7] = True
    m[1, 1] = False
    return m


def make_folder(root: Path, *, with_filenames: bool = True) -> dict:
    """A 8x6, 4-light DiLiGenT folder; returns the uint16 image stack and what was written."""
    root.mkdir(parents=True, exist_ok=True)
    mask = fake_mask()
    normals = fake_normals()
    rng = np.random.default_rng(0)
    albedo = rng.uniform(0.2, 0.6, size=(H, W, 3))
    stack = []
    for p in range(P):
        shade = np.clip(normals @ DIRS[p], 0, None)[..., None] * albedo * INTENSITIES[p] * 0.4
        v = np.rint(np.clip(shade, 0, 1) * 65535).astype(np.uint16)
        v[0, :] = 257 * np.arange(W)[:, None] + 1  # values an 8-bit path would destroy (outside the mask)
        stack.append(v)
    stack = np.array(stack)
    stack[2, 2, 3] = (65535, 100, 100)  # one saturated red channel inside the mask
    names = [f"{i:03d}.png" for i in range(1, P + 1)]
    for name, v in zip(names, stack):
        write_png(root / name, v, bits=16)
    if with_filenames:
        (root / "filenames.txt").write_text("\n".join(names) + "\n")
    np.savetxt(root / "light_directions.txt", DIRS, fmt="%.4f")
    np.savetxt(root / "light_intensities.txt", INTENSITIES, fmt="%.4f")
    m8 = np.zeros((H, W, 3), np.uint8)
    m8[mask, 1] = 255  # object marked in one channel only
    write_png(root / "mask.png", m8, bits=8)
    scipy.io.savemat(root / "Normal_gt.mat", {"Normal_gt": np.where(mask[..., None], normals, 0.0)})
    return {"stack": stack, "mask": mask, "normals": normals, "names": names}


@pytest.fixture
def fake(tmp_path):
    info = make_folder(tmp_path / "obj")
    info["root"] = tmp_path / "obj"
    return info


def test_fake_folder_contents_exact(fake):
    surface, obs, stats = load_photometric_stereo(fake["root"], dtype=torch.float64)
    mask, stack = fake["mask"], fake["stack"]
    T = int(mask.sum())
    assert surface.grid_shape == (H, W) and surface.num_texels == T and surface.units == "px"
    assert not surface.has_mesh
    np.testing.assert_array_equal(surface.mask(), mask)
    # positions and values, texel by texel in row-major order (slow, obvious)
    t = 0
    for r in range(H):
        for c in range(W):
            if not mask[r, c]:
                continue
            assert surface.texel_index[t] == r * W + c
            assert surface.positions[t].tolist() == [c - W / 2, H / 2 - r, 0.0]
            np.testing.assert_allclose(surface.normals[t].numpy(), fake["normals"][r, c], atol=1e-12)
            for p in range(P):
                np.testing.assert_array_equal(obs.intensity[p, t].numpy() * 65535, stack[p, r, c].astype(float))
                n = fake["normals"][r, c]
                sat = bool((stack[p, r, c] >= 0.995 * 65535).any())
                assert obs.saturated[p, t] == sat
                assert obs.valid[p, t] == (n @ DIRS[p] > 0 and n[2] > 0 and not sat)
                np.testing.assert_allclose(obs.light_dir[p, t].numpy(), DIRS[p] / np.linalg.norm(DIRS[p]), atol=1e-12)
            t += 1
    assert surface.areas.tolist() == [1.0] * T
    np.testing.assert_allclose(obs.light_intensity.numpy(), INTENSITIES)
    assert obs.falloff.shape == (P, T) and (obs.falloff == 1).all()
    assert obs.view_dir.shape == (T, 3) and (obs.view_dir == torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)).all()
    assert not obs.shadowed.any() and obs.light_positions is None
    np.testing.assert_allclose(obs.kappa.numpy(), [math.pi] * 3)
    assert obs.light_names == fake["names"]
    assert obs.intensity.dtype == torch.float64 and obs.light_dir.dtype == torch.float64
    assert stats["bit_depth"] == 16 and stats["texels"] == T and stats["lights"] == P
    assert stats["saturated_observations"] == 1 and stats["per_light"]["saturated"] == [0, 0, 1, 0]
    assert stats["per_light"]["valid"] == obs.valid.sum(1).tolist()
    assert stats["load_time_s"] > 0
    # subsetting keeps working on the expanded light_dir
    sub = obs.subset_lights([3, 1])
    assert sub.light_dir.shape == (2, T, 3) and sub.light_names == ["004.png", "002.png"]


def test_light_subset_and_filename_order(fake, tmp_path):
    root = fake["root"]
    _, full, _ = load_photometric_stereo(root)
    _, sub, stats = load_photometric_stereo(root, light_subset=[3, 0], kappa=(1.0, 2.0, 3.0))
    assert sub.light_names == ["004.png", "001.png"] and stats["lights"] == 2
    assert torch.equal(sub.intensity, full.intensity[[3, 0]])
    assert torch.equal(sub.light_intensity, full.light_intensity[[3, 0]])
    assert torch.equal(sub.light_dir, full.light_dir[[3, 0]])
    assert sub.kappa.tolist() == [1.0, 2.0, 3.0]
    with pytest.raises(CaptureError, match="light_subset"):
        load_photometric_stereo(root, light_subset=[0, 4])
    # filenames.txt decides the order (light tables follow it); without it, sorted NNN.png
    (root / "filenames.txt").write_text("004.png\n003.png\n002.png\n001.png\n")
    _, rev, _ = load_photometric_stereo(root)
    assert rev.light_names == ["004.png", "003.png", "002.png", "001.png"]
    assert torch.equal(rev.intensity, full.intensity.flip(0))
    (root / "filenames.txt").unlink()
    _, nolist, _ = load_photometric_stereo(root)
    assert nolist.light_names == fake["names"] and torch.equal(nolist.intensity, full.intensity)


def _expect(root, cls, *fragments, **kwargs):
    with pytest.raises(cls) as err:
        load_photometric_stereo(root, **kwargs)
    msg = str(err.value)
    for f in fragments:
        assert f in msg, f"{f!r} not in {msg!r}"
    return msg


def test_missing_folder_says_how_to_get_the_data(tmp_path):
    msg = _expect(tmp_path / "nowhere", DataMissingError, "nowhere")
    assert "https://sites.google.com/site/photometricstereodata/single" in msg
    assert "capture.path=/path/to/DiLiGenT/pmsData/ballPNG" in msg


def test_bundled_config_without_the_data_stops_with_the_download_hint(tmp_path):
    """configs/diligent_ball.yaml names no real folder: run as is, it stops with the one DataMissingError."""
    with pytest.raises(DataMissingError) as e:
        torchrefl.fit(ROOT / "configs" / "diligent_ball.yaml", [f"output.dir={tmp_path / 'out'}"], quiet=True)
    assert "/path/to/DiLiGenT/pmsData/ballPNG" in str(e.value) and "photometricstereodata" in str(e.value)
    assert isinstance(e.value, CaptureError)


@pytest.mark.parametrize(
    "name", ["light_directions.txt", "light_intensities.txt", "mask.png", "Normal_gt.mat", "003.png"]
)
def test_missing_file(fake, name):
    (fake["root"] / name).unlink()
    _expect(fake["root"], CaptureError, name, "missing")


def test_no_images_at_all(tmp_path):
    (tmp_path / "empty").mkdir()
    _expect(tmp_path / "empty", CaptureError, "empty", "NNN.png")


def test_unreadable_image(fake):
    (fake["root"] / "002.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    _expect(fake["root"], CaptureError, "002.png")


def test_image_size_differs(fake):
    write_png(fake["root"] / "003.png", np.zeros((H + 1, W, 3), np.uint16), bits=16)
    _expect(fake["root"], CaptureError, "003.png is 8x7", "expected 8x6")


def test_bit_depth_differs(fake):
    write_png(fake["root"] / "003.png", np.zeros((H, W, 3), np.uint8), bits=8)
    _expect(fake["root"], CaptureError, "003.png", "8-bit", "16-bit")


def test_mask_size_differs(fake):
    write_png(fake["root"] / "mask.png", np.full((H, W + 2, 3), 255, np.uint8), bits=8)
    _expect(fake["root"], CaptureError, "mask.png is 10x6", "expected 8x6")


def test_normal_map_size_differs(fake):
    scipy.io.savemat(fake["root"] / "Normal_gt.mat", {"Normal_gt": np.zeros((H, W - 1, 3))})
    _expect(fake["root"], CaptureError, "Normal_gt.mat", "7x6", "expected 8x6")


def test_normal_map_wrong_key_or_corrupt(fake):
    scipy.io.savemat(fake["root"] / "Normal_gt.mat", {"normals": fake_normals()})
    _expect(fake["root"], CaptureError, "Normal_gt.mat", "Normal_gt", "missing")
    (fake["root"] / "Normal_gt.mat").write_bytes(b"MATLAB garbage")
    _expect(fake["root"], CaptureError, "Normal_gt.mat")


@pytest.mark.parametrize("name", ["light_directions.txt", "light_intensities.txt"])
def test_light_table_row_count(fake, name):
    table = DIRS if name == "light_directions.txt" else INTENSITIES
    np.savetxt(fake["root"] / name, table[:3], fmt="%.4f")
    _expect(fake["root"], CaptureError, name, "3 rows", "expected 4")
    np.savetxt(fake["root"] / name, np.vstack([table, table[:1]]), fmt="%.4f")
    _expect(fake["root"], CaptureError, name, "5 rows", "expected 4")


@pytest.mark.parametrize("name", ["light_directions.txt", "light_intensities.txt"])
def test_light_table_bad_lines(fake, name):
    path = fake["root"] / name
    lines = path.read_text().splitlines()
    path.write_text("\n".join(lines[:2] + ["0.1 abc 0.9"] + lines[3:]) + "\n")
    _expect(fake["root"], CaptureError, name, "line 3", "non-numeric")
    path.write_text("\n".join(lines[:1] + ["0.1 0.9"] + lines[2:]) + "\n")
    _expect(fake["root"], CaptureError, name, "line 2", "expected 3")


@pytest.mark.parametrize("bad", ["-1.0 1.0 1.0", "1.0 0.0 1.0", "1.0 nan 1.0"])
def test_bad_light_intensity_names_the_line(fake, bad):
    path = fake["root"] / "light_intensities.txt"
    lines = path.read_text().splitlines()
    path.write_text("\n".join(lines[:3] + [bad]) + "\n")
    _expect(fake["root"], CaptureError, "light_intensities.txt", "line 4", "> 0")


@pytest.mark.parametrize("bad", ["0.0 0.0 2.0", "nan 0.0 1.0"])
def test_bad_light_direction_names_the_line(fake, bad):
    path = fake["root"] / "light_directions.txt"
    lines = path.read_text().splitlines()
    path.write_text("\n".join(lines[:1] + [bad] + lines[2:]) + "\n")
    _expect(fake["root"], CaptureError, "light_directions.txt", "line 2", "unit")


def test_bad_normals_inside_mask(fake):
    n = np.where(fake["mask"][..., None], fake["normals"], 0.0)
    n[2, 2] = np.nan
    n[3, 3] *= 2.0
    n[0, 0] = np.nan  # outside the mask: ignored
    scipy.io.savemat(fake["root"] / "Normal_gt.mat", {"Normal_gt": n})
    _expect(fake["root"], GeometryError, "Normal_gt.mat", "2 of")


def test_empty_mask(fake):
    write_png(fake["root"] / "mask.png", np.zeros((H, W, 3), np.uint8), bits=8)
    _expect(fake["root"], CaptureError, "mask.png", "selects no pixel")


@pytest.mark.skipif(not BALL.is_dir(), reason="../shared/data/diligent_ball missing")
def test_diligent_ball_lambertian_normals(tmp_path):
    t0 = time.perf_counter()
    surface, obs, stats = load_photometric_stereo(BALL, threads=2)
    print(
        f"\nDiLiGenT ball: {stats['lights']} images, {stats['texels']} texels, {stats['bit_depth']}-bit, "
        f"{stats['saturated_observations']} saturated, loaded in {time.perf_counter() - t0:.2f} s"
    )
    mask = np.asarray(Image.open(BALL / "mask.png").convert("RGB")).any(-1)
    assert surface.grid_shape == (512, 612) and surface.num_texels == int(mask.sum())
    assert obs.intensity.shape == (96, surface.num_texels, 3) and stats["bit_depth"] == 16
    assert obs.light_names[0] == "001.png" and obs.light_names[-1] == "096.png"
    # raw sensor values (not divided by the light intensity): the high byte is what Pillow reads
    pil = np.asarray(Image.open(BALL / "010.png").convert("RGB"))[mask].astype(np.int64)
    ours = np.rint(obs.intensity[9].numpy().astype(np.float64) * 65535).astype(np.int64)
    assert np.abs((ours >> 8) - pil).max() <= 1

    # Lambertian least squares on every fifth image: per texel b = albedo * n from grey = mean_c(I_c / Y_c)
    sub = obs.subset_lights(list(range(0, 96, 5))).to(torch.float64)
    g = (sub.intensity / sub.light_intensity[:, None, :]).mean(-1)  # (P, T)
    w = ((g > 0.01 * g.max()) & ~sub.saturated).to(torch.float64)
    L = sub.light_dir[:, 0]  # directional: the same vector at every texel
    assert torch.equal(sub.light_dir, L[:, None, :].expand_as(sub.light_dir))
    A = torch.einsum("pt,pi,pj->tij", w, L, L)
    rhs = torch.einsum("pt,pi,pt->ti", w, L, g)
    ok = w.sum(0) >= 3
    b = torch.linalg.solve(A[ok], rhs[ok])
    n_fit = b / b.norm(dim=1, keepdim=True)
    n_gt = surface.normals[ok].to(torch.float64)
    err = torch.rad2deg(torch.atan2(torch.linalg.cross(n_fit, n_gt).norm(dim=1), (n_fit * n_gt).sum(1)))
    print(
        f"Lambertian fit on {sub.num_lights} images: mean angular error {float(err.mean()):.2f} deg "
        f"over {int(ok.sum())} texels"
    )
    assert ok.float().mean() > 0.95
    assert float(err.mean()) < 6.0

    # channel order: I_c / Y_c = albedo_c * shading, so the red/blue ratio of a texel is constant over the
    # lights only when image channels and light_intensities.txt columns are paired correctly
    def spread(Y):
        r = torch.log(sub.intensity[..., 0] / Y[:, None, 0]) - torch.log(sub.intensity[..., 2] / Y[:, None, 2])
        r = torch.where(sub.valid & (sub.intensity.min(-1).values > 0.02), r, torch.nan)
        return float(((r - r.nanmean(0, keepdim=True)) ** 2).nanmean().sqrt())

    assert spread(sub.light_intensity) < 0.75 * spread(sub.light_intensity.flip(-1))


@pytest.mark.skipif(not BALL.is_dir(), reason="../shared/data/diligent_ball missing")
def test_diligent_ball_light_subset():
    surface, obs, stats = load_photometric_stereo(BALL, light_subset=[0, 47, 95])
    assert obs.light_names == ["001.png", "048.png", "096.png"] and stats["lights"] == 3
    dirs = np.loadtxt(BALL / "light_directions.txt")[[0, 47, 95]]
    np.testing.assert_allclose(
        obs.light_dir[:, 0].numpy(), dirs / np.linalg.norm(dirs, axis=1, keepdims=True), atol=1e-6
    )
    np.testing.assert_allclose(
        obs.light_intensity.numpy(), np.loadtxt(BALL / "light_intensities.txt")[[0, 47, 95]], rtol=1e-6
    )
    first = np.asarray(Image.open(BALL / "048.png").convert("RGB"))[surface.mask()].astype(np.int64)
    assert np.abs((np.rint(obs.intensity[1].numpy() * 65535.0).astype(np.int64) >> 8) - first).max() <= 1
