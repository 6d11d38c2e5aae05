"""scripts/photon_noise_at_truth.py in its tiny mode on the tiny fold: the indirect light's error and noise rows."""

from conftest import load_script

noise = load_script("photon_noise_at_truth")


def test_tiny_mode_on_the_tiny_fold(tiny_fold_run, capsys):
    assert noise.main(["--tiny", str(noise.FOLD), str(tiny_fold_run / "capture")]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[1].startswith("indirect light removed |")
    true_row, defaults = lines[2].split(" | "), lines[3].split(" | ")
    assert true_row[:3] == ["true indirect light", "-", "-"]
    assert defaults[0] == "defaults" and float(defaults[1]) >= 0 and float(defaults[2]) >= 0
