"""scripts/uncertainty_calibration.py: the interval shares against the normal distribution's, and its tiny mode
fits a re-drawn capture and prints the calibration table; --runs pools finished runs to the same table."""

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
spec = importlib.util.spec_from_file_location(
    "uncertainty_calibration", ROOT / "scripts" / "uncertainty_calibration.py"
)
calibration = importlib.util.module_from_spec(spec)
sys.modules[spec.name] = calibration
spec.loader.exec_module(calibration)


def test_interval_shares_of_known_z_scores():
    z = np.array([0.0, 0.5, -1.0, 1.5, -1.9, 2.0, 2.6, -3.5])
    # |z| <= 1.96 for 5 of 8; <= 0.6745 (the 50 % interval) for 2 of 8
    assert calibration.covered(z, np.array([0.95, 0.5])).tolist() == [5 / 8, 2 / 8]


def test_tiny_mode_prints_the_table(tmp_path, capsys):
    out = tmp_path / "cal"
    assert calibration.main(["--tiny", "--seeds", "1", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "| parameter | level |" in text and "| sigma | local |" in text
    rows = json.loads((out / "calibration.json").read_text())
    assert {r["parameter"] for r in rows} == {"pd", "ps", "sigma"}
    assert all(r["count"] > 0 and 0.0 <= r["coverage_95"] <= 1.0 for r in rows)
    assert (out / "calibration.png").stat().st_size > 0
    # the finished run pooled again, without a fit: the same z-scores
    again = tmp_path / "again"
    assert calibration.main(["--runs", str(out / "noise_0"), "--out", str(again)]) == 0
    assert json.loads((again / "calibration.json").read_text()) == rows


def test_profile_curvature_of_a_circular_profile():
    # rows along an arc of radius 20: outward normals are convex (+1/20), inward ones concave (-1/20)
    from types import SimpleNamespace

    t = np.linspace(0.0, 1.0, 9)[:, None].repeat(4, 1)
    n = np.stack([np.sin(t), np.cos(t), np.zeros_like(t)], -1)
    run = SimpleNamespace(positions=20.0 * n, normals=n)
    k = calibration.profile_curvature(run)
    assert np.allclose(k[1:-1], 1 / 20) and np.all(k[[0, -1]] == 0)
    run.normals = -n
    assert np.allclose(calibration.profile_curvature(run)[1:-1], -1 / 20)
