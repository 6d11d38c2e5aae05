"""cylindrical_scan: synthetic scanner against analytic geometry, loader geometry and errors."""

import math
import shutil

import numpy as np
import pytest
import torch
import yaml

from torchrefl.capture.cylindrical_rig import CylindricalRig, light_grid_positions
from torchrefl.capture.cylindrical_scan import load_scan_geometry, load_scan_observations, load_truth, read_scan_yaml
from torchrefl.config import LightGridConfig, SyntheticConfig
from torchrefl.errors import CaptureError
from torchrefl.synthetic.scan import SyntheticScan


def small_cfg(**kw):
    base = dict(
        columns=96,
        rows=80,
        angle_step_deg=360 / 96,
        height_step_mm=2.0,
        size_mm=[50.0, 60.0, 40.0],
        supersample=2,
        mesh_subdivisions=5,
        noise_dn=0.0,
    )
    base.update(kw)
    return SyntheticConfig(**base)


@pytest.fixture(scope="module")
def scan_folder(tmp_path_factory):
    folder = tmp_path_factory.mktemp("scan")
    scan = SyntheticScan(small_cfg(), LightGridConfig(), seed=3)
    scan.write_geometry(folder)
    positions = scan.candidate_positions()[[4, 24, 35]]
    scan.write_textures(folder, positions)
    return folder, scan


def test_head_frame_axes_are_orthonormal_and_co_rotate():
    rig = CylindricalRig(10, 8, 0.0, math.radians(45), 0.0, 1.0, 300.0, 0.0)
    s = rig.angles()
    u, w = CylindricalRig.head_axes(s)
    np.testing.assert_allclose((u * w).sum(-1), 0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(u, axis=-1), 1)
    cam = rig.camera_positions(s)
    # eq. 2.1: the surface point at angle s is r * (-sin s, ., -cos s): the camera is radially outside it
    np.testing.assert_allclose(cam[:, [0, 2]], 300.0 * np.stack([-np.sin(s), -np.cos(s)], -1), atol=1e-9)
    grid = light_grid_positions(10, 6, 50.0, 300.0)
    assert grid.shape == (60, 3) and np.allclose(grid[:, 0].mean(), 0) and grid[0, 1] > grid[-1, 1]


def test_range_image_matches_the_analytic_ellipsoid():
    scan = SyntheticScan(small_cfg(), seed=0)
    r = scan.range_image()
    rig = scan.rig
    S, T = np.meshgrid(rig.angles(), rig.heights())
    a, b, c = scan.axes
    y = -T
    inside = (y / b) ** 2 < 1
    # r(s) on the ellipse cross-section at height y: x = -r sin s, z = -r cos s
    rr = np.sqrt(np.clip(1 - (y / b) ** 2, 0, None) / ((np.sin(S) / a) ** 2 + (np.cos(S) / c) ** 2))
    hit = np.isfinite(r)
    assert (hit == inside).mean() > 0.97
    both = hit & inside
    np.testing.assert_allclose(r[both], rr[both], atol=1e-6)


def test_loader_geometry_against_analytic_normals(scan_folder):
    folder, scan = scan_folder
    geom = load_scan_geometry(folder, threads=1, dtype=torch.float64)
    x = geom.surface.positions.numpy()
    n = geom.surface.normals.numpy()
    a, b, c = scan.axes
    true_n = x / np.array([a, b, c]) ** 2
    true_n /= np.linalg.norm(true_n, axis=-1, keepdims=True)
    ang = np.degrees(np.arccos(np.clip((n * true_n).sum(-1), -1, 1)))
    assert np.median(ang) < 0.5
    on_surface = ((x / np.array([a, b, c])) ** 2).sum(-1)
    assert np.median(np.abs(on_surface - 1)) < 1e-3
    assert len(geom.surface.mesh_faces) > 0 and (geom.surface.areas > 0).all()


def test_observations_and_truth(scan_folder):
    folder, scan = scan_folder
    geom = load_scan_geometry(folder, threads=1, dtype=torch.float64)
    obs, stats = load_scan_observations(geom, threads=1, dtype=torch.float64)
    assert obs.num_lights == 3 and stats["bit_depth"] == 8
    torch.testing.assert_close(obs.light_dir.norm(dim=-1), torch.ones_like(obs.falloff))
    # convex object: no cast shadow can fall on a texel that faces the light
    assert int(obs.shadowed.sum()) <= 0.002 * obs.shadowed.numel()
    truth = load_truth(folder, geom.surface)
    assert truth["pd"].shape == (geom.surface.num_texels, 3)


