"""scripts/reproduce_object_e.py: its tiny mode fits setup 2 with the three methods and writes the table."""

import json

from conftest import load_script

repro = load_script("reproduce_object_e")


def test_tiny_mode_fits_the_three_methods(tmp_path):
    assert repro.main(["--tiny", "--out", str(tmp_path)]) == 0
    rows = json.loads((tmp_path / "object_e.json").read_text())
    assert [(r["setup"], r["method"], r["level"]) for r in rows] == [(2, "I", "local"), (2, "II", "radiosity"),
                                                                     (2, "III", "photon")]  # fmt: skip
    assert (tmp_path / "pd_profiles.png").stat().st_size > 0
