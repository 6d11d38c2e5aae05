"""python -m torchrefl.render: a relit PNG and a turntable from a run folder, and its named errors (exit status 2)."""

import json

import numpy as np
import pytest
from conftest import write_grid_run

from torchrefl import render
from torchrefl.capture.images import read_image


def _cap_run(folder):
    """A run folder on a spherical cap of radius 50 mm (a 24 x 24 texel grid), diffuse and glossy."""
    u, v = np.meshgrid(np.linspace(-0.6, 0.6, 24), np.linspace(-0.6, 0.6, 24))
    n = np.stack([u, -v, np.sqrt(1.0 - u * u - v * v)], -1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    write_grid_run(folder, 50.0 * n, n, pd=(0.6, 0.4, 0.2), ps=0.3, sigma=0.15)
    return folder


def test_a_relit_png_and_a_turntable(tmp_path, capsys):
    run = _cap_run(tmp_path / "run")
    out = tmp_path / "relit.png"
    args = [str(run), "--camera", "orbit 0 0 200", "--light", "orbit 20 30 300", "--size", "48x40", "--quiet"]
    assert render.main([*args, "--out", str(out), "--encoding", "linear16"]) == 0
    image, bits = read_image(out)
    assert image.shape == (40, 48, 3) and bits == 16
    assert image[20, 24].min() > 0.05 and image[0, 0].max() == 0  # the cap in the middle, background black
    assert render.main([*args, "--out", str(out)]) == 2  # exists: --overwrite replaces it
    assert "exists" in capsys.readouterr().err
    frames = tmp_path / "turn"
    assert render.main([*args, "--turntable", "4", "--out", str(frames)]) == 0
    names = sorted(p.name for p in frames.iterdir())
    assert names == [*(f"frame_{k:03d}.png" for k in range(4)), "turntable.gif"]
    first, _ = read_image(frames / "frame_000.png")
    behind, _ = read_image(frames / "frame_002.png")
    assert first[20, 24].max() > 0.05 and behind.max() == 0  # turned by 180 degrees: the cap faces away


@pytest.mark.parametrize(
    "out, extra, match",
    [
        ("{tmp}", [], "is a folder"),
        ("{tmp}/missing/relit.png", [], "does not exist"),
        ("{tmp}/relit.jpg", [], "expected a .png"),
        ("{tmp}/file.txt", ["--turntable", "2"], "is a file"),
        ("{tmp}/relit.png", ["--camera", "orbit 0 0 10"], "inside the object's bounding sphere"),
        ("{tmp}/relit.png", ["--camera", "sideways"], "expected 'orbit AZ EL"),
        ("{tmp}/relit.png", ["--light", "point 1 2"], "expected 3 finite numbers"),
        ("{tmp}/relit.png", ["--light", "dir 0 0 1", "--intensity", "-1"], "intensity"),
        ("{tmp}/relit.png", ["--camera", "photographs"], "not photometric stereo"),
        ("{tmp}/relit.png", ["--light", "{tmp}/lights.json"], "holds 2 lights; name one"),
        ("{tmp}/relit.png", ["--light", "{tmp}/lights.json:c"], "has no light 'c' (it has a, b)"),
    ],
)
def test_bad_arguments_are_named_errors(tmp_path, capsys, out, extra, match):
    run = _cap_run(tmp_path / "run")
    (tmp_path / "file.txt").write_text("a file")
    lights = {k: {"position": [0, 0, 500 + i], "intensity": [1, 1, 1]} for i, k in enumerate("ab")}
    (tmp_path / "lights.json").write_text(json.dumps(lights))
    extra = [e.format(tmp=tmp_path) for e in extra]
    assert render.main([str(run), "--out", out.format(tmp=tmp_path), "--size", "8x8", "--quiet", *extra]) == 2
    assert match in capsys.readouterr().err


def test_an_incomplete_run_folder_is_a_named_error(tmp_path, capsys):
    run = _cap_run(tmp_path / "run")
    (run / "run_complete.json").unlink()
    assert render.main([str(run), "--out", str(tmp_path / "x.png"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "run_complete.json" in err or "incomplete" in err
