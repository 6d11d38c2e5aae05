"""Charts: faces joined by edges continuous in 3-D and in UV."""

import numpy as np
from atlas_meshes import cube_atlas, uv_sphere

from torchrefl.geometry.atlas_charts import face_charts


def test_a_cube_with_a_chart_per_side_has_six_charts():
    chart = face_charts(cube_atlas())
    assert chart.tolist() == [0, 0, 1, 1, 2, 2, 3, 3, 4, 4, 5, 5]


def test_a_seam_inside_one_uv_chart_keeps_it_one_chart():
    # The longitude seam of a lat-long sphere joins the chart to itself; its faces are all one chart.
    assert np.unique(face_charts(uv_sphere(1.0, 6, 12))).tolist() == [0]


def test_a_uv_cut_splits_a_chart():
    mesh = uv_sphere(1.0, 6, 12)
    upper = mesh.uvs[:, :, 1].min(axis=1) >= 0.5
    mesh.uvs[upper, :, 1] += 0.001  # the upper half's UVs no longer meet the lower half's at the equator
    chart = face_charts(mesh)
    assert len(np.unique(chart)) == 2 and (chart[upper] != chart[~upper][0]).all()
