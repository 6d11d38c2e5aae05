"""Calibration of the per-texel uncertainty (torchrefl.fit.uncertainty) on synthetic captures re-drawn with
independent sensor noise (synthetic.noise_seed; same scene, same lights).

Each noise seed's capture is fitted; over the well-determined texels (estimated, Ps and sigma measured from the
texel's own observations and determined to 10 % relative std) the z-scores (estimate - truth) / std of every
parameter are pooled over the seeds. Printed per parameter (Pd and Ps per channel pooled) and transport level:
the z-scores' std (target [0.8, 1.25]) and the share of truths inside the nominal 95 % interval (target 90-98 %);
and the calibration curve (the share inside the nominal interval against its nominal level) as a plot.

The noiseless images are rendered once (the first seed's run) and reused by the other seeds: the scene, the lights
and the interreflection paths do not depend on synthetic.noise_seed, only the sensor noise drawn after them does
(SyntheticScan._sensor), so each seed's capture is the same radiance with its own noise, and a path-traced scene
costs one rendering instead of one per seed.

    python scripts/uncertainty_calibration.py [--config configs/quick.yaml] [--seeds 8] [--out FOLDER]
        [--plot docs/results/uncertainty_calibration.png] [dotted.key=value ...]
    python scripts/uncertainty_calibration.py --runs RUN_DIR [RUN_DIR ...]   # pool finished synthetic runs instead
        [--by-profile]    # and their concave and convex texels apart (the rows' profile curvature's sign)
    python scripts/uncertainty_calibration.py --tiny      # a 32 x 24 texel scan, 2 seeds (a check, not a result)
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from statistics import NormalDist

import numpy as np

import torchrefl
from torchrefl.report.uncertainty import RELATIVE_PRECISION, relative_std
from torchrefl.synthetic.scan import SyntheticScan

ROOT = Path(__file__).resolve().parents[1]
TINY = [
    "synthetic.columns=32",
    "synthetic.rows=24",
    "synthetic.angle_step_deg=11.25",
    "synthetic.height_step_mm=7.5",
    "synthetic.supersample=1",
    "synthetic.mesh_subdivisions=3",
    "selection.max_lights=4",
    "fit.iterations=5",
    "fit.sigma_search=4",
    "output.map_lights=0",
]
#: nominal central interval levels of the calibration curve
LEVELS = np.linspace(0.05, 0.99, 48)


@dataclass
class Calibration:
    """The z-scores of one parameter at one transport level: their std, the share of truths inside the nominal 95 %
    interval, how many (texel, channel, seed) values, their mean (a bias the std does not describe)."""

    parameter: str
    level: str
    z_std: float
    coverage_95: float
    count: int
    z_mean: float


def render_once() -> dict:
    """Memoise SyntheticScan.radiance_images in this process (module docstring): keyed by the scan's config without
    its noise seed, its seed and the head positions. Returns the memo (its size is the number of renderings)."""
    memo: dict = {}
    render = SyntheticScan.radiance_images

    def radiance_images(scan, head_positions, progress=None):
        positions = np.asarray(head_positions, dtype=np.float64)
        key = (repr(replace(scan.cfg, noise_seed=None)), scan.seed, positions.tobytes())
        if key not in memo:
            memo[key] = render(scan, positions, progress=progress)
        return memo[key]

    SyntheticScan.radiance_images = radiance_images
    return memo


def profile_curvature(run) -> np.ndarray:
    """(H, W) the sign-carrying curvature of the texel grid along its rows (a cylindrical scan's profile):
    (n[i+1] - n[i-1]) . (p[i+1] - p[i-1]) / |p[i+1] - p[i-1]|^2 in 1 / length, < 0 concave, > 0 convex; 0 on the
    first and last rows."""
    n, p = run.normals, run.positions
    out = np.zeros(n.shape[:2])
    dp, dn = p[2:] - p[:-2], n[2:] - n[:-2]
    out[1:-1] = (dn * dp).sum(-1) / np.maximum((dp * dp).sum(-1), 1e-12)
    return out


def z_scores(run, where: np.ndarray | None = None) -> dict:
    """{parameter: (N,) z-scores} over the run's well-determined texels (module docstring), those of where (H, W)
    bool only when given."""
    truth = np.load(run.folder / "capture" / "truth.npz")
    ps_rel, sg_rel = relative_std(run.ps, run.sigma, run.ps_std, run.sigma_std)
    good = run.mask & run.lobe_measured & (ps_rel <= RELATIVE_PRECISION) & (sg_rel <= RELATIVE_PRECISION)
    if where is not None:
        good = good & where
    out = {}
    for name in ("pd", "ps", "sigma"):
        est, std, true = getattr(run, name), getattr(run, f"{name}_std"), truth[name]
        if name == "ps" and est.shape[-1] != true.shape[-1]:
            true = true.mean(-1, keepdims=True)
        out[name] = ((est[good] - true[good]) / std[good]).reshape(-1)
    return out


def covered(z: np.ndarray, levels: np.ndarray = LEVELS) -> np.ndarray:
    """The share of |z| inside each nominal central interval level's normal quantile."""
    q = np.array([NormalDist().inv_cdf(0.5 + a / 2.0) for a in levels])
    return (np.abs(z)[None, :] <= q[:, None]).mean(1)


def plot(curves: dict, path: Path) -> None:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(5.0, 4.6), layout="constrained")
    ax = fig.subplots()
    ax.plot([0, 1], [0, 1], color="0.5", lw=1, ls="--", label="ideal")
    for label, share in curves.items():
        ax.plot(LEVELS, share, lw=1.6, label=label)
    ax.axhspan(0.90, 0.98, xmin=0.93, xmax=0.97, color="0.85")
    ax.set_xlabel("nominal level of the central interval")
    ax.set_ylabel("share of truths inside it")
    ax.set_title("calibration of the per-texel std", fontsize=11)
    ax.legend(fontsize=8)
    fig.savefig(path, dpi=110)