def test_crease_texels_are_excluded_and_counted(scan_folder):
    """load_scan_observations(crease_angle_deg=...): the smooth ellipsoid has no crease at 60 degrees; at 3
    degrees (its facets' spread at this resolution) some texels count as creases, and every observation of
    theirs is invalid."""
    folder, _ = scan_folder
    geom = load_scan_geometry(folder, threads=1, dtype=torch.float64)
    base, s0 = load_scan_observations(geom, threads=1, dtype=torch.float64)
    smooth, s60 = load_scan_observations(geom, threads=1, dtype=torch.float64, crease_angle_deg=60.0)
    assert s0["crease_texels_excluded"] == 0 and s60["crease_texels_excluded"] == 0
    assert torch.equal(base.valid, smooth.valid)
    tight, s3 = load_scan_observations(geom, threads=1, dtype=torch.float64, crease_angle_deg=3.0)
    assert 0 < s3["crease_texels_excluded"] < geom.surface.num_texels
    lost = base.valid.any(0) & ~tight.valid.any(0)
    assert int(lost.sum()) > 0 and bool((tight.valid <= base.valid).all())


def raised_block(folder, tmp_path):
    """A copy of the scan folder with a block raised 6 mm from the ellipsoid: (folder, its range image)."""
    step = tmp_path / "step"
    shutil.copytree(folder, step)
    r = np.load(step / "range.npy")
    r[30:46, 40:56] += 6.0
    np.save(step / "range.npy", r)
    return step, r


def test_a_raised_block_is_a_mixed_footprint_excluded_and_counted(scan_folder, tmp_path):
    """A block raised 6 mm from the smooth ellipsoid (a plate's rim, a depth step): the texels along its rim are
    mixed footprints (ScanGeometry.mixed), none of their observations is valid, and the statistics count them;
    the smooth ellipsoid, the block's top and the surface around it are not flagged."""
    folder, _ = scan_folder
    assert not load_scan_geometry(folder, threads=1, dtype=torch.float64).mixed.any()
    step, r = raised_block(folder, tmp_path)
    geom = load_scan_geometry(step, threads=1, dtype=torch.float64)
    grid = np.zeros(r.size, bool)
    grid[geom.surface.texel_index.numpy()] = geom.mixed
    grid = grid.reshape(r.shape)
    assert grid[33:43, 39:41].all() and grid[33:43, 55:57].all() and grid[29:31, 43:53].all()
    assert not grid[33:43, 43:53].any() and not grid[33:43, 30:37].any() and not grid[:20].any()
    obs, stats = load_scan_observations(geom, threads=1, dtype=torch.float64)
    mixed = torch.from_numpy(geom.mixed)
    assert not obs.valid[:, mixed].any() and stats["mixed_footprint_texels_excluded"] == int(mixed.sum())


def test_textures_are_deterministic_and_noise_is_seeded(tmp_path):
    cfg = small_cfg(noise_dn=2.0)
    a = SyntheticScan(cfg, seed=5).render_texture([0.0, 0.0, 300.0])
    b = SyntheticScan(cfg, seed=5).render_texture([0.0, 0.0, 300.0])
    c = SyntheticScan(cfg, seed=6).render_texture([0.0, 0.0, 300.0])
    assert (a == b).all() and (a != c).any()


def test_supersampled_texture_agrees_with_noise_free_model(scan_folder):
    """Rendered at 2x2 sub-samples, each texel's value is close to the local model at its centre."""
    from torchrefl.transport.local import local_terms, predict

    folder, scan = scan_folder
    geom = load_scan_geometry(folder, threads=1, dtype=torch.float64)
    obs, _ = load_scan_observations(geom, threads=1, dtype=torch.float64)
    truth = load_truth(folder, geom.surface)
    pred = predict(local_terms("torrance_sparrow", geom.surface.normals, obs), truth["pd"], truth["ps"], truth["sigma"])
    m = obs.valid & (pred.max(-1).values < 0.9)
    err = ((pred - obs.intensity).abs() * 255)[m]
    assert err.median() < 1.0


def test_missing_and_bad_files(tmp_path, scan_folder):
    folder, _ = scan_folder
    with pytest.raises(CaptureError, match="capture folder not found"):
        read_scan_yaml(tmp_path / "nope")
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(CaptureError, match="scan.yaml.*not found"):
        read_scan_yaml(empty)
    doc = yaml.safe_load((folder / "scan.yaml").read_text())
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "range.npy").write_bytes((folder / "range.npy").read_bytes())
    doc2 = dict(doc, light={"intensity": [1.0, -2.0, 1.0]})
    (bad / "scan.yaml").write_text(yaml.safe_dump(doc2))
    with pytest.raises(CaptureError, match="light.intensity.*positive"):
        read_scan_yaml(bad)
    doc3 = dict(doc, lights=[{"image": "textures/000.png"}])
    (bad / "scan.yaml").write_text(yaml.safe_dump(doc3))
    with pytest.raises(CaptureError, match=r"lights\[0\].*position_mm"):
        read_scan_yaml(bad)
    doc4 = dict(doc, lights=[{"image": "textures/000.png", "position_mm": [0, 0, 300]}])
    (bad / "scan.yaml").write_text(yaml.safe_dump(doc4))
    geom = load_scan_geometry(bad, threads=1)
    with pytest.raises(CaptureError, match="000.png"):
        load_scan_observations(geom, threads=1)


