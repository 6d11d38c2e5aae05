"""The vase's Pd profile: relative Pd error of fitted runs binned by height, and the share of texels within 2 %.

For every run folder (python -m torchrefl.train configs/concave.yaml ...) the estimated texels' Pd (channel mean)
is compared with the capture's truth.npz, the relative error is binned by the texel's height (the vase's neck
is the middle of the range, its flanks at +-35 mm), and the script prints the median relative error per bin
(percent), the largest of those within the neck (|height| < 35 mm), and the share of all estimated texels within
2 % of the truth.

    python scripts/vase_profile.py RUN [RUN ...] [--capture CAPTURE_FOLDER] [--bin-mm 4]

--capture names the capture folder when a run fitted an existing one (capture.kind=cylindrical_scan); by
default a run's own RUN/capture is used.

    python scripts/vase_profile.py --tiny      # a tiny vase fitted with Method I, then its profile (the test's mode)
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from tiny_mode import ROOT, tiny_run  # noqa: E402

NECK_MM = 35.0


def profile(run: Path, capture: Path, bin_mm: float) -> dict:
    """{'centres': (B,) mm, 'median_rel': (B,), 'neck_max_abs': float, 'within_2pct': float}."""
    for f in (run / "params.npz", capture / "truth.npz"):
        if not f.exists():
            sys.exit(f"vase_profile: {f} does not exist (expected a torchrefl run folder and its capture)")
    p, t = np.load(run / "params.npz"), np.load(capture / "truth.npz")
    if p["pd"].shape != t["pd"].shape:
        sys.exit(
            f"vase_profile: {run / 'params.npz'} has a {p['pd'].shape[:2]} grid, {capture / 'truth.npz'} "
            f"{t['pd'].shape[:2]}: not the same capture"
        )
    mask = p["mask"] & (t["pd"].mean(-1) > 0)
    rel = p["pd"].mean(-1)[mask] / t["pd"].mean(-1)[mask] - 1.0
    height = p["positions"][..., 1][mask].astype(np.float64)
    edges = np.arange(np.floor(height.min() / bin_mm) * bin_mm, height.max() + bin_mm, bin_mm)
    which = np.digitize(height, edges) - 1
    centres, med = [], []
    for b in range(len(edges) - 1):
        v = rel[which == b]
        if v.size:
            centres.append(0.5 * (edges[b] + edges[b + 1]))
            med.append(float(np.median(v)))
    centres, med = np.array(centres), np.array(med)
    neck = np.abs(centres) < NECK_MM
    return {
        "centres": centres,
        "median_rel": med,
        "neck_max_abs": float(np.abs(med[neck]).max()) if neck.any() else float("nan"),
        "within_2pct": float((np.abs(rel) < 0.02).mean()),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="*", type=Path)
    ap.add_argument("--capture", type=Path, default=None)
    ap.add_argument("--bin-mm", type=float, default=4.0)
    ap.add_argument("--tiny", action="store_true", help="fit a tiny vase (Method I) and profile it: seconds")
    args = ap.parse_args(argv)
    if args.tiny:
        run = tiny_run(
            Path(tempfile.mkdtemp(prefix="vase_profile_")) / "run", ROOT / "configs" / "concave.yaml", "local"
        )
        args.runs, args.bin_mm = [run], 20.0
    if not args.runs:
        ap.error("give run folders, or --tiny")
    for run in args.runs:
        pr = profile(run, args.capture or run / "capture", args.bin_mm)
        print(
            f"{run}: largest binned |Pd error| in the neck {100 * pr['neck_max_abs']:.1f} %, "
            f"texels within 2 % {100 * pr['within_2pct']:.1f} %"
        )
        print("  height mm: " + " ".join(f"{c:+.0f}" for c in pr["centres"]))
        print("  median %:  " + " ".join(f"{100 * m:+.1f}" for m in pr["median_rel"]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
