"""The scale check of a cylindrical_scan folder (capture/scan_scale.py, issue 33 finding 6): the default synthetic
scene (its object, camera and light grid) on a coarse grid, written with its range image or its lights in the
wrong unit."""

import json
import shutil

import numpy as np
import pytest
import yaml

from capture.test_capture_checks import config
from torchrefl.capture.cylindrical_scan import CylindricalScanLoader, load_scan_geometry
from torchrefl.capture.scan_scale import head_distances
from torchrefl.config import LightGridConfig, SyntheticConfig
from torchrefl.errors import CaptureError, GeometryError
from torchrefl.synthetic.scan import SyntheticScan
from torchrefl.train import main


def default_scene_coarse():
    """configs/default.yaml's scene (62 x 95 x 50 mm ellipsoid, camera at 300 mm, 5 cm light grid at 300 mm) on a
    96 x 80 grid of 3.75 deg x 2.5 mm."""
    cfg = SyntheticConfig(columns=96, rows=80, angle_step_deg=3.75, height_step_mm=2.5, supersample=1, noise_dn=0.0)
    return SyntheticScan(cfg, LightGridConfig(), seed=0)


@pytest.fixture(scope="module")
def master(tmp_path_factory):
    """The scene's folder with two rendered textures (light 0, light 1 of the candidate grid's middle)."""
    folder = tmp_path_factory.mktemp("scale_master")
    scan = default_scene_coarse()
    scan.write_geometry(folder)
    scan.write_textures(folder, scan.candidate_positions()[[24, 35]])
    return folder


@pytest.fixture
def scan(master, tmp_path):
    folder = tmp_path / "scan"
    shutil.copytree(master, folder)
    return folder


def rescale_range(folder, factor):
    np.save(folder / "range.npy", (np.load(folder / "range.npy") * factor).astype(np.float32))


def rescale_lights(folder, factor):
    doc = yaml.safe_load((folder / "scan.yaml").read_text())
    for light in doc["lights"]:
        light["position_mm"] = [x * factor for x in light["position_mm"]]
    (folder / "scan.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))


def test_the_scene_in_mm_passes_without_warning(scan):
    assert load_scan_geometry(scan, threads=1).scale_warnings == []
    capture = CylindricalScanLoader().load(scan, config("cylindrical_scan", scan), [].append)
    assert not [w for w in capture.warnings if "radius" in w]


def test_a_range_image_in_metres_is_refused_naming_the_file(scan):
    rescale_range(scan, 0.001)
    with pytest.raises(GeometryError) as exc:
        load_scan_geometry(scan, threads=1)
    msg = str(exc.value)
    assert msg.startswith(f"{scan / 'range.npy'}: the ranges look like metres")
    assert "range.scale_mm: 1000" in msg and "camera.distance_mm" in msg and "lights[" in msg


def test_a_range_image_in_metres_with_its_scale_given_is_accepted(scan):
    rescale_range(scan, 0.001)
    doc = yaml.safe_load((scan / "scan.yaml").read_text())
    doc["range"]["scale_mm"] = 1000.0
    (scan / "scan.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    assert load_scan_geometry(scan, threads=1).scale_warnings == []


def test_a_wrong_range_scale_is_refused_saying_what_to_multiply_it_by(scan):
    doc = yaml.safe_load((scan / "scan.yaml").read_text())
    doc["range"]["scale_mm"] = 0.001  # millimetres declared as micrometres
    (scan / "scan.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    with pytest.raises(GeometryError, match=r"multiply range\.scale_mm \(0\.001\) in .*scan\.yaml by 1000"):
        load_scan_geometry(scan, threads=1)


def test_a_range_image_in_centimetres_is_warned_into_the_capture_warnings(scan):
    """A factor 10 is also a 6 mm object on the same rig, so it cannot be refused: it is a warning, in the capture's
    warnings (the log and metrics.json capture.warnings)."""
    rescale_range(scan, 0.1)
    capture = CylindricalScanLoader().load(scan, config("cylindrical_scan", scan), [].append)
    ours = [w for w in capture.warnings if "look like centimetres" in w]
    assert len(ours) == 1 and ours[0].startswith(str(scan / "range.npy")) and "range.scale_mm: 10" in ours[0]


def test_lights_in_metres_beside_a_range_in_mm_are_refused(scan):
    rescale_lights(scan, 0.001)
    with pytest.raises(CaptureError, match=r"lights\[\*\]\.position_mm in .*scan\.yaml look like metres"):
        load_scan_geometry(scan, threads=1)


def test_lights_in_a_manifest_are_named_by_the_manifest(scan):
    doc = yaml.safe_load((scan / "scan.yaml").read_text())
    lines = [{**e, "position_mm": [x * 0.001 for x in e["position_mm"]]} for e in doc["lights"]]
    (scan / "manifest.jsonl").write_text("".join(json.dumps(e) + "\n" for e in lines))
    doc["lights"] = "manifest.jsonl"
    (scan / "scan.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    with pytest.raises(CaptureError, match=r"lights\[\*\]\.position_mm in .*manifest\.jsonl look like metres"):
        load_scan_geometry(scan, threads=1)


def test_head_distances_are_about_the_axis():
    np.testing.assert_allclose(head_distances([[30.0, 500.0, 40.0], [0.0, -9.0, 300.0]]), [50.0, 300.0])


def test_the_command_line_refuses_a_range_in_metres_in_one_line(scan, tmp_path, capsys):
    """The case of issue 33: a range image in metres fitted silently to a wrong answer and exit 0; now exit 2 with
    one message that names range.npy and the fix."""
    rescale_range(scan, 0.001)
    cfg = tmp_path / "run.yaml"
    cfg.write_text(yaml.safe_dump({"capture": {"kind": "cylindrical_scan", "path": str(scan)}}))
    assert main([str(cfg), f"output.dir={tmp_path / 'out'}", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "range.npy: the ranges look like metres" in err and "range.scale_mm: 1000" in err
    assert "Traceback" not in err
