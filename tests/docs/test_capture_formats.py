"""docs/capture-formats.md: the mesh_views worked example, copied from the page, reads as the page says."""

import re
from pathlib import Path

import numpy as np
import pytest
import torch

from torchrefl.capture.images import write_png
from torchrefl.capture.view_folder import read_view_folder

PAGE = Path(__file__).resolve().parents[2] / "docs" / "capture-formats.md"


def _example_files() -> dict[str, str]:
    """The JSON blocks of the mesh_views worked example, by the file name in the sentence before each."""
    text = PAGE.read_text()
    section = text[text.index("### A worked example") :]
    section = section[: section.index("\n## ")]
    blocks = re.findall(r"`(\w+\.json)`[^\n]*:\n\n```json\n(.*?)```", section, flags=re.S)
    return dict(blocks)


def test_worked_example_reads_and_projects_as_stated(tmp_path):
    files = _example_files()
    assert sorted(files) == ["cameras.json", "images.json", "lights.json"]
    for name, content in files.items():
        (tmp_path / name).write_text(content)
    (tmp_path / "images").mkdir()
    for name in ("front_top", "front_side", "left_top", "left_side"):
        write_png(tmp_path / "images" / f"{name}.png", np.zeros((1200, 1600), dtype=np.uint16), 16)
    view = read_view_folder(tmp_path)
    assert view.camera_index.tolist() == [0, 0, 1, 1] and view.light_index.tolist() == [0, 1, 0, 1]
    assert view.views.images[3].exposure == 2.0 and view.warnings == ()
    assert view.cameras.centres().tolist() == [[0.0, 0.0, 500.0], [-500.0, 0.0, 0.0]]
    # the page's hand computation: (10, 20, 0) in `front` is (-10, 20, 500); k1 = -0.05, k2 = 0.01
    x, y = -10 / 500, 20 / 500
    r2 = x * x + y * y
    radial = 1 - 0.05 * r2 + 0.01 * r2 * r2
    uv = view.cameras.project(torch.tensor([[10.0, 20.0, 0.0]], dtype=torch.float64), camera=0).uv[0]
    assert uv.tolist() == pytest.approx([2400 * x * radial + 799.5, 2400 * y * radial + 599.5], abs=1e-9)
    assert uv.tolist() == pytest.approx([751.505, 695.490], abs=1e-3)  # as the page prints them
