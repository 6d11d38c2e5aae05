"""metrics.json's specular_source block: where Ps and sigma come from, per region, and the unmeasured patches;
the summary line that prints the measured share."""

import numpy as np
import pytest

from torchrefl.fit.initialise import (
    COVER_FULL,
    COVER_MATERIAL,
    COVER_NONE,
    COVER_PD_BOUND,
    COVER_PD_ONLY,
    COVER_SHARED,
    COVER_UNTRUSTED,
)
from torchrefl.report.coverage import source_counts, specular_sources, unmeasured_patches
from torchrefl.report.summary import summary_table


def coverage_grid():
    """A 10 x 12 grid: measured everywhere estimated, two interpolated patches (a 3 x 4 one and a 2 x 2 one),
    a Pd-bound texel joined to the big patch diagonally, a rim of untrusted geometry, one texel without data."""
    cov = np.full((10, 12), COVER_FULL, dtype=np.int8)
    cov[0], cov[-1], cov[:, 0], cov[:, -1] = COVER_UNTRUSTED, COVER_UNTRUSTED, COVER_UNTRUSTED, COVER_UNTRUSTED
    cov[2:5, 2:6] = COVER_PD_ONLY
    cov[5, 6] = COVER_PD_BOUND
    cov[7:9, 8:10] = COVER_PD_ONLY
    cov[8, 2] = COVER_NONE
    estimated = (cov != COVER_UNTRUSTED) & (cov != COVER_NONE)
    return cov, estimated


def test_counts_and_shares_add_up_over_the_estimated_texels():
    cov, est = coverage_grid()
    out = source_counts(cov, est)
    assert out["estimated"] == 8 * 10 - 1
    assert out["interpolated"] == 12 + 1 + 4 and out["shared"] == 0
    assert out["measured"] + out["interpolated"] + out["shared"] + out["material"] == out["estimated"]
    assert out["measured_share"] == pytest.approx(out["measured"] / out["estimated"])
    shared = np.where(est, COVER_SHARED, cov)
    assert source_counts(shared, est)["shared_share"] == 1.0
    assert source_counts(cov, np.zeros_like(est))["measured_share"] is None
    pooled = np.where(cov == COVER_PD_ONLY, COVER_MATERIAL, cov)
    assert source_counts(pooled, est)["material"] == 16 and source_counts(pooled, est)["interpolated"] == 1


def test_unmeasured_patches_are_the_largest_connected_interpolated_texels():
    cov, est = coverage_grid()
    patches = unmeasured_patches(cov, est)
    assert patches == [
        {"texels": 13, "rows": [2, 5], "columns": [2, 6]},
        {"texels": 4, "rows": [7, 8], "columns": [8, 9]},
    ]
    assert unmeasured_patches(cov, est, largest=1) == patches[:1]
    assert unmeasured_patches(np.full_like(cov, COVER_FULL), est) == []


def test_texels_with_the_objects_lobe_are_unmeasured_patches_too():
    """The texels far from every highlight take the object's lobe (code 5): the largest area without highlights
    (the fold's lower plate) must be listed, joined with the interpolated texels around it (18 texels set, one
    without data)."""
    cov, est = coverage_grid()
    cov[6:9, 2:8] = np.where(cov[6:9, 2:8] == COVER_FULL, COVER_SHARED, cov[6:9, 2:8])
    patches = unmeasured_patches(cov, est)
    assert patches[0] == {"texels": 12 + 1 + 17 + 4, "rows": [2, 8], "columns": [2, 9]}
    assert len(patches) == 1
    assert unmeasured_patches(np.where(cov == COVER_SHARED, COVER_MATERIAL, cov), est) == patches  # code 7 too


def test_per_region_shares_where_the_truth_has_regions():
    cov, est = coverage_grid()
    region = np.zeros(cov.shape, dtype=np.int64)
    region[:, 6:] = 1
    region[0] = -1
    out = specular_sources(cov, est, region)
    assert set(out["regions"]) == {"0", "1"}
    assert out["regions"]["0"]["interpolated"] == 12 and out["regions"]["1"]["interpolated"] == 5
    assert sum(r["estimated"] for r in out["regions"].values()) == out["estimated"]
    assert "regions" not in specular_sources(cov, est) and len(out["unmeasured_patches"]) == 2
    with pytest.raises(ValueError, match="one \\(H, W\\) grid"):
        specular_sources(cov, est[:5])


def test_the_summary_prints_the_measured_share_and_the_untrusted_texels():
    cov, est = coverage_grid()
    metrics = {
        "timing_s": {"total": 1.0},
        "texels": 120,
        "lights": 3,
        "model": "local",
        "brdf": "torrance_sparrow",
        "rerender": {},
        "coverage": {"estimated": int(est.sum()), "untrusted_geometry": int((cov == COVER_UNTRUSTED).sum())},
        "specular_source": specular_sources(cov, est),
    }
    table = summary_table(metrics)
    assert (
        "Ps/sigma measured at 78.5% of 79 estimated texels (interpolated 21.5%, shared lobe 0.0%, material's lobe "
        "from interreflection 0.0%)" in table
    )
    assert "untrusted geometry: 40 texels not fitted" in table
    assert "largest area without a highlight of its own: 13 texels, rows 2-5, columns 2-6" in table
    metrics["specular_source"] = specular_sources(np.where(est, COVER_FULL, cov), est)
    assert "without a highlight" not in summary_table(metrics)
    del metrics["specular_source"], metrics["coverage"]
    assert "measured at" not in summary_table(metrics)
