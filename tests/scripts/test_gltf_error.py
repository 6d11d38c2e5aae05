"""scripts/gltf_error.py: its tiny mode renders a small cap both ways through the written .glb; the table and its
command name no machine's paths."""

import importlib.util
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
spec = importlib.util.spec_from_file_location("gltf_error", ROOT / "scripts" / "gltf_error.py")
script = importlib.util.module_from_spec(spec)
sys.modules[spec.name] = script  # dataclasses look their module up there
spec.loader.exec_module(script)


def test_tiny_mode_measures_the_conversions(tmp_path, capsys):
    assert script.main(["--tiny", "--work", str(tmp_path), "--out", str(tmp_path / "table.md")]) == 0
    page = (tmp_path / "table.md").read_text()
    assert "Written by `python scripts/gltf_error.py --tiny`" in page and str(tmp_path) not in page
    row = script.tiny(tmp_path / "again")
    assert row.count > 0 and 0 < row.specular < 0.3  # glTF strength k(sigma) Ps, below Ps = 0.3 at sigma 0.15
    # the fitted conversion is closer to the fitted model than the one-line formula, and undoing glTF's diffuse
    # darkening closes most of the rest; all well under a few DN on this half-glossy cap
    assert row.compensated < row.fitted < row.one_line < 5.0
    # the glossy half's highlights are a few of the observations, and there the fitted lobe is clearly closer
    assert 0 < row.near_share < 0.5 and row.fitted_near < 0.8 * row.one_line_near


def test_ball_missing_is_a_skipped_row(tmp_path):
    row = script.run_config("diligent_ball", tmp_path, False, tmp_path / "no_ball")
    assert row.note.startswith("skipped: no DiLiGenT ball folder") and not (tmp_path / "diligent_ball").exists()


def test_set_overrides_reach_the_fit(tmp_path):
    # a value the config refuses: the fit stops at once, and the row's failure names the forwarded override
    row = script.run_config("quick", tmp_path, False, None, ("fit.iterations=-7",))
    assert row.note.startswith("failed:") and "fit.iterations=-7" in row.note


def test_set_without_an_equals_sign_is_refused(capsys):
    try:
        script.main(["--configs", "quick", "--set", "fit.model"])
    except SystemExit as exc:
        assert exc.code == 2
    assert "--set fit.model: expected KEY=VALUE" in capsys.readouterr().err