def test_texture_size_mismatch_names_the_file(tmp_path, scan_folder):
    from torchrefl.capture.images import write_png

    folder, _ = scan_folder
    bad = tmp_path / "mismatch"
    bad.mkdir()
    (bad / "range.npy").write_bytes((folder / "range.npy").read_bytes())
    (bad / "textures").mkdir()
    write_png(bad / "textures" / "000.png", np.zeros((10, 12, 3)), bits=8)
    doc = yaml.safe_load((folder / "scan.yaml").read_text())
    doc["lights"] = [{"image": "textures/000.png", "position_mm": [0, 0, 300]}]
    (bad / "scan.yaml").write_text(yaml.safe_dump(doc))
    geom = load_scan_geometry(bad, threads=1)
    with pytest.raises(CaptureError, match="000.png.*expected 96x80"):
        load_scan_observations(geom, threads=1)


def test_range_without_any_surface(tmp_path, scan_folder):
    folder, _ = scan_folder
    bad = tmp_path / "blank"
    bad.mkdir()
    np.save(bad / "range.npy", np.full((8, 8), np.nan, dtype=np.float32))
    (bad / "scan.yaml").write_text((folder / "scan.yaml").read_text())
    with pytest.raises(CaptureError, match="selects nothing"):
        load_scan_geometry(bad, threads=1)


def test_saturated_pixels_are_excluded_and_counted(tmp_path):
    scan = SyntheticScan(small_cfg(light_intensity=400000.0), seed=2)
    scan.write_geometry(tmp_path)
    scan.write_textures(tmp_path, scan.candidate_positions()[[24]])
    geom = load_scan_geometry(tmp_path, threads=1)
    obs, stats = load_scan_observations(geom, threads=1, saturation_level=0.995)
    assert stats["saturated_observations"] > 0
    assert not (obs.valid & obs.saturated).any()
    assert int(obs.saturated.sum()) >= stats["saturated_observations"]


def test_a_strip_no_fitting_window_describes_is_excluded_and_counted(scan_folder, tmp_path):
    """The ellipsoid cut at its equator, with two rows bent 45 degrees back below the cut (a plate's end face
    narrower than the 5 x 5 fitting window): their normals are extrapolated across the crease, so they are
    untrusted (ScanGeometry.unfit), none of their observations is valid, and the statistics count them."""
    folder, _ = scan_folder
    strip = tmp_path / "strip"
    shutil.copytree(folder, strip)
    r = np.load(strip / "range.npy")
    m = r.shape[0] // 2
    dt = float(yaml.safe_load((strip / "scan.yaml").read_text())["grid"]["height_step_mm"])
    r[m + 1] = r[m] - 1.0 * dt
    r[m + 2] = r[m] - 2.0 * dt
    r[m + 3 :] = np.nan
    np.save(strip / "range.npy", r)
    geom = load_scan_geometry(strip, threads=1, dtype=torch.float64)
    grid = np.zeros(r.size, bool)
    grid[geom.surface.texel_index.numpy()] = geom.unfit
    grid = grid.reshape(r.shape)
    centre = slice(r.shape[1] // 2 - 10, r.shape[1] // 2 + 10)
    assert grid[m + 1 : m + 3, centre].all()
    assert not grid[m - 12 : m - 2, centre].any()  # the equatorial band (the caps turn too fast at 2 mm rows)
    obs, stats = load_scan_observations(geom, threads=1, dtype=torch.float64)
    unfit = torch.from_numpy(geom.unfit & ~geom.mixed)
    assert not obs.valid[:, unfit].any() and stats["unfit_range_texels_excluded"] == int(unfit.sum()) > 0


def test_observations_at_a_cast_shadows_edge_are_excluded_and_counted(scan_folder, tmp_path):
    """The raised block casts shadows on the ellipsoid: the lit observations next to a shadowed texel of the same
    face (capture.shadow_edges) are invalid and counted; the smooth ellipsoid has none."""
    from torchrefl.capture.shadow_edges import face_neighbours, shadow_edge_observations

    folder, _ = scan_folder
    _, smooth = load_scan_observations(load_scan_geometry(folder, threads=1, dtype=torch.float64), threads=1)
    assert smooth["shadowed_observations"] == 0 and smooth["shadow_edge_observations"] == 0
    step, r = raised_block(folder, tmp_path)
    geom = load_scan_geometry(step, threads=1, dtype=torch.float64)
    obs, stats = load_scan_observations(geom, threads=1, dtype=torch.float64)
    s = geom.surface
    edge = shadow_edge_observations(obs.shadowed.numpy(), face_neighbours(s.neighbours, s.normals.numpy()))
    assert stats["shadowed_observations"] > 0 and edge.sum() > 0
    assert not obs.valid[torch.from_numpy(edge)].any()
    assert 0 < stats["shadow_edge_observations"] <= int(edge.sum())
