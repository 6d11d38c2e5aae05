"""torchrefl.report.export_run: the files a user takes elsewhere (OBJ + MTL, .glb, 16-bit PNG and EXR maps), read
back with independent readers (trimesh, pygltflib, Pillow, OpenEXR), and the export's named errors."""

import json
import math

import numpy as np
import OpenEXR
import pygltflib
import pytest
import trimesh
from PIL import Image
from reference.gltf_brdf import GlbMaterial
from reference.png_reader import read_png

from torchrefl.errors import GeometryError, OutputError, RunFolderError
from torchrefl.geometry.range_mesh import grid_triangulation
from torchrefl.report.export_run import export_run
from torchrefl.report.run_marker import write_marker
from torchrefl.report.run_result import load_run

H, W = 6, 16  # a full turn of 16 columns: the scan's grid wraps


def srgb8(x):
    """8-bit sRGB of linear x in [0, 1] (IEC 61966-2-1), written out here."""
    x = np.clip(x, 0, 1)
    return np.round(255 * np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055))


def cylinder_run(folder, kind="cylindrical_scan", faces=True, extra=None):
    """A run folder on a cylinder of radius 30 mm (rows along y), texel (0, 0) without an estimate; `grid_faces`
    the wrapped grid triangulation (faces=False: none, a run without geometry)."""
    rng = np.random.default_rng(1)
    phi = 2 * np.pi * (np.arange(W) + 0.5) / W
    y = np.linspace(-10, 10, H)
    n = np.stack([np.broadcast_to(np.sin(phi), (H, W)), np.zeros((H, W)), np.broadcast_to(np.cos(phi), (H, W))], -1)
    positions = 30.0 * n + np.stack([np.zeros((H, W)), np.repeat(y[:, None], W, 1), np.zeros((H, W))], -1)
    mask = np.ones((H, W), dtype=bool)
    mask[0, 0] = False
    params = dict(
        pd=rng.uniform(0.05, 0.95, (H, W, 3)),
        ps=rng.uniform(0.0, 0.5, (H, W, 3)),
        sigma=rng.uniform(0.05, 0.4, (H, W)),
        mask=mask,
        brdf=np.array("torrance_sparrow"),
        positions=positions,
        normals=n,
        kappa=np.full(3, math.pi),
        units=np.array("mm"),
        coverage=np.where(mask, 2, 0).astype(np.int8),
        **(extra or {}),
    )
    if faces:
        params["grid_faces"] = grid_triangulation(positions, np.ones((H, W), bool), wrap=True)[1].astype(np.int32)
    folder.mkdir(parents=True)
    np.savez_compressed(folder / "params.npz", **params)
    metrics = {"model": "local", "brdf": "torrance_sparrow", "texels": H * W, "lights": 2, "rerender": {}}
    (folder / "metrics.json").write_text(json.dumps({**metrics, "timing_s": {"total": 1.0}}))
    (folder / "config.yaml").write_text(f"capture:\n  kind: {kind}\n")
    write_marker(folder)
    return params


def test_scan_export_reads_back_with_trimesh_pygltflib_and_the_fitted_maps(tmp_path):
    p = cylinder_run(tmp_path / "run")
    res = load_run(tmp_path / "run").export(tmp_path / "out")
    assert res.formats == ("maps", "obj", "glb") and all(f.is_file() for f in res.files)
    # OBJ + MTL: every grid point a vertex, the Pd texture as map_Kd, the seam's corners past u = 1
    obj = trimesh.load(tmp_path / "out" / "object.obj", process=False)
    assert len(obj.faces) == 2 * H * W - 2 * W  # (H - 1) rows of W quads: the last column joins the first
    mtl = (tmp_path / "out" / "object.mtl").read_text()
    assert "map_Kd textures/basecolor.png" in mtl
    vt = np.array(
        [
            [float(a) for a in line.split()[1:]]
            for line in (tmp_path / "out" / "object.obj").open()
            if line.startswith("vt ")
        ]
    )
    assert np.isclose(vt[:, 0].max(), 1 + 0.5 / W) and np.isclose(vt[:, 0].min(), 0.5 / W)
    # glb: trimesh and pygltflib read it; positions in metres; the base colour texture is Pd within 1 DN
    scene = trimesh.load(tmp_path / "out" / "object.glb")
    (mesh,) = scene.geometry.values()
    assert len(mesh.faces) == len(obj.faces)
    np.testing.assert_allclose(np.abs(mesh.vertices).max(), np.abs(p["positions"]).max() / 1000, rtol=1e-6)
    gltf = pygltflib.GLTF2().load(str(tmp_path / "out" / "object.glb"))
    assert gltf.materials[0].extensions["KHR_materials_specular"]["specularFactor"] == pytest.approx(
        res.specular_factor
    )
    assert "KHR_materials_specular" in gltf.extensionsUsed
    mat = GlbMaterial(tmp_path / "out" / "object.glb")
    blob = gltf.binary_blob()
    view = gltf.bufferViews[gltf.images[gltf.textures[0].source].bufferView]
    import io

    base = np.asarray(Image.open(io.BytesIO(blob[view.byteOffset : view.byteOffset + view.byteLength])))
    assert base.shape == (H, W, 3)
    assert np.abs(base[p["mask"]].astype(float) - srgb8(p["pd"])[p["mask"]]).max() <= 1
    # texels without an estimate take their neighbour's value in the textures (no black seams)
    assert (base[0, 0] > 0).any()
    assert mat.metallic.max() == 0 and 0 < mat.roughness.min() and mat.roughness.max() <= 1
    # the glTF uv of a vertex lands on its texel: rows from the top (v down)
    uv = mat.uvs
    assert uv[:, 1].min() > 0 and uv[:, 1].max() < 1