def fitted(config: str, overrides: list, seeds: int, out: Path):
    """The runs of config fitted for noise seeds 1000, 1001, ... (synthetic.noise_seed), rendered once."""
    render_once()
    for k in range(seeds):
        seed = [f"synthetic.noise_seed={1000 + k}", f"output.dir={out / f'noise_{k}'}"]
        yield torchrefl.fit(torchrefl.load_config(config, overrides + seed), overwrite=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", default=str(ROOT / "configs" / "quick.yaml"))
    ap.add_argument("--seeds", type=int, default=None, help="sensor-noise seeds (synthetic.noise_seed; default 8)")
    ap.add_argument("--out", default=None, help="folder of the runs (default: a temporary folder)")
    ap.add_argument("--plot", default=None, help="the calibration curve's PNG (default: OUT/calibration.png)")
    ap.add_argument("--tiny", action="store_true", help="a 32 x 24 texel scan, 2 seeds: a check, not a result")
    ap.add_argument("--runs", nargs="+", default=None, help="pool these finished synthetic runs (no fit)")
    ap.add_argument(
        "--by-profile", action="store_true", help="rows for the concave and the convex texels of the profile too"
    )
    ap.add_argument("overrides", nargs="*", help="dotted.key=value config overrides")
    args = ap.parse_args(argv)
    out = Path(args.out or tempfile.mkdtemp(prefix="uncertainty_calibration_"))
    out.mkdir(parents=True, exist_ok=True)
    seeds = args.seeds or (2 if args.tiny else 8)
    overrides = (TINY if args.tiny else []) + list(args.overrides) + ["output.progress=false"]
    pooled: dict = {}
    if args.runs:
        runs = (torchrefl.load_run(folder) for folder in args.runs)
        seeds, what = len(args.runs), f"runs {' '.join(args.runs)}"
    else:
        runs = fitted(args.config, overrides, seeds, out)
        what = f"config {args.config} {' '.join(overrides)}"
    for k, run in enumerate(runs):
        if run.pd_std is None:
            print(f"{run.folder}: the run has no uncertainty", file=sys.stderr)
            return 1
        level = run.metrics["model"]
        zs = z_scores(run)
        for name, z in zs.items():
            pooled.setdefault((name, level), []).append(z)
        if args.by_profile:
            k_profile = profile_curvature(run)
            for part, where in (("concave", k_profile < 0), ("convex", k_profile > 0)):
                if not (where & run.mask).any():  # no such texel (a convex object has no concave part)
                    continue
                for name, z in z_scores(run, where).items():
                    pooled.setdefault((name, f"{level}, {part}"), []).append(z)
        u, t = run.metrics["uncertainty"], run.metrics["timing_s"]
        spread = ", ".join(f"{name} {np.nanstd(z):.3f}" for name, z in zs.items())
        print(
            f"run {k}: level {level}, noise {[round(x, 3) for x in u['noise_dn']]} DN ({u['noise_source']}), "
            f"{zs['sigma'].size} determined texels, z std {spread}; fit {t['fit']:.0f} s, "
            f"uncertainty {t['uncertainty']:.1f} s, total {t['total']:.0f} s"
        )
    rows, curves = [], {}
    for (name, level), parts in pooled.items():
        z = np.concatenate(parts)
        z = z[np.isfinite(z)]
        rows.append(
            Calibration(
                name,
                level,
                float(z.std()) if z.size else math.nan,
                float(covered(z, np.array([0.95]))[0]),
                z.size,
                float(z.mean()) if z.size else math.nan,
            )
        )
        curves[f"{name} ({level})"] = covered(z)
    print(f"\n{seeds} noise seeds, {what}")
    print("| parameter | level | z std (target 0.8-1.25) | 95 % interval covers (target 90-98 %) | values | z mean |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r.parameter} | {r.level} | {r.z_std:.3f} | {100 * r.coverage_95:.1f} % | {r.count} | {r.z_mean:+.3f} |"
        )
    plot(curves, Path(args.plot) if args.plot else out / "calibration.png")
    (out / "calibration.json").write_text(json.dumps([asdict(r) for r in rows], indent=2))
    print(f"\nwritten {out / 'calibration.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
