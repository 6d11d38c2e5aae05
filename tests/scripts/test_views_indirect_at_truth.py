"""scripts/views_indirect_at_truth.py in its tiny mode on a tiny bowl: the converged, photon-level and capture rows and
the two local fits."""

from conftest import load_script

script = load_script("views_indirect_at_truth")


def test_tiny_mode_on_a_tiny_bowl(capsys):
    assert script.main(["--tiny"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("converged render: 16 paths x 2")
    header = lines[1].split(" | ")
    assert header[0] == "indirect light" and header[-1] == "RMS vs converged (DN)"
    rows = {line.split(" | ")[0]: line.split(" | ") for line in lines[2:9]}
    assert float(rows["converged (DN)"][1]) > 0  # the bowl's inside lights itself
    for name in ("photon level / converged", "capture / converged"):
        assert float(rows[name][-1]) >= 0
    fits = [line.split(" | ") for line in lines[-2:]]
    assert [f[0] for f in fits] == ["the converged indirect light", "the photon level's"]
    assert all(0 <= float(f[1]) < 10 for f in fits)