def test_value_maps_are_linear_16_bit_and_float_exr(tmp_path):
    p = cylinder_run(tmp_path / "run")
    export_run(tmp_path / "run", tmp_path / "out", formats=["maps"])
    maps = tmp_path / "out" / "maps"
    assert not (tmp_path / "out" / "object.glb").exists()
    pd, bits = read_png(maps / "pd.png")
    assert bits == 16 and pd.shape == (H, W, 4)
    m = p["mask"]
    assert np.abs(pd[..., :3][m] - np.round(p["pd"][m] * 65535)).max() <= 1
    assert (pd[..., 3][m] == 65535).all() and (pd[0, 0] == 0).all()
    sigma = read_png(maps / "sigma.png")[0]
    assert np.abs(sigma[..., 0][m] / 65535 * (math.pi / 2) - p["sigma"][m]).max() < 1e-4
    normals = read_png(maps / "normals.png")[0]
    assert np.abs(normals[..., :3] / 65535 * 2 - 1 - p["normals"]).max() < 1e-4
    coverage, bits = read_png(maps / "coverage.png")
    assert bits == 16
    np.testing.assert_array_equal(coverage[..., 0], p["coverage"])
    with OpenEXR.File(str(maps / "pd.exr")) as f:
        rgba = f.channels()["RGBA"].pixels
    np.testing.assert_array_equal(rgba[..., :3][m], p["pd"][m].astype(np.float32))
    assert (rgba[..., 3] == m).all()


def test_atlas_mesh_export_keeps_the_mesh_uvs(tmp_path):
    # a mesh_views run: params.npz names the mesh (a triangle over the atlas) inside the run folder
    run = tmp_path / "run"
    run.mkdir()
    (run / "mesh.obj").write_text("v 0 0 0\nv 10 0 0\nv 0 10 0\nvt 0.1 0.1\nvt 0.9 0.1\nvt 0.1 0.9\nf 1/1 2/2 3/3\n")
    (run / "params.npz").unlink(missing_ok=True)
    import shutil

    cylinder_run(tmp_path / "tmp", kind="mesh_views", faces=False, extra={"mesh": np.array("mesh.obj")})
    for f in ("params.npz", "metrics.json", "config.yaml"):
        shutil.copy(tmp_path / "tmp" / f, run / f)
    write_marker(run)
    export_run(run, tmp_path / "out")
    obj = trimesh.load(tmp_path / "out" / "object.obj", process=False)
    np.testing.assert_allclose(np.sort(obj.visual.uv[:, 0]), [0.1, 0.1, 0.9])
    glb = GlbMaterial(tmp_path / "out" / "object.glb")
    np.testing.assert_allclose(np.sort(glb.uvs[:, 1]), [0.1, 0.9, 0.9], atol=1e-6)  # v flipped for glTF
    np.testing.assert_allclose(np.abs(glb.positions).max(), 0.01, rtol=1e-6)


def test_a_run_without_geometry_exports_maps_and_refuses_mesh_formats(tmp_path):
    cylinder_run(tmp_path / "run", kind="photometric_stereo", faces=False)
    run = load_run(tmp_path / "run")
    assert run.export(tmp_path / "out").formats == ("maps",)
    assert not (tmp_path / "out" / "object.obj").exists()
    with pytest.raises(GeometryError, match=r"run: export format\(s\) glb need the object's mesh.*no geometry"):
        run.export(tmp_path / "out2", formats=["glb"])


def test_a_scan_run_without_grid_faces_says_to_rerun(tmp_path):
    cylinder_run(tmp_path / "run", faces=False)  # a scan run written before params.npz had grid_faces
    with pytest.raises(GeometryError, match=r"params.npz has no 'grid_faces' \(a scan run written before"):
        export_run(tmp_path / "run", tmp_path / "out", formats=["obj"])


def test_export_errors_name_the_path(tmp_path):
    cylinder_run(tmp_path / "run")
    (tmp_path / "a_file").write_text("not a folder")
    with pytest.raises(OutputError, match=r"a_file is a file, expected a folder"):
        export_run(tmp_path / "run", tmp_path / "a_file")
    (tmp_path / "run" / "run_complete.json").unlink()  # an incomplete run
    with pytest.raises(RunFolderError, match=r"no completeness marker run_complete.json: the run is incomplete"):
        export_run(tmp_path / "run", tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_output_export_switches_the_run_s_export_folder(tmp_path):
    """A run writes export/ (a photometric stereo run: maps only) unless output.export is false."""
    from report.test_run_folder import tiny_capture_args

    from torchrefl.train import main

    assert main(tiny_capture_args(tmp_path, f"output.dir={tmp_path / 'on'}", "--quiet")) == 0
    assert sorted(p.name for p in (tmp_path / "on" / "export").iterdir()) == ["maps"]
    assert (tmp_path / "on" / "export" / "maps" / "pd.exr").is_file()
    assert "export/maps/pd.png" in json.loads((tmp_path / "on" / "run_complete.json").read_text())["files"]
    args = tiny_capture_args(tmp_path, f"output.dir={tmp_path / 'off'}", "output.export=false", "--quiet")
    assert main(args) == 0 and not (tmp_path / "off" / "export").exists()
