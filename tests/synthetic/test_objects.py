"""Mesh objects of the synthetic scans: the vase's geometry and materials, and what the cylindrical scanner
sees of it (all of it) against the bowl (about a third of its inside)."""

import numpy as np
import pytest
import trimesh

from torchrefl.config import SyntheticConfig
from torchrefl.synthetic.materials import region_materials
from torchrefl.synthetic.objects import vase
from torchrefl.synthetic.scan import SyntheticScan

LIGHT = np.array([0.0, 50.0, 300.0])


def cfg(**kw):
    base = dict(
        object="vase",
        columns=128,
        rows=112,
        angle_step_deg=360 / 128,
        height_step_mm=2.0,
        supersample=1,
        noise_dn=0.0,
        indirect_samples=0,
    )
    base.update(kw)
    return SyntheticConfig(**base)


def test_the_vase_is_a_closed_outward_mesh_with_exact_normals():
    obj = vase()
    m = trimesh.Trimesh(obj.vertices, obj.faces, process=False)
    assert m.is_watertight and m.is_winding_consistent and m.volume > 0
    n = obj.normal(m.triangles_center, np.arange(len(m.faces)))
    assert ((n * m.face_normals).sum(-1) > 0.999).all()
    assert obj.material is None  # texel-aligned maps, given by the scanner


def test_the_vase_profile_is_c1_with_a_concave_neck():
    prof = vase().info["profile"]
    y = np.linspace(-55.0, 55.0, 22001)
    r = prof.radius(y)
    assert np.abs(np.diff(r)).max() < 0.01  # continuous (steps of 0.005 mm)
    np.testing.assert_allclose(np.gradient(r, y)[2:-2], prof.slope(y)[2:-2], atol=2e-3)
    neck = np.abs(y) < prof.y_edge - 0.5
    assert (np.gradient(np.gradient(r, y), y)[neck] > 0).all()  # r'' > 0: the neck is concave seen from outside
    assert r.min() == pytest.approx(prof.core, abs=1e-6) and r.max() == pytest.approx(prof.r_max, abs=1e-6)
    assert np.abs(prof.slope(y)).max() == pytest.approx(np.tan(np.radians(60.0)), rel=1e-3)  # flank slope at the edges


def seen_share(scan, points):
    """Share of surface points that the scanner's ray through their own (angle, height) hits first."""
    s = np.arctan2(-points[:, 0], -points[:, 2])
    o, d = scan._scan_rays(s, -points[:, 1])
    p, _, _, _, hit = scan._mesh_scan(o, d)
    return float((hit & (np.linalg.norm(p - points, axis=-1) < 0.05)).mean())


def area_samples(obj, faces, n=4000, seed=0):
    m = trimesh.Trimesh(obj.vertices, obj.faces[faces], process=False)
    pts, _ = trimesh.sample.sample_surface(m, n, seed=seed)
    return pts


def test_the_scanner_sees_all_of_the_vase_and_a_third_of_the_bowls_inside():
    v = SyntheticScan(cfg(), seed=0)
    prof = v.object.info["profile"]
    assert seen_share(v, area_samples(v.object, np.arange(v.object.info["side_faces"]))) > 0.995
    b = SyntheticScan(cfg(object="bowl"), seed=0)
    assert seen_share(b, area_samples(b.object, np.arange(b.object.info["inner_faces"]))) < 0.5
    # every scan line through the vase's side hits it on the profile, in front of the axis
    r = v.range_image()
    heights = -v.rig.heights()
    side = np.abs(heights) < 56.0 - 1.0
    assert np.isfinite(r[side]).all() and not np.isfinite(r[np.abs(heights) > 56.0]).any()
    np.testing.assert_allclose(r[side], np.broadcast_to(prof.radius(heights[side])[:, None], r[side].shape), atol=0.01)
    # and the camera sees every scanned texel of the side (the shoulders hide no part of the neck)
    count = v._subsamples()["count"].reshape(r.shape)
    assert (count[side] > 0).all()


def test_the_vase_materials_are_the_texel_maps_everywhere():
    v = SyntheticScan(cfg(), seed=3)
    maps = region_materials(112, 128, seed=3)
    hit = v.truth["texel_hit"]
    for k in ("pd", "ps", "sigma", "region"):
        np.testing.assert_array_equal(v.truth[k][hit], maps[k][hit])
    assert len(np.unique(v.truth["region"][hit])) >= 4 and v.truth["sigma"][hit].std() > 0.01
    # path vertices anywhere on the side take the material of the texel they are scanned at
    pts = area_samples(v.object, np.arange(1000), n=200, seed=1)
    rows = np.round((-pts[:, 1] - v.rig.height0) / v.rig.height_step).astype(int)
    cols = np.round(np.mod(np.arctan2(-pts[:, 0], -pts[:, 2]), 2 * np.pi) / v.rig.angle_step).astype(int) % 128
    m = v._material_at(pts, np.zeros(len(pts), dtype=np.int64))
    np.testing.assert_array_equal(m["pd"], maps["pd"][rows, cols])


def test_the_vases_neck_receives_interreflection_and_its_body_almost_none():
    direct = SyntheticScan(cfg(materials="uniform"), seed=0).radiance_image(LIGHT)
    full = SyntheticScan(cfg(materials="uniform", indirect_samples=32), seed=0).radiance_image(LIGHT)
    heights = -SyntheticScan(cfg(), seed=0).rig.heights()
    cols = slice(48, 80)  # facing the head
    lit = direct[:, cols, 0] > 0.02
    ratio = np.where(lit, full[:, cols, 0] / np.where(lit, direct[:, cols, 0], 1.0) - 1.0, np.nan)
    neck = np.abs(heights) < 12.0
    body = np.abs(heights) > 50.0
    assert np.nanmean(ratio[neck]) > 0.04  # the local model would overestimate Pd there
    assert np.nanmean(ratio[body & (np.abs(heights) < 55.0)]) < 0.01
