"""scripts/vase_profile.py: its tiny mode fits a tiny vase and prints its binned Pd profile."""

import numpy as np
import pytest
from conftest import load_script

vase = load_script("vase_profile")


def test_tiny_mode_prints_the_profile(capsys):
    assert vase.main(["--tiny"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert "largest binned |Pd error| in the neck" in lines[0]
    assert lines[1].startswith("  height mm:") and lines[2].startswith("  median %:")


def test_the_profile_of_a_known_error(tmp_path):
    """A run 10 % above the truth everywhere: every bin's median is +10 %, no texel within 2 %."""
    h = np.linspace(-60, 60, 30)
    positions = np.zeros((30, 4, 3))
    positions[..., 1] = h[:, None]
    truth = np.full((30, 4, 3), 0.4)
    mask = np.ones((30, 4), bool)
    run, cap = tmp_path / "run", tmp_path / "cap"
    run.mkdir(), cap.mkdir()
    np.savez(run / "params.npz", pd=1.1 * truth, mask=mask, positions=positions)
    np.savez(cap / "truth.npz", pd=truth)
    pr = vase.profile(run, cap, 10.0)
    assert np.allclose(pr["median_rel"], 0.1) and pr["within_2pct"] == 0.0
    assert pr["neck_max_abs"] == pytest.approx(0.1)
