"""One physical object, two capture kinds: the mesh_views ellipsoid (torchrefl/synthetic/uv_objects.py, its glossy
papers on its UV atlas) photographed by calibrated cameras (configs/mesh_views.yaml) and scanned by the cylindrical
rig (torchrefl/synthetic/scan.py with that object), both fitted with Method I; the fitted Pd, Ps and sigma are
compared at the same surface points (each mesh_views texel with the scan texel nearest to it in 3-D, within a texel
size), beside each fit's own error against the truth at those points.

    python scripts/compare_capture_kinds.py --size full --out outputs/compare_kinds    # docs/results/mesh_views.md
    python scripts/compare_capture_kinds.py --size tiny --out /tmp/kinds               # seconds (the test's size)

The two truths are one material function sampled at the two grids' points: they differ only where a matched pair
straddles a paper border (reported as the truth mismatch).
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

import torchrefl
from torchrefl.config import SyntheticConfig
from torchrefl.report.run_result import RunResult, load_run
from torchrefl.synthetic.scan import SyntheticScan
from torchrefl.synthetic.uv_objects import make_views_object

ROOT = Path(__file__).resolve().parents[1]
MEASURED = 2  # coverage code: Pd, Ps and sigma measured from the texel's own highlights (docs/outputs.md)


@dataclass(frozen=True)
class Sizes:
    """mesh_views: overrides of configs/mesh_views.yaml; scan: the cylindrical scan's grid (SyntheticConfig keys);
    lights: the scan's lights, head-frame [lateral, vertical, radial] mm; optimizer, iterations: fit.optimizer and
    fit.iterations of both (none: the closed forms and the sigma search only)."""

    mesh_views: tuple[str, ...]
    scan: dict
    lights: tuple[tuple[float, float, float], ...]
    optimizer: str
    iterations: int


def _lights(laterals, verticals, radial=300.0) -> tuple:
    """A grid of head-frame light positions (next to the camera, which rides at [0, 0, 300])."""
    return tuple((float(x), float(y), radial) for y in verticals for x in laterals)


SIZES = {
    # the bundled config as it is; a scan of about its texel size (2.8 deg x 1.6 mm: 2-3 mm texels)
    "full": Sizes(
        mesh_views=(),
        scan=dict(columns=128, rows=80, angle_step_deg=2.8125, height_step_mm=1.6, supersample=2),
        lights=_lights([-75.0, -25.0, 25.0, 75.0], [-125.0, -50.0, 0.0, 50.0, 125.0]),
        optimizer="lm",
        iterations=60,
    ),
    "tiny": Sizes(
        mesh_views=(
            "capture.texture_size=16",
            "views.width=96",
            "views.height=72",
            "views.focal_px=160",
            "views.camera_elevations_deg=[-20.0,30.0]",
            "views.cameras_per_ring=2",
            "views.lights_per_view=2",
            "views.supersample=1",
            "fit.holdout=[]",
        ),
        scan=dict(columns=32, rows=20, angle_step_deg=11.25, height_step_mm=6.0, supersample=1),
        lights=_lights([-25.0, 25.0], [-75.0, 0.0, 75.0]),
        optimizer="none",
        iterations=0,
    ),
}


@dataclass(frozen=True)
class Agreement:
    """The two fits at the matched surface points (mesh_views texels with a scan texel within `tolerance_mm`).

    pd_rms_diff: RMS over points and channels of Pd(mesh_views) - Pd(scan); pd_rms_err_views, pd_rms_err_scan:
    each fit's RMS error against its own truth there; pd_rms_truth_diff: the two truths' RMS difference (paper
    borders between the pair). ps_/sigma_median_rel_diff: median |a - b| / b (b the scan's) over the matched
    points where both fits measured the lobe (coverage 2), `lobe_matched` of them, with each fit's median relative
    error against its truth there and the two truths' median relative difference."""

    matched: int
    views_texels: int
    tolerance_mm: float
    pd_rms_diff: float
    pd_rms_err_views: float
    pd_rms_err_scan: float
    pd_rms_truth_diff: float
    lobe_matched: int
    ps_median_rel_diff: float | None
    sigma_median_rel_diff: float | None
    ps_median_rel_err_views: float | None
    ps_median_rel_err_scan: float | None
    sigma_median_rel_err_views: float | None
    sigma_median_rel_err_scan: float | None
    ps_median_rel_truth_diff: float | None
    sigma_median_rel_truth_diff: float | None

    def pd_tolerance(self) -> float:
        """The RMS difference two independent fits with these errors would show: their errors and the truths'
        mismatch added in quadrature."""
        return float(np.sqrt(self.pd_rms_err_views**2 + self.pd_rms_err_scan**2 + self.pd_rms_truth_diff**2))

    def table(self) -> str:
        f = lambda x: "-" if x is None else f"{x:.4f}"
        rows = [
            ("matched points", f"{self.matched} of {self.views_texels} estimated mesh_views texels"),
            ("match tolerance", f"{self.tolerance_mm:.2f} mm"),
            ("Pd RMS difference", f"{f(self.pd_rms_diff)} (independent errors predict {f(self.pd_tolerance())})"),
            ("Pd RMS error vs truth", f"mesh_views {f(self.pd_rms_err_views)}, scan {f(self.pd_rms_err_scan)}"),
            ("Pd truths' RMS difference", f(self.pd_rms_truth_diff)),
            ("lobe measured by both", f"{self.lobe_matched} points"),
            ("Ps median rel. difference", f"{f(self.ps_median_rel_diff)} (truths: {f(self.ps_median_rel_truth_diff)})"),
            (
                "Ps median rel. error",
                f"mesh_views {f(self.ps_median_rel_err_views)}, scan {f(self.ps_median_rel_err_scan)}",
            ),
            (
                "sigma median rel. difference",
                f"{f(self.sigma_median_rel_diff)} (truths: {f(self.sigma_median_rel_truth_diff)})",
            ),
            (
                "sigma median rel. error",
                f"mesh_views {f(self.sigma_median_rel_err_views)}, scan {f(self.sigma_median_rel_err_scan)}",
            ),
        ]
        return "\n".join(f"| {a} | {b} |" for a, b in [("quantity", "value"), ("---", "---"), *rows])


def scan_folder(folder: Path, sizes: Sizes, seed: int) -> Path:
    """The mesh_views ellipsoid of `seed` scanned by the cylindrical rig into `folder` (a cylindrical_scan folder)."""
    obj = make_views_object("ellipsoid", seed).mesh
    scan = SyntheticScan(replace(SyntheticConfig(), **sizes.scan), seed=seed, obj=obj)
    scan.write_geometry(folder)
    scan.write_textures(folder, np.array(sizes.lights))
    return folder


def fit_both(out: Path, sizes: Sizes, seed: int) -> tuple[RunResult, RunResult]:
    """(mesh_views run, scan run) of the same object, fitted with Method I into out/mesh_views and out/scan."""
    common = [f"seed={seed}", f"fit.optimizer={sizes.optimizer}", f"fit.iterations={sizes.iterations}"]
    common += ["fit.model=local", "output.progress=false"]
    views = torchrefl.fit(
        ROOT / "configs" / "mesh_views.yaml",
        [*common, *sizes.mesh_views, f"output.dir={out / 'mesh_views'}"],
        quiet=True,
    )
    folder = scan_folder(out / "scan_capture", sizes, seed)
    scan = torchrefl.fit(
        ROOT / "configs" / "default.yaml",
        [*common, "capture.kind=cylindrical_scan", f"capture.path={folder}", f"output.dir={out / 'scan'}"],
        quiet=True,
    )
    return views, scan


def _truth(path: Path) -> dict:
    with np.load(path, allow_pickle=False) as npz:
        return {k: npz[k] for k in ("pd", "ps", "sigma")}


def _spacing(points: np.ndarray) -> float:
    """Median distance from a texel to its nearest other texel (the texel size), mm."""
    return float(np.median(cKDTree(points).query(points, k=2)[0][:, 1]))


def _rel(a: np.ndarray, b: np.ndarray) -> float | None:
    return float(np.median(np.abs(a - b) / np.abs(b))) if len(a) else None


def compare(views: RunResult, scan: RunResult, views_truth: dict, scan_truth: dict) -> Agreement:
    """The two runs' maps at matched points (module doc): each estimated mesh_views texel with the nearest estimated
    scan texel, kept within the larger of the two texel sizes."""
    pv, ps_ = views.positions[views.mask], scan.positions[scan.mask]
    tolerance = max(_spacing(pv), _spacing(ps_))
    dist, j = cKDTree(ps_).query(pv)
    ok = dist <= tolerance
    pick = lambda run, truth, key, rows: (run.__dict__[key][run.mask][rows], truth[key][run.mask][rows])
    iv, js = np.flatnonzero(ok), j[ok]
    (pd_v, pd_vt), (pd_s, pd_st) = pick(views, views_truth, "pd", iv), pick(scan, scan_truth, "pd", js)
    rms = lambda d: float(np.sqrt(np.mean(np.square(d))))
    measured = (views.coverage[views.mask][iv] == MEASURED) & (scan.coverage[scan.mask][js] == MEASURED)
    grey = lambda a: a.mean(-1) if a.ndim == 2 else a  # Ps of RGB or grey runs as one number per point
    lobe = lambda run, truth, key, rows: [grey(a)[measured] for a in pick(run, truth, key, rows)]
    (psv, psvt), (pss, psst) = lobe(views, views_truth, "ps", iv), lobe(scan, scan_truth, "ps", js)
    (sv, svt), (ss, sst) = lobe(views, views_truth, "sigma", iv), lobe(scan, scan_truth, "sigma", js)
    return Agreement(
        matched=int(ok.sum()),
        views_texels=len(pv),
        tolerance_mm=tolerance,
        pd_rms_diff=rms(pd_v - pd_s),
        pd_rms_err_views=rms(pd_v - pd_vt),
        pd_rms_err_scan=rms(pd_s - pd_st),
        pd_rms_truth_diff=rms(pd_vt - pd_st),
        lobe_matched=int(measured.sum()),
        ps_median_rel_diff=_rel(psv, pss),
        sigma_median_rel_diff=_rel(sv, ss),
        ps_median_rel_err_views=_rel(psv, psvt),
        ps_median_rel_err_scan=_rel(pss, psst),
        sigma_median_rel_err_views=_rel(sv, svt),
        sigma_median_rel_err_scan=_rel(ss, sst),
        ps_median_rel_truth_diff=_rel(psvt, psst),
        sigma_median_rel_truth_diff=_rel(svt, sst),
    )


def compare_runs(out: Path) -> Agreement:
    """compare() of the two runs that fit_both wrote into `out`."""
    views, scan = load_run(Path(out) / "mesh_views"), load_run(Path(out) / "scan")
    return compare(
        views, scan, _truth(views.folder / "capture" / "truth.npz"), _truth(Path(out) / "scan_capture" / "truth.npz")
    )


def run(out: Path, size: str = "tiny", seed: int = 0) -> Agreement:
    """Capture, fit and compare at `size` (SIZES) into `out`."""
    views, scan = fit_both(Path(out), SIZES[size], seed)
    return compare(
        views, scan, _truth(views.folder / "capture" / "truth.npz"), _truth(Path(out) / "scan_capture" / "truth.npz")
    )


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", choices=sorted(SIZES), default="tiny")
    ap.add_argument("--out", type=Path, required=True, help="a new folder for the two captures and runs")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--compare-only", action="store_true", help="compare the runs already in --out (no capture, fit)")
    args = ap.parse_args(argv)
    print((compare_runs(args.out) if args.compare_only else run(args.out, args.size, args.seed)).table())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
